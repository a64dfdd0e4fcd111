"""How far each test set lies from the scan-fitting model's training poses (experiments/scan_model/run.sh).

Mean and 5th-percentile nearest-training-pose distance (mean non-root geodesic angle, degrees; ``arteq.data.
poses.pose_set_gaps``) of every test set and of the user-scan suite's acrobatic templates (handstand, splits,
backbend, ...; experiments/fitting/check_calibration.py ``ACROBATIC``, jittered 5 deg as user_scans.py makes
them), against 5000 draws of the training mix, and for reference against the ID-only training poses of the
research model. The acrobatic set is the held-out extreme set the scan model was not tuned on.

    OMP_NUM_THREADS=1 python experiments/scan_model/pose_gaps.py > experiments/scan_model/pose_gaps.md
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "fitting"))

from check_calibration import ACROBATIC  # noqa: E402
from user_scans import pose_from_template  # noqa: E402

from arteq.data.poses import (  # noqa: E402
    LimbOODPoses,
    MixedPoses,
    PoseSource,
    SyntheticIDPoses,
    SyntheticOODPoses,
    draw_poses,
    nearest_pose_distance,
)

MIX = {"id": 0.4, "ood": 0.4, "limb1": 0.1, "limb2": 0.1}  # run.sh's data.train_pose_mix
N_REF, N_QUERY = 5000, 500


class Templates(PoseSource):
    """The acrobatic templates, each jittered by 5 deg per angle, in turn."""

    def __init__(self) -> None:
        self.names = list(ACROBATIC)

    def sample(self, index: int, generator: torch.Generator) -> dict:
        seed = int(torch.randint(2**31 - 1, (), generator=generator))
        rot = pose_from_template(ACROBATIC[self.names[index % len(self.names)]], np.random.default_rng(seed))
        import roma

        return {"pose": roma.rotmat_to_rotvec(rot), "betas": None, "transl": None}


def main() -> None:
    train_mix = MixedPoses(
        {"id": SyntheticIDPoses(wide_prob=0.5), "ood": SyntheticOODPoses(), "limb1": LimbOODPoses(1),
         "limb2": LimbOODPoses(2)}, MIX,
    )  # fmt: skip
    references = {
        "scan model (training mix)": train_mix,
        "research model (ID, half widened)": SyntheticIDPoses(wide_prob=0.5),
    }
    queries = {
        "test_id": SyntheticIDPoses(),
        "test_ood (hard)": SyntheticOODPoses(),
        "test_ood_limb1": LimbOODPoses(1),
        "test_ood_limb2": LimbOODPoses(2),
        "acrobatic templates (user_scans)": Templates(),
    }
    drawn = {name: draw_poses(src, N_QUERY, 101 + i) for i, (name, src) in enumerate(queries.items())}
    cols = list(references)
    print("| query set | " + " | ".join(f"to {c}: mean / p5 deg" for c in cols) + " |")
    print("|---|" + "---:|" * len(cols))
    cells = {}
    for c, ref_src in references.items():
        ref = draw_poses(ref_src, N_REF, 0)
        for q, poses in drawn.items():
            d = np.degrees(nearest_pose_distance(poses, ref).numpy())
            cells[q, c] = f"{d.mean():.1f} / {np.percentile(d, 5):.1f}"
    for q in queries:
        print(f"| {q} | " + " | ".join(cells[q, c] for c in cols) + " |")
    print(f"\n{N_REF} reference draws (seed 0), {N_QUERY} per query set (seeds 101..), non-root joints.")
    print("`OMP_NUM_THREADS=1 python experiments/scan_model/pose_gaps.py`")


if __name__ == "__main__":
    main()
