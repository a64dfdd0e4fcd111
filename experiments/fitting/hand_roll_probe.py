"""Probe: is a hand's roll about its forearm what the refined fits get wrong, and does the scan tell?

    OMP_NUM_THREADS=1 python experiments/fitting/hand_roll_probe.py > experiments/fitting/hand_roll_probe.txt

The 8 everyday adults of the check's labelled set (seed 0; experiments/fitting/check_calibration.py), fitted
by ``anny_scan`` through the public API with the hand-roll search off (``twist_at=-1``; crossed-limb step
off). Per hand: its V2V, then for each of 12 turns about the forearm (elbow -> wrist axis, 30 deg apart)
``angle:score/V2V``: score = the mean distance (cm, capped at 5) of the hand's 150 evenly spread vertices
(``BodyTables.branch_subset``) to the scan, V2V = the hand's vertices against the truth (cm). ``*`` marks
the turn :func:`arteq.fit.refine.twist_search` would keep (best score, 0.15 cm lower than at 0 deg, at most
2.5 cm).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from check_calibration import labelled_set

    from arteq.body.skeleton import JOINT_NAMES, PARENTS
    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig, body_tables

    torch.set_num_threads(1)
    items = [it for it in labelled_set(0) if it["group"] == "everyday adults"]
    f = Fitter(ckpt="anny_scan", device="cpu", check=False, anny=False, crossing=False,
               refine_config=RefineConfig(twist_at=-1))  # fmt: skip
    tables = body_tables(f.body)
    for it in items:
        r = f.fit_points(it["points"], name=it["name"])
        scan = cKDTree(it["points"])
        for side in ("left", "right"):
            j = JOINT_NAMES.index(f"{side}_wrist")
            hand = f.vertex_parts == j
            sub = tables.branch_subset(j).numpy()
            pivot = r.joints[j]
            axis = pivot - r.joints[PARENTS[j]]
            axis = axis / np.linalg.norm(axis)
            cells = []
            for k in range(12):
                turn = roma.rotvec_to_rotmat(torch.as_tensor(axis * k * np.pi / 6)).numpy()
                moved = (r.vertices - pivot) @ turn.T + pivot
                score = np.minimum(scan.query(moved[sub])[0] * 100, 5.0).mean()
                err = np.linalg.norm(moved[hand] - it["vertices"][hand], axis=1).mean() * 100
                cells.append((score, err))
            best = int(np.argmin([c[0] for c in cells]))
            keep = best != 0 and cells[0][0] - cells[best][0] >= 0.15 and cells[best][0] <= 2.5
            row = " ".join(f"{k * 30}:{s:.2f}/{e:.0f}{'*' if keep and k == best else ''}" for k, (s, e) in
                           enumerate(cells))  # fmt: skip
            print(f"{it['name']} {side:5s} V2V {cells[0][1]:5.1f} | {row}", flush=True)


if __name__ == "__main__":
    main()
