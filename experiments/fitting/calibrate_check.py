"""Quality-check values on positives (one body: noise, 10 % outliers, ID/OOD) and negatives (two bodies,
sphere, box, half a body, body x0.5 / x2), each refined from the best start available (the ground
truth of one body, perturbed), so the numbers measure the criterion, not the network.

python experiments/fitting/calibrate_check.py [--n 6]
"""

import argparse

import numpy as np
import roma
import torch

from arteq.body import load_body_model
from arteq.fit.demo import synthetic_scan
from arteq.fit.quality import fit_quality
from arteq.fit.refine import RefineConfig, body_tables, refine

ap = argparse.ArgumentParser()
ap.add_argument("--n", type=int, default=6)
args = ap.parse_args()
torch.set_num_threads(1)
body = load_body_model("anny22")
subset = body_tables(body).m2s_subset.numpy()
parts = body.part_labels.numpy()


def start_from(s, rng, scale=1.0):
    pose = torch.as_tensor(s["pose"], dtype=torch.float32)[None]
    pert = roma.rotvec_to_rotmat(torch.as_tensor(rng.normal(0, 0.1, (1, 22, 3)), dtype=torch.float32))
    return {
        "local_rotmats": pose @ pert,
        "betas": torch.as_tensor(s["betas"] + rng.normal(0, 0.3, 10), dtype=torch.float32)[None],
        "transl": torch.as_tensor(s["transl"] + rng.normal(0, 0.02, 3), dtype=torch.float32)[None],
    }


def run(points, s, rng, labels):
    c = points.mean(0)
    st = start_from(s, rng)
    st["transl"] = st["transl"] - torch.as_tensor(c, dtype=torch.float32)
    lab = np.where(labels < 0, rng.integers(0, 22, len(labels)), labels)
    wrong = rng.random(len(lab)) < 0.2
    lab = np.where(wrong, rng.integers(0, 22, len(lab)), lab)
    probs = np.eye(22)[lab] * 0.7 + 0.3 / 22
    pts = torch.as_tensor(points - c, dtype=torch.float32)[None]
    out = refine(body, pts, torch.as_tensor(probs, dtype=torch.float32)[None], st, RefineConfig())
    return fit_quality(
        points - c, out.vertices[0].double().numpy(), parts, subset, out.betas[0].numpy(), probs
    )


rows = []
for i in range(args.n):
    rng = np.random.default_rng(i)
    split = "test_ood" if i % 2 else "test_id"
    s = synthetic_scan(body, split, i, 5000, offset=0.0)
    rows.append(("one body", run(s["points"], s, rng, s["labels"])))
    so = synthetic_scan(body, split, i, 5000, offset=0.0, outliers=0.1)
    rows.append(("one body, 10% outliers", run(so["points"], so, rng, so["labels"])))
    s2 = synthetic_scan(body, split, i + 100, 5000, offset=0.0)
    side = np.array([0.9, 0.0, 0.0]) @ s2["rotation"].T
    both = np.concatenate([s["points"][::2], s2["points"][::2] + side])
    rows.append(
        ("two bodies 0.9 m apart", run(both, s, rng, np.concatenate([s["labels"][::2], -np.ones(2500, int)])))
    )
    sph = rng.normal(size=(5000, 3))
    sph = sph / np.linalg.norm(sph, axis=1, keepdims=True) * 0.5 + s["vertices"].mean(0)
    rows.append(("sphere r=0.5 m", run(sph, s, rng, -np.ones(5000, int))))
    box = trimesh_box = None
    import trimesh

    box = trimesh.creation.box(extents=(0.5, 1.7, 0.3))
    bp, _ = trimesh.sample.sample_surface(box, 5000, seed=i)
    rows.append(
        ("box 0.5x1.7x0.3 m", run(np.asarray(bp) + s["vertices"].mean(0), s, rng, -np.ones(5000, int)))
    )
    up = s["vertices"] - s["vertices"].mean(0)
    keep = (s["points"] - s["vertices"].mean(0)) @ (
        up[np.argmax(up @ np.ones(3))] / np.linalg.norm(up[np.argmax(up @ np.ones(3))])
    ) > 0
    rows.append(("half a body", run(s["points"][keep], s, rng, s["labels"][keep])))
    for f in (0.5, 2.0):
        sc = s["points"] * f
        rows.append((f"body x{f}", run(sc, s, rng, s["labels"])))
keys = ["inlier_frac", "rmse_in_cm", "coverage", "parts_covered", "max_abs_beta", "extent_m"]
print("| case | n | " + " | ".join(keys) + " | flagged |")
print("|---|---:|" + "---:|" * len(keys) + "---:|")
for case in dict.fromkeys(r[0] for r in rows):
    qs = [q for c, q in rows if c == case]
    cells = []
    for k in keys:
        v = [q[k] for q in qs]
        cells.append(f"{min(v):.3g}..{max(v):.3g}")
    flagged = sum(bool(q["flags"]) for q in qs)
    flags = sorted({f for q in qs for f in q["flags"]})
    print(f"| {case} | {len(qs)} | " + " | ".join(cells) + f" | {flagged}/{len(qs)} {' '.join(flags)} |")
