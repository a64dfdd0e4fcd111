"""How far each test set lies from the training poses: mean nearest-training-pose distance (degrees, mean
over the 21 non-root joints of the geodesic angle between local rotations) of 500 poses of every test set
to 5000 training poses, for the narrow everyday training poses and for the widened ones (data.wide_poses).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/articulated/gaps.py > experiments/articulated/gaps.md
"""

from arteq.body.factory import create_body
from arteq.data.poses import (
    ContactRejectedPoses,
    LimbOODPoses,
    SyntheticIDPoses,
    SyntheticOODPoses,
    pose_set_gaps,
)

body = create_body({"name": "anny22"})
names = {"id_heldout": "test_id (held-out everyday)", "ood": "test_ood (hard)", "limb1": "test_ood_limb1",
         "limb2": "test_ood_limb2", "contact": "test_ood_contact"}  # fmt: skip
rows = {}
for wide in (0.0, 0.5):
    queries = {"id_heldout": SyntheticIDPoses(), "ood": SyntheticOODPoses(), "limb1": LimbOODPoses(1),
               "limb2": LimbOODPoses(2), "contact": ContactRejectedPoses(body)}  # fmt: skip
    rows[wide] = pose_set_gaps(SyntheticIDPoses(wide_prob=wide), queries, n_ref=5000, n_query=500, seed=0)
print(
    "| test set (500 poses) | to narrow training poses: mean deg (p5) | ratio to test_id "
    "| to widened (wide_poses 0.5): mean deg (p5) | ratio to test_id |"
)
print("|---|---:|---:|---:|---:|")
for k, label in names.items():
    cells = []
    for wide in (0.0, 0.5):
        g = rows[wide][k]
        cells += [
            f"{g['mean_deg']:.1f} ({g['p5_deg']:.1f})",
            f"{g['mean_deg'] / rows[wide]['id_heldout']['mean_deg']:.1f}x",
        ]
    print(f"| {label} | " + " | ".join(cells) + " |")
