"""Single-view fits given the simulator's true camera direction (``Fitter.view_dir`` per scan) instead of the
estimated one: how much of the error the direction estimate costs (the bound of a better estimate).
``--set w_sil=...`` took a silhouette-term patch of the refinement (probed 2026-12-05, not kept: see README).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/true_direction.py --truth --out true.json
    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/true_direction.py --out estimated.json
"""

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import run as R  # noqa: E402
from direction_probe import cameras  # noqa: E402

from arteq.fit.api import Fitter  # noqa: E402
from arteq.fit.refine import RefineConfig  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("--scans", type=int, default=32)
ap.add_argument("--splits", default="side,back")
ap.add_argument("--truth", action="store_true", help="give the fitter the true camera direction")
ap.add_argument("--set", nargs="*", default=[], help="RefineConfig fields")
ap.add_argument("--out", required=True)
a = ap.parse_args()
torch.set_num_threads(1)
fitter = Fitter(ckpt="anny_scan", device="cpu", anny=False, refine_config=RefineConfig.from_strings(a.set))
body = fitter.module.body
data = R.scans(a.scans, body)
rows = []
for sp in a.splits.split(","):
    split = "test_view_" + sp
    d = data[split]
    for i, (cam, pts_t) in enumerate(cameras(body, a.scans, split)):
        assert torch.allclose(pts_t, d["points"][i], atol=1e-5), "regenerated scan differs from the cached one"
        pts = d["points"][i].double().numpy()
        true_dir = cam - pts.mean(0)
        true_dir /= np.linalg.norm(true_dir)
        fitter.view_dir = true_dir if a.truth else None
        t0 = time.perf_counter()
        res = fitter.fit_points(pts, name=f"{sp}{i}")
        wall = time.perf_counter() - t0
        with torch.no_grad():
            gt = body(betas=d["betas"][i : i + 1], pose=d["pose"][i : i + 1], transl=d["transl"][i : i + 1])
        ok = res.vertices is not None
        v2v = float(np.linalg.norm(res.vertices - gt.vertices[0].numpy(), axis=1).mean() * 100) if ok else None
        mp = float(np.linalg.norm(res.joints - gt.joints[0].numpy(), axis=1).mean() * 100) if ok else None
        ang = None
        if res.view_dir is not None:
            ang = float(np.degrees(np.arccos(np.clip(np.dot(res.view_dir, true_dir), -1, 1))))
        rows.append(dict(split=split, index=i, v2v_cm=v2v, mpjpe_cm=mp, seconds=wall, dir_err_deg=ang,
                         mode=res.scan_mode))  # fmt: skip
        print(sp, i, v2v, mp, ang, flush=True)
Path(a.out).write_text(json.dumps({"command": " ".join(sys.argv), "rows": rows}, indent=1))
