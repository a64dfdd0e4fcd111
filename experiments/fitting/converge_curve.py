"""V2V to the true mesh at every refinement iteration, for 40, 60 and 100 iterations (every point in the
objective, ``w_betas`` 0.1, ``lr_betas`` 0.1, the rest as ``arteq-fit``'s), on every other scan of
user_scans.py's children and adults (the reach_up scans left out), one start, no crossed-limb step.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/converge_curve.py \
        > experiments/fitting/converge/curve.txt

Prints per scan its final V2V and the curve at ten points, then per iteration count the mean curve at
twenty points (cm).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    import user_scans as us

    import arteq.fit.api as api
    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig

    torch.set_num_threads(1)
    scans = [s for s in us.people_scans(0) if s.group in ("children", "adults") and "reach_up" not in s.name]
    scans = scans[::2]
    cur: dict = {}
    refine = api.refine

    def recorded(*a, **k):  # the refinement with a callback that measures each iteration's fit
        def cb(it, vd):
            cur["curve"].append(
                np.linalg.norm(vd[0].detach().numpy() + cur["c"] - cur["truth"], axis=1).mean() * 100
            )

        return refine(*a, **k, callback=cb)

    api.refine = recorded
    for iters in (40, 60, 100):
        cfg = RefineConfig(iters=iters, points=0, w_betas=0.1, lr_betas=0.1)
        f = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False, second_start=False,
                   crossing=False, refine_config=cfg)  # fmt: skip
        curves = []
        for s in scans:
            item = f.prepare(s.points)
            cur.update(c=item["center"], truth=s.vertices, curve=[])
            r = f.fit_prepared([item])[0]
            curves.append(np.array(cur["curve"]))
            final = np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100
            pts = " ".join(f"{x:.2f}" for x in cur["curve"][:: max(1, iters // 10)])
            print(iters, s.name[:30], "final", round(final, 2), "curve", pts, flush=True)
        m = np.mean(curves, 0)
        print("MEAN", iters, " ".join(f"{x:.2f}" for x in m[:: max(1, iters // 20)]), flush=True)


if __name__ == "__main__":
    main()
