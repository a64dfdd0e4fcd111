"""Single views whose fit is off: the same scan fitted from other readings (Fitter seeds 1, 2: other network
draws; three fixed random rotations of the scan, the fit turned back), V2V cm and status of each.

    OMP_NUM_THREADS=1 python experiments/single_view/readings_probe.py back:21,back:26,back:1,back:27,front:2,front:16
    OMP_NUM_THREADS=1 python experiments/single_view/readings_probe.py back:30,back:29,side:18,side:13,side:17,front:27

Output: readings/probe.txt (labels ``s<seed>r<rotation>``; ``s0r0`` is the default fit). The cases are the
worst of the 32-scan four-draw run (experiments/fitting/net_draws/single_view32_d4). See
experiments/fitting/retries.md, last section.
"""

import sys

import numpy as np
import torch

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parent))
import run
from scipy.spatial.transform import Rotation

from arteq.fit.api import Fitter

torch.set_num_threads(1)
cases = [(c.split(":")[0], int(c.split(":")[1])) for c in sys.argv[1].split(",")]
fitters = {s: Fitter(ckpt="anny_scan", device="cpu", anny=False, seed=s) for s in (0, 1, 2)}
body = fitters[0].module.body
data = run.scans(32, body)
rots = Rotation.random(3, random_state=5).as_matrix()
for sp, i in cases:
    d = data["test_view_" + sp]
    pts = d["points"][i].double().numpy()
    with torch.no_grad():
        gt = (
            body(betas=d["betas"][i : i + 1], pose=d["pose"][i : i + 1], transl=d["transl"][i : i + 1])
            .vertices[0]
            .numpy()
        )
    out = []
    for s, f in fitters.items():
        for k, R in enumerate([np.eye(3)] + list(rots) if s == 0 else [np.eye(3)]):
            c = pts.mean(0)
            r = f.fit_points((pts - c) @ R.T + c)
            v = (r.vertices - c) @ R + c
            out.append(
                (f"s{s}r{k}", round(float(np.linalg.norm(v - gt, axis=1).mean() * 100), 1), r.status[:4])
            )
    print(sp, i, out, flush=True)
