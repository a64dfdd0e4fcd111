"""The user suite's "an adult and a child touching" scan of seeds 0-5 (user_scans.people_scans), fitted with
``arteq-fit``'s defaults: status, the adult's fit's values, and the second-person test's (the group off the
fit fitted alone), fit seconds (one thread).

    OMP_NUM_THREADS=1 python experiments/fitting/second_person/suite_pairs.py > suite_pairs.log
"""

import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import user_scans as us  # noqa: E402

from arteq.fit import Fitter  # noqa: E402

torch.set_num_threads(1)
f = Fitter(anny=False, ckpt="anny_scan", device="cpu", points=5000)
for seed in range(6):
    s = [x for x in us.people_scans(seed) if x.name == "an adult and a child touching"][0]
    r = f.fit_points(s.points, name=s.name)
    q = r.quality
    fit = (f"fit: inliers {q['inlier_frac']:.3f}, coverage {q['coverage']:.3f}, off group "
           f"{q['off_group_frac']:.3f} / {q['off_group_cm']:.0f} cm;")  # fmt: skip
    alone = "not tried"
    if "second_person_inliers" in q:
        alone = (f"inliers {q['second_person_inliers']:.3f}, coverage {q['second_person_coverage']:.3f}, "
                 f"ratio {q['second_person_ratio']:.3f}, flags '{q['second_person_flags']}'")  # fmt: skip
    seconds = r.timings.get("total", 0.0)
    print(f"seed {seed}: {r.status}; {fit} group alone: {alone} | {seconds:.1f} s", flush=True)
