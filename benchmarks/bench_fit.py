"""Accuracy and time of arteq-fit on 5000-point test clouds (not a test: prints markdown tables).

    python benchmarks/bench_fit.py --mode perturbed [--samples 8] [--batch 1]
    python benchmarks/bench_fit.py --mode network [--ckpt anny22] [--samples 16]

``perturbed``: refinement alone, from the ground truth perturbed (every joint rotated --rot rad about a
random axis, betas + --betas sigma, translation --transl m off) with --wrong of the part labels
replaced by random ones; V2V after 0, 10, 20, 30, 40 iterations and seconds per scan.
``network``: the whole pipeline of ``arteq.fit`` (network, then refinement) on the project's own
test_id / test_ood sets (data module, 5000 points): V2V / MPJPE (22 joints) without and with
refinement, network and refinement seconds per scan. Run with one process on an otherwise idle machine
(timings rise 10-20x when another CPU-bound process shares the cores).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import roma
import torch


def refine_config(args):
    """``RefineConfig`` with ``--iters`` and every ``--set KEY=VALUE`` (its fields, e.g. ``sigma_end=2``)."""
    from arteq.fit.refine import RefineConfig

    return RefineConfig.from_strings(args.set, iters=args.iters)


def perturbed(args) -> None:
    from arteq.body import load_body_model
    from arteq.data.dataset import BodyScanDataset
    from arteq.data.poses import SyntheticIDPoses, SyntheticOODPoses
    from arteq.fit.refine import refine

    body = load_body_model("anny22")
    cfg = refine_config(args)
    print(f"| split | start V2V | V2V after 10 / 20 / 30 / {args.iters} it | s per scan (B={args.batch}) |")
    print("|---|---:|---|---:|")
    for split in ("test_id", "test_ood"):
        src = SyntheticOODPoses() if split == "test_ood" else SyntheticIDPoses()
        ds = BodyScanDataset(src, body, split, args.samples, num_points=5000,
                             augment="so3" if split == "test_ood" else "none")  # fmt: skip
        g = torch.Generator().manual_seed(1)
        curves: dict[int, list[float]] = {}
        starts, secs = [], 0.0
        for s0 in range(0, args.samples, args.batch):
            items = [ds[i] for i in range(s0, min(args.samples, s0 + args.batch))]
            b = {k: torch.stack([it[k] for it in items]) for k in items[0]}
            n = b["points"].shape[0]
            lab = b["labels"]
            wrong = torch.rand(lab.shape, generator=g) < args.wrong
            lab = torch.where(wrong, torch.randint(0, 22, lab.shape, generator=g), lab)
            probs = torch.nn.functional.one_hot(lab, 22).float() * 0.7 + 0.3 / 22
            gt = body(betas=b["betas"], pose=b["pose"], transl=b["transl"]).vertices
            axis = torch.nn.functional.normalize(torch.randn(n, 22, 3, generator=g), dim=-1)
            off = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
            init = {
                "local_rotmats": b["pose"] @ roma.rotvec_to_rotmat(axis * args.rot),
                "betas": b["betas"] + args.betas * torch.randn(n, 10, generator=g),
                "transl": b["transl"] + args.transl * off,
            }
            with torch.no_grad():
                v0 = body(betas=init["betas"], pose=init["local_rotmats"], transl=init["transl"]).vertices
            starts += ((v0 - gt).norm(dim=-1).mean(-1) * 100).tolist()

            def cb(it, v, gt=gt, curves=curves):
                curves.setdefault(it, []).extend(((v - gt).norm(dim=-1).mean(-1) * 100).tolist())

            # timing run without the callback, then the curve run
            t0 = time.perf_counter()
            out = refine(body, b["points"], probs, init, cfg)
            secs += time.perf_counter() - t0
            refine(body, b["points"], probs, init, cfg, callback=cb)
            curves.setdefault(cfg.iters, []).extend(
                ((out.vertices - gt).norm(dim=-1).mean(-1) * 100).tolist()
            )
        marks = [10, 20, 30, cfg.iters]
        curve = " / ".join(f"{np.mean(curves[m]):.2f}" for m in marks if m in curves)
        print(f"| {split} | {np.mean(starts):.2f} | {curve} (max {np.max(curves[cfg.iters]):.2f}) "
              f"| {secs / args.samples:.2f} |")  # fmt: skip


def network(args) -> None:
    from arteq.data import BodyScanDataModule
    from arteq.fit.api import Fitter

    rows = []
    for refine_on in (False, True):
        fitter = Fitter(ckpt=args.ckpt, device=args.device, refine=refine_on, points=5000,
                        refine_config=refine_config(args), check=False, anny=False)  # fmt: skip
        dm = BodyScanDataModule(body_model=dict(fitter.module.hparams.body_model), num_points=5000,
                                test_size=args.samples, batch_size=args.batch, num_workers=0)  # fmt: skip
        dm.setup("test")
        body = fitter.body
        for split, loader in zip(("test_id", "test_ood"), dm.test_dataloader()):
            v2v, mpjpe, t_net, t_ref, flagged = [], [], 0.0, 0.0, 0
            for b in loader:
                items = [fitter.prepare(p.double().numpy(), name=f"{split}") for p in b["points"]]
                res = fitter.fit_prepared(items)
                with torch.no_grad():
                    gt = body(betas=b["betas"], pose=b["pose"], transl=b["transl"])
                for i, r in enumerate(res):
                    v2v.append(np.linalg.norm(r.vertices - gt.vertices[i].numpy(), axis=1).mean() * 100)
                    mpjpe.append(np.linalg.norm(r.joints - gt.joints[i].numpy(), axis=1).mean() * 100)
                    t_net += r.timings["network"]
                    t_ref += r.timings["refine"]
                    flagged += bool(r.quality["flags"])
            n = len(v2v)
            rows.append((split, refine_on, np.mean(v2v), np.median(v2v), np.mean(mpjpe), t_net / n, t_ref / n,
                         flagged, n))  # fmt: skip
    print(f"checkpoint: {fitter.checkpoint_id} (network input {fitter.net_points} points)")
    print("| split | refinement | V2V cm (mean / median) | MPJPE cm | network s | refine s | flagged |")
    print("|---|---|---:|---:|---:|---:|---:|")
    for split, r, m, med, j, tn, tr, fl, n in rows:
        on = "yes" if r else "no"
        print(f"| {split} | {on} | {m:.2f} / {med:.2f} | {j:.2f} | {tn:.3f} | {tr:.2f} | {fl}/{n} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--mode", choices=("perturbed", "network"), default="perturbed")
    ap.add_argument("--samples", type=int, default=8)
    ap.add_argument("--batch", type=int, default=1)
    ap.add_argument("--iters", type=int, default=40)
    ap.add_argument("--rot", type=float, default=0.15)
    ap.add_argument("--betas", type=float, default=0.5)
    ap.add_argument("--transl", type=float, default=0.03)
    ap.add_argument("--wrong", type=float, default=0.2)
    ap.add_argument("--ckpt", default=None)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--threads", type=int, default=None)
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="RefineConfig fields")
    args = ap.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    perturbed(args) if args.mode == "perturbed" else network(args)


if __name__ == "__main__":
    main()
