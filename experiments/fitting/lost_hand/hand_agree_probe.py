"""Probe (nothing in the fitter uses it): per fitted hand (and foot), do the scan points it explains (its
nearest fitted part, within 2 cm, clutter removed) carry the network's label of that part, either side's
hand or forearm (foot or ankle)? Against the part's true error (mean vertex distance, cm). One JSON line per
scan of the user suite (``user_scans.people_scans``), the fitter's defaults.

    OMP_NUM_THREADS=1 python experiments/fitting/lost_hand/hand_agree_probe.py 0 1 > agree01.jsonl
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import user_scans as us  # noqa: E402

from arteq.body.skeleton import JOINT_NAMES  # noqa: E402
from arteq.fit import Fitter  # noqa: E402

torch.set_num_threads(1)
J = {n: i for i, n in enumerate(JOINT_NAMES)}
ENDS = {
    "left_hand": ("left_wrist", "left_elbow", "right_wrist", "right_elbow"),
    "right_hand": ("right_wrist", "right_elbow", "left_wrist", "left_elbow"),
    "left_foot": ("left_ankle", "left_foot", "right_ankle", "right_foot"),
    "right_foot": ("right_ankle", "right_foot", "left_ankle", "left_foot"),
}
f = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
parts = f.vertex_parts
out = []
for seed in map(int, sys.argv[1:]):
    for s in us.people_scans(seed):
        if s.vertices is None:
            continue
        r = f.fit_points(s.points, name=s.name)
        if r.vertices is None:
            continue
        rec = {
            "seed": seed,
            "group": s.group,
            "name": s.name,
            "status": r.status,
            "v2v": float(np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100),
        }
        for end, names in ENDS.items():
            own = J[names[0]]
            ok = [J[n] for n in names]
            m = (r.point_fit_labels == own) & (r.point_labels >= 0) & (r.point_distance < 0.02)
            lab = r.point_labels[m]
            rec[end] = {
                "n": int(m.sum()),
                "agree": float(np.isin(lab, ok).mean()) if m.sum() else float("nan"),
                "err": float(
                    np.linalg.norm(r.vertices[parts == own] - s.vertices[parts == own], axis=1).mean() * 100
                ),
            }
        out.append(rec)
        print(json.dumps(rec), flush=True)
