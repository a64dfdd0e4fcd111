"""How the network reads the torso of the lost acrobatic fits: per torso part, its global rotation's error and
where the truth sits among the pose head's weights over the 60 group elements.

    OMP_NUM_THREADS=1 python experiments/scan_model/spine/torso/torso_reading.py \
        bends:plough bends:wheel acrobatic:bow acrobatic:backbend [--bodies 4] [--json OUT.json]

The scans of ``acro_eval.py`` (``--bodies`` per template, the same generator), read by ``arteq-fit``'s
network (``anny_scan``, its draws; no refinement). Per scan and part (pelvis, spine1-3, neck, head): the
mean angle (degrees) of the draws' global rotations to the truth's; the group element nearest the truth,
its angle, its rank and weight in the first draw's weights, and the three largest weights with their
elements' angles to the truth; for the pelvis and the spine, the first draw's error as an angle about an
axis in the truth's part frame (x left-right, y up, z forward).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # experiments/scan_model
sys.path.insert(0, str(HERE.parents[2] / "fitting"))

import acro_eval as ae  # noqa: E402

from arteq.body.skeleton import JOINT_NAMES  # noqa: E402
from arteq.fit import Fitter  # noqa: E402

PARTS = (0, 3, 6, 9, 12, 15)


def angle(a: np.ndarray, b: np.ndarray) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(a.T @ b) - 1) / 2))))


def axis_angle(r: np.ndarray) -> tuple[float, np.ndarray]:
    """Angle (degrees) and unit axis of a rotation (near a half turn: from its symmetric part)."""
    deg = angle(np.eye(3), r)
    if deg > 150:
        m = (r + np.eye(3)) / 2
        i = int(np.argmax(np.diag(m)))
        return deg, m[:, i] / math.sqrt(max(m[i, i], 1e-12))
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return deg, v / (np.linalg.norm(v) + 1e-12)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("sets", nargs="+", help="SET:TEMPLATE, e.g. bends:plough")
    ap.add_argument("--bodies", type=int, default=4)
    ap.add_argument("--json")
    a = ap.parse_args()
    torch.set_num_threads(1)
    fitter = Fitter("anny_scan", anny=False, retries=0, torso_retry=False, refine=False)
    group = fitter.module.net.pose_head.group_rotations.double().numpy()
    seen = {}
    network = fitter._network

    def keep_first(*args, **kw):
        pred = network(*args, **kw)
        seen.setdefault("pred", pred)
        return pred

    fitter._network = keep_first
    rows = []
    for spec in a.sets:
        set_name, _, template = spec.partition(":")
        for s in [s for s in ae.make_scans(a.bodies, ae.SETS[set_name]) if s["template"] == template]:
            seen.clear()
            fitter.fit_points(s["points"])
            g = seen["pred"]["global_rotmats"].double().numpy()  # [draws, 22, 3, 3]
            w = seen["pred"]["rot_weights"].double().numpy()
            t = s["grot"]
            row = {"template": template, "body": s["body"], "age": round(s["age"], 1), "parts": {}}
            print(f"{template} {s['body']} (age {s['age']:.0f})")
            for j in PARTS:
                err = float(np.mean([angle(g[d, j], t[j]) for d in range(len(g))]))
                to_truth = np.array([angle(group[e], t[j]) for e in range(len(group))])
                order = np.argsort(-w[0, j])
                near = int(np.argmin(to_truth))
                rank = int(np.where(order == near)[0][0])
                top = [(round(float(w[0, j, e]), 3), round(float(to_truth[e]), 1)) for e in order[:3]]
                part = {
                    "error_deg": round(err, 1),
                    "nearest_deg": round(float(to_truth[near]), 1),
                    "nearest_rank": rank,
                    "nearest_weight": round(float(w[0, j, near]), 3),
                    "top": top,
                }
                if j < 12:
                    deg, ax = axis_angle(t[j].T @ g[0, j])
                    part["first_draw"] = {"deg": round(deg, 1), "axis": np.round(ax, 2).tolist()}
                row["parts"][JOINT_NAMES[j]] = part
                print(f"  {JOINT_NAMES[j]:8s} {part}", flush=True)
            rows.append(row)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
