"""Single views whose fit changed when the clean-up's distance went from 20 to 30 cm (keep_near_m,
experiments/fitting/holes.md): which points 30 cm keeps that 20 cm removed, and how far they lie from the
true surface (flying pixels, or body).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/near_probe.py

The scans are those of ``run.py --scans 32`` whose V2V changed (side 7, 13, 26; back 29).
"""
import sys
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parent))
import numpy as np, torch
from scipy.spatial import cKDTree
from run import scans
from arteq.fit.api import Fitter
from arteq.fit.clean import CleanConfig
torch.set_num_threads(1)
f30 = Fitter(ckpt="anny_scan", device="cpu", anny=False)
f20 = Fitter(ckpt="anny_scan", device="cpu", anny=False, clean_config=CleanConfig(keep_near_m=0.2))
body = f30.module.body
data = scans(32, body)
for split, idxs in (("test_view_side", (7, 13, 26)), ("test_view_back", (29,))):
    d = data[split]
    for i in idxs:
        pts = d["points"][i].double().numpy()
        with torch.no_grad():
            gt = body(betas=d["betas"][i:i+1], pose=d["pose"][i:i+1], transl=d["transl"][i:i+1]).vertices[0].numpy()
        dist = cKDTree(gt).query(pts)[0] * 100
        r30, r20 = f30.fit_points(pts), f20.fit_points(pts)
        k30, k20 = r30.point_clutter == 0, r20.point_clutter == 0
        extra = k30 & ~k20
        v30 = np.linalg.norm(r30.vertices - gt, axis=1).mean() * 100
        v20 = np.linalg.norm(r20.vertices - gt, axis=1).mean() * 100
        lab = d["labels"][i].numpy()[extra]
        print(f"{split} {i}: V2V 20cm {v20:.2f} 30cm {v30:.2f}; kept only at 30 cm: {extra.sum()} points, "
              f"distance to the true surface cm median {np.median(dist[extra]) if extra.any() else float('nan'):.1f}, "
              f"within 2 cm {int((dist[extra] < 2).sum())}; true parts {np.bincount(lab, minlength=22).nonzero()[0].tolist()}; "
              f"removed by 20 cm as {np.bincount(r20.point_clutter[extra].astype(int) if extra.any() else [0], minlength=4).tolist()}", flush=True)
