"""Does the network's pose on the scans it loses depend on the input's orientation? (A test-time-augmentation
probe: if some rotations gave good poses, several rotated inputs scored against the scan would be a lever.)

    OMP_NUM_THREADS=1 python experiments/fitting/tta_probe.py > experiments/fitting/tta_probe.txt

The user-scan suite's acrobatic and reach_up scans (seed 0), the network alone (anny_scan, no refinement,
no second start, no check): V2V cm of the prediction on the scan as it is (first column) and turned by 7
Haar-random rotations (the prediction turned back). Output: experiments/fitting/tta_probe.txt.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from user_scans import people_scans, random_rotation

    from arteq.fit import Fitter

    torch.set_num_threads(1)
    f = Fitter(ckpt="anny_scan", device="cpu", anny=False, check=False, crossing=False, refine=False,
               second_start=False)  # fmt: skip
    rng = np.random.default_rng(5)
    for s in people_scans(0):
        if s.group != "acrobatic" and "reach_up" not in s.name:
            continue
        c = s.points.mean(0)
        v2v = []
        for k in range(8):
            rot = np.eye(3) if k == 0 else random_rotation(rng)
            r = f.fit_points((s.points - c) @ rot.T, name=s.name)
            v2v.append(np.linalg.norm(r.vertices @ rot + c - s.vertices, axis=1).mean() * 100)
        print(f"{s.name:40s}", " ".join(f"{x:5.1f}" for x in v2v), flush=True)


if __name__ == "__main__":
    main()
