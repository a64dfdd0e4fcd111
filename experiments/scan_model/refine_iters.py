"""Probe: does a longer (or faster) refinement close anny_scan's gap on everyday bodies?

    OMP_NUM_THREADS=1 python experiments/scan_model/refine_iters.py anny_scan iters=40 iters=60 iters=80 \
        iters=80,reassoc_every=4 iters=60,lr_rot=0.03,lr_betas=0.08 \
        iters=40,lr_rot=0.04,lr_transl=0.02,lr_betas=0.1 iters=40,lr_rot=0.03,lr_betas=0.08
    OMP_NUM_THREADS=1 python experiments/scan_model/refine_iters.py anny22 iters=40

The 33 bodies of the check's labelled set (seed 0) without its acrobatic adults (everyday adults, children,
heavy builds, 10 % clutter; experiments/fitting/check_calibration.py), fitted through the public API with
each RefineConfig override (``points=N`` sets the Fitter's point count instead; the crossed-limb step off:
this was measured before it existed). Prints the
mean / median V2V (cm), usable fits (V2V <= 3 cm), the first 8 (everyday adults) mean, every scan's V2V and
the median refinement seconds (one thread; not comparable across rows when other jobs share the cores).
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fitting"))


def main() -> None:
    from check_calibration import labelled_set

    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig

    torch.set_num_threads(1)
    groups = ("everyday adults", "children 3-12 y", "heavy / extreme builds", "10% clutter")
    items = [it for it in labelled_set(0) if it["group"] in groups]
    ckpt = sys.argv[1]
    for arm in sys.argv[2:]:
        sets = re.split(r",(?=\w+=)", arm)  # a comma before KEY= separates
        points = [int(x.split("=")[1]) for x in sets if x.startswith("points=")]  # the Fitter's, not a knob
        cfg = RefineConfig.from_strings([x for x in sets if not x.startswith("points=")])
        f = Fitter(ckpt=ckpt, device="cpu", check=False, anny=False, refine_config=cfg, crossing=False,
                   points=points[-1] if points else 5000)  # fmt: skip
        v, ts = [], []
        for it in items:
            r = f.fit_points(it["points"], name=it["name"])
            ts.append(r.timings["refine"])
            v.append(np.linalg.norm(r.vertices - it["vertices"], axis=1).mean() * 100)
        v = np.array(v)
        each = " ".join(f"{x:.1f}" for x in v)
        usable = f"{np.sum(v <= 3)}/{len(v)}"
        print(f"{ckpt} {arm}: V2V mean {v.mean():.2f} median {np.median(v):.2f} usable {usable} "
              f"everyday8 {v[:8].mean():.2f} | {each} refine {np.median(ts):.2f} s", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
