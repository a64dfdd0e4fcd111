"""The hands' last pass in variants, paired on the same fits: each scan fitted once without it
(``Fitter(hands=False)``), then the pass run on that fit with each variant's settings.

    OMP_NUM_THREADS=1 python experiments/fitting/hands_variants.py native|user SEED

``native``: experiments/fitting/native_anny.py's scans (versions native, hands, spread); ``user``: the
user-scan suite's bodies. Variants: ``hand`` (the default, one curl per hand), ``finger`` (one per finger).
Prints one json line per scan (V2V cm: ``none`` the fit without the pass) and the means per group.
"""

import json
import sys
from pathlib import Path

import numpy as np
import roma
import torch

from arteq.body.hands import hands_for
from arteq.fit import Fitter
from arteq.fit.hands import HandsConfig, fit_hands

sys.path.insert(0, str(Path(__file__).resolve().parent))
torch.set_num_threads(1)

suite, seed = sys.argv[1], int(sys.argv[2])
if suite == "native":
    import native_anny as na

    scans = [s for s in na.native_scans(seed, 12) if s.group in ("hands", "spread", "native")]
else:
    import user_scans as us

    scans = [
        s
        for s in us.people_scans(seed)
        if s.vertices is not None and s.group in ("adults", "children", "acrobatic")
    ]
f = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False, hands=False)
hc = hands_for(f.body)
hands = np.isin(f.body.lbs_weights.argmax(1).numpy(), [20, 21])
variants = {"hand": HandsConfig(), "finger": HandsConfig(per_finger=True)}
rows = []
for s in scans:
    r = f.fit_points(s.points, name=s.name)
    if r.vertices is None:
        continue
    init = {
        "local_rotmats": roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float32))[None],
        "betas": torch.as_tensor(r.betas)[None],
        "transl": torch.as_tensor(r.transl_m, dtype=torch.float32)[None],
    }
    rec = {
        "name": s.name,
        "group": s.group,
        "none": float(np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100),
    }
    if r.scan_mode == "full":
        for k, cfg in variants.items():
            out = fit_hands(f.body, hc, [r.scan_points.astype(np.float64)], init, cfg)
            rec[k] = float(
                np.linalg.norm(out["vertices"][0].double().numpy() - s.vertices, axis=1).mean() * 100
            )
    rows.append(rec)
    print(json.dumps(rec), flush=True)
for g in sorted({r["group"] for r in rows}):
    rs = [r for r in rows if r["group"] == g and "hand" in r]
    print(
        g,
        len(rs),
        {k: round(float(np.mean([r[k] for r in rs])), 3) for k in ("none", "hand", "finger")},
        "finger better/worse >0.05:",
        sum(r["finger"] < r["hand"] - 0.05 for r in rs),
        sum(r["finger"] > r["hand"] + 0.05 for r in rs),
    )
