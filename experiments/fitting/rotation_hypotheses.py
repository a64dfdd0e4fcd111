"""Probe: does fitting from several rotated copies of a scan, keeping the best-fitting one, help?

    PYTHONPATH=src OMP_NUM_THREADS=1 python experiments/fitting/rotation_hypotheses.py --k 8 --n 16 [--refine]

The network is equivariant to the 60 rotations of its group only; in other rotations its prediction
changes. For each test cloud (the project's test sets, 5000 points, shipped model) the network sees the
cloud in ``k`` orientations (the identity and ``k - 1`` random rotations, fixed seed); each prediction
(refined with ``--refine``, in its own frame) is rotated back and scored against the scan alone
(symmetric Chamfer: scan -> body vertex subset, body subset -> scan with the worst 15 % dropped).
Printed per split, mean V2V in cm: the identity's (what ``arteq-fit`` does), the best of the ``k``
(oracle, needs ground truth), the one the score picks, and the mean over the ``k``; the picked one's
median; seconds per scan.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import roma
import torch
from scipy.spatial import cKDTree

from arteq.data import BodyScanDataModule
from arteq.fit.api import Fitter, resample
from arteq.fit.refine import RefineConfig, refine


def score(scan: torch.Tensor, verts: torch.Tensor, subset: torch.Tensor) -> torch.Tensor:
    """Symmetric Chamfer distance of ``verts [K, V, 3]`` (its ``subset``) to ``scan [N, 3]`` -> ``[K]``."""
    s = scan[None, ::5].expand(verts.shape[0], -1, -1)
    v = verts[:, subset]
    d_sv = torch.cdist(s, v).min(-1).values.mean(-1)
    d_vs = torch.cdist(v, s).min(-1).values.sort(-1).values
    return d_sv + d_vs[:, : int(0.85 * d_vs.shape[1])].mean(-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--k", type=int, default=8)
    ap.add_argument("--n", type=int, default=16)
    ap.add_argument("--refine", action="store_true")
    ap.add_argument("--ckpt", default="anny22")
    args = ap.parse_args()
    torch.set_num_threads(1)
    f = Fitter(ckpt=args.ckpt, device="cpu", refine=False, points=5000, check=False, anny=False)
    dm = BodyScanDataModule(body_model=dict(f.module.hparams.body_model), num_points=5000,
                            test_size=args.n, batch_size=args.n, num_workers=0)  # fmt: skip
    dm.setup("test")
    body, subset = f.body, torch.as_tensor(f.subset)
    rots = torch.cat(
        [torch.eye(3)[None], roma.random_rotmat(args.k - 1, generator=torch.Generator().manual_seed(0))]
    )
    rots = rots.double()
    print(f"checkpoint {f.checkpoint_id}, k={args.k}, refine={args.refine}")
    print(
        "| split | identity | oracle best of k | picked by score | mean of k | picked, median | s per scan |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|")
    for split, loader in zip(("test_id", "test_ood"), dm.test_dataloader()):
        b = next(iter(loader))
        with torch.no_grad():
            gt = body(betas=b["betas"], pose=b["pose"], transl=b["transl"]).vertices.double()
        rows, t0 = [], time.time()
        for i in range(args.n):
            it = f.prepare(b["points"][i].double().numpy())
            rng = np.random.default_rng(0)
            x = resample(it["centred"], f.net_points, rng)
            xr = resample(it["centred"], 5000, rng)
            with torch.no_grad():
                p = f.module((torch.as_tensor(x)[None] @ rots.transpose(1, 2)).float())
            if args.refine:
                probs = p["part_probs"].double()[:, cKDTree(x).query(xr)[1]]
                init = {"local_rotmats": p["local_rotmats"], "betas": p["betas"], "transl": p["transl"]}
                xrs = torch.as_tensor(xr)[None] @ rots.transpose(1, 2)
                v = refine(body, xrs, probs, init, RefineConfig()).vertices.double()
            else:
                with torch.no_grad():
                    v = body(betas=p["betas"].double(), pose=p["local_rotmats"].double(),
                             transl=p["transl"].double()).vertices.double()  # fmt: skip
            v = v @ rots  # each back to the scan's frame
            v2v = (v - (gt[i] - torch.as_tensor(it["center"]))).norm(dim=-1).mean(-1) * 100
            pick = score(torch.as_tensor(it["centred"]), v, subset).argmin()
            rows.append((v2v[0].item(), v2v.min().item(), v2v[pick].item(), v2v.mean().item()))
        r = np.array(rows)
        m = r.mean(0)
        print(f"| {split} | {m[0]:.2f} | {m[1]:.2f} | {m[2]:.2f} | {m[3]:.2f} | {np.median(r[:, 2]):.2f} | "
              f"{(time.time() - t0) / args.n:.1f} |")  # fmt: skip


if __name__ == "__main__":
    main()
