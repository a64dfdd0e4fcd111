"""Why the adults' reach_up fits miss 1.5 cm: the arms' joint rotations against the truth's, and the surface
scores of the fit and of the fit from the true pose.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/reach_twist_probe.py --seeds 0 1 \
        > experiments/fitting/stature/reach_twist_probe.txt

For each ``reach_up`` adult of the user-scan suite, ``arteq-fit``'s ``Fitter`` (defaults, ``anny_scan``) as
shipped and with every refinement start's pose replaced by the truth (as ``start_probe.py --start
true_pose``). Per fit: V2V, the surface scores (mean distance of the scan's points to the fitted vertices,
``s2m``, and of the evenly spread fitted vertices to the scan, ``m2s``, cm), and per arm joint the rotation
angle of the fitted local rotation, of the true one, and between them (degrees).
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

JOINTS = ("spine3", "left_collar", "right_collar", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow")


def main(argv: list[str] | None = None) -> None:
    import user_scans as us
    from scipy.spatial import cKDTree

    import arteq.fit.api as api
    from arteq.body.skeleton import JOINT_NAMES
    from arteq.fit import Fitter

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    a = ap.parse_args(argv)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    fitter = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
    refine, truth = api.refine, {}

    def refine_from(body_, points, probs, starts, cfg, **kw):
        if truth.get("pose") is not None:
            starts = dict(starts)
            r = starts["local_rotmats"].clone()
            r[:] = truth["pose"].to(r.dtype)
            starts["local_rotmats"] = r
        return refine(body_, points, probs, starts, cfg, **kw)

    def angle(r: torch.Tensor) -> float:
        return float(np.degrees(roma.rotmat_to_rotvec(r).norm()))

    api.refine = refine_from
    print(f"# {__doc__.splitlines()[0]}\n# OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/reach_twist_probe.py "
          + " ".join(argv or sys.argv[1:]))  # fmt: skip
    try:
        for seed in a.seeds:
            for s in us.people_scans(seed):
                if s.group != "adults" or "reach_up" not in s.name:
                    continue
                for start in ("network", "true pose"):
                    truth["pose"] = s.pose.double() if start == "true pose" else None
                    r = fitter.fit_points(s.points, name=s.name)
                    v = r.vertices.astype(np.float64)
                    s2m = cKDTree(v).query(s.points)[0].mean() * 100
                    m2s = cKDTree(s.points).query(v[fitter.subset])[0].mean() * 100
                    v2v = np.linalg.norm(v - s.vertices, axis=1).mean() * 100
                    fit = roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float64))
                    tr = s.pose.double()
                    joints = "; ".join(
                        f"{n} {angle(fit[k]):.0f}/{angle(tr[k]):.0f}/{angle(fit[k].T @ tr[k]):.0f}"
                        for n in JOINTS
                        for k in [JOINT_NAMES.index(n)]
                    )
                    print(f"seed {seed} | {s.name} | start {start} | V2V {v2v:.2f} s2m {s2m:.3f} m2s {m2s:.3f} | "
                          f"fit/true/between deg: {joints}", flush=True)  # fmt: skip
    finally:
        api.refine = refine


if __name__ == "__main__":
    main()
