"""Probe (nothing in the fitter uses it): does a fitted hand that sinks into the rest of the fitted body
(a thigh, the shins, the other arm's side of the chest) mark a hand fitted in the wrong place? Per hand of
each fit dumped by ``user_scans.py --dump-fits DIR``: the share of its vertices more than 5 mm inside the
rest of the body (signed distance along the nearest other vertex's normal; the own arm and collar left
out), the same for the true mesh, and the hand's true error (mean vertex distance, cm). No refitting.

    python experiments/fitting/user_scans.py --ckpt anny_scan --seed S --json ... --dump-fits /tmp/fitsS
    python experiments/fitting/lost_hand/hand_overlap_probe.py /tmp/fits0 /tmp/fits1 ...
"""

import glob
import sys

import numpy as np
import torch
from scipy.spatial import cKDTree

from arteq.body.factory import create_body
from arteq.body.skeleton import JOINT_NAMES
from arteq.fit.refine import branch_parts
from arteq.geometry.normals import vertex_normals

body = create_body({"name": "anny_allages"})
parts, faces = body.part_labels.numpy(), body.faces
J = {n: i for i, n in enumerate(JOINT_NAMES)}
HANDS = {"left": J["left_wrist"], "right": J["right_wrist"]}
ARM = {s: branch_parts(J[f"{s}_collar"]) + [J[f"{s}_collar"]] for s in HANDS}


def sunk(v: np.ndarray, side: str) -> float:
    """Share of the hand's vertices more than 5 mm inside the rest of the body (not its own arm)."""
    n = vertex_normals(torch.as_tensor(v[None], dtype=torch.float32), faces)[0].numpy()
    hand = parts == HANDS[side]
    idx = np.flatnonzero(~np.isin(parts, ARM[side]))
    nn = idx[cKDTree(v[idx]).query(v[hand])[1]]
    return float((np.einsum("ij,ij->i", v[hand] - v[nn], n[nn]) < -0.005).mean())


rows = []
for folder in sys.argv[1:]:
    for f in sorted(glob.glob(folder + "/*.npz")):
        z = np.load(f)
        fit, truth = z["fit"].astype(np.float64), z["truth"].astype(np.float64)
        for side in HANDS:
            m = parts == HANDS[side]
            err = float(np.linalg.norm(fit[m] - truth[m], axis=1).mean() * 100)
            name = f"{folder.rstrip('/').split('/')[-1]}/{f.split('/')[-1][:-4]}"
            rows.append((name, side, str(z["status"]), err, sunk(fit, side), sunk(truth, side)))
rows.sort(key=lambda r: -r[4])
print("| fit | hand | status | hand error cm | fit: share sunk | truth: share sunk |")
print("|---|---|---|---:|---:|---:|")
for r in rows:
    if r[4] >= 0.05 or r[5] >= 0.05 or r[3] >= 8:
        print(f"| {r[0]} | {r[1]} | {r[2]} | {r[3]:.1f} | {r[4]:.2f} | {r[5]:.2f} |")
lost = [r for r in rows if r[3] >= 8]
good = [r for r in rows if r[3] < 4]
for t in (0.1, 0.2, 0.3, 0.4):
    print(f"\nshare sunk >= {t}: {sum(r[4] >= t for r in lost)} of {len(lost)} hands 8 cm or more off, "
          f"{sum(r[4] >= t for r in good)} of {len(good)} within 4 cm", end="")
print()
