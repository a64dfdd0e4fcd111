"""Refinement from perturbed ground-truth starts: V2V vs iterations and time (indicative study).

python experiments/fitting/study_refine.py --split test_ood --samples 8 --rot 0.15 --wrong 0.2
"""
import argparse
import time

import roma
import torch

from arteq.body import load_body_model
from arteq.data.dataset import BodyScanDataset
from arteq.data.poses import SyntheticIDPoses, SyntheticOODPoses
from arteq.fitting.refine import RefineConfig, refine

ap = argparse.ArgumentParser()
ap.add_argument("--split", default="test_ood")
ap.add_argument("--samples", type=int, default=8)
ap.add_argument("--points", type=int, default=5000)
ap.add_argument("--rot", type=float, default=0.15, help="rad per joint perturbation")
ap.add_argument("--transl", type=float, default=0.03)
ap.add_argument("--betas", type=float, default=0.5)
ap.add_argument("--wrong", type=float, default=0.2, help="fraction of wrong labels")
ap.add_argument("--outliers", type=float, default=0.0)
ap.add_argument("--batch", type=int, default=1)
ap.add_argument("--set", nargs="*", default=[])
args = ap.parse_args()
torch.set_num_threads(1)
body = load_body_model("anny22")
src = SyntheticOODPoses() if args.split == "test_ood" else SyntheticIDPoses()
ds = BodyScanDataset(src, body, args.split, args.samples, num_points=args.points,
                     augment="so3" if args.split == "test_ood" else "none")
g = torch.Generator().manual_seed(1)
cfg = RefineConfig()
for kv in args.set:
    k, v = kv.split("=")
    setattr(cfg, k, type(getattr(cfg, k))(v))
starts, ends, times = [], [], []
curves = {}
for s in range(0, args.samples, args.batch):
    items = [ds[i] for i in range(s, min(args.samples, s + args.batch))]
    batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    pts, labels = batch["points"], batch["labels"]
    B = pts.shape[0]
    if args.outliers > 0:
        m = int(args.outliers * pts.shape[1])
        lo, hi = pts.amin(1, keepdim=True), pts.amax(1, keepdim=True)
        out = lo + (hi - lo) * torch.rand(B, m, 3, generator=g)
        pts = pts.clone(); pts[:, :m] = out
        labels = labels.clone(); labels[:, :m] = torch.randint(0, 22, (B, m), generator=g)
    wrong = torch.rand(labels.shape, generator=g) < args.wrong
    labels = torch.where(wrong, torch.randint(0, 22, labels.shape, generator=g), labels)
    probs = torch.nn.functional.one_hot(labels, 22).float() * 0.7 + 0.3 / 22
    gt = body(betas=batch["betas"], pose=batch["pose"], transl=batch["transl"])
    axis = torch.nn.functional.normalize(torch.randn(B, 22, 3, generator=g), dim=-1)
    pert = roma.rotvec_to_rotmat(axis * args.rot)
    init = {"local_rotmats": batch["pose"] @ pert,
            "betas": batch["betas"] + args.betas * torch.randn(B, 10, generator=g),
            "transl": batch["transl"] + args.transl * torch.nn.functional.normalize(torch.randn(B, 3, generator=g), dim=-1)}
    def cb(it, v):
        curves.setdefault(it, []).extend(((v - gt.vertices).norm(dim=-1).mean(-1) * 100).tolist())
    with torch.no_grad():
        st = body(betas=init["betas"], pose=init["local_rotmats"], transl=init["transl"]).vertices
    starts += ((st - gt.vertices).norm(dim=-1).mean(-1) * 100).tolist()
    t0 = time.perf_counter()
    res = refine(body, pts, probs, init, cfg, callback=cb if s == 0 or True else None)
    times.append((time.perf_counter() - t0) / B)
    ends += ((res.vertices - gt.vertices).norm(dim=-1).mean(-1) * 100).tolist()
mean = lambda x: sum(x) / len(x)
print(f"start V2V {mean(starts):.2f} cm -> {mean(ends):.2f} cm (max {max(ends):.2f}); {mean(times):.3f} s/scan (incl. callback)")
print("curve:", " ".join(f"{it}:{mean(v):.2f}" for it, v in sorted(curves.items()) if it % 5 == 0 or it == len(curves) - 1))
