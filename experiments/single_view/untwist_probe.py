"""Probe: how far the network's part rotations are from the truth on single views, before and after
:func:`arteq.fit.partial.untwist` (no refinement).

For the scans of ``run.py`` (16 per view, the shipped model), per view: the mean over scans of the mean
geodesic error (degrees) of the 22 parts' global rotations, as predicted and untwisted; the pelvis's error;
and how many parts the untwist turned back per scan. Writes ``results/untwist_probe.json``.

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python experiments/single_view/untwist_probe.py --scans 16
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import roma
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from run import SPLITS, scans  # noqa: E402


def main() -> None:
    from arteq.fit.api import Fitter, resample
    from arteq.fit.partial import untwist

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=16)
    ap.add_argument("--ckpt", default=None)
    args = ap.parse_args()
    torch.set_num_threads(1)
    f = Fitter(ckpt=args.ckpt, device="cpu", anny=False, refine=False)
    body = f.body
    data = scans(args.scans, body)
    flip = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=torch.float64))
    out = []
    print("| view | part error, predicted | part error, untwisted | pelvis error | parts turned back |")
    print("|---|---:|---:|---:|---|")
    for split in SPLITS:
        d = data[split]
        rows = []
        for i in range(args.scans):
            it = f.prepare(d["points"][i].double().numpy())
            x = resample(it["centred"], f.net_points, np.random.default_rng(f.seed))
            with torch.no_grad():
                p = f.module(torch.as_tensor(x, dtype=torch.float32)[None])
                g = body(betas=p["betas"].double(), pose=p["local_rotmats"].double()).global_rotmats[0]
                gt = body(betas=d["betas"][i : i + 1], pose=d["pose"][i : i + 1]).global_rotmats[0].double()
            turned = torch.as_tensor(untwist(g.double().numpy()))
            g = g.double()
            g2 = torch.where(turned[:, None, None], g @ flip, g)
            e1 = roma.rotmat_geodesic_distance(g, gt) * 180 / np.pi
            e2 = roma.rotmat_geodesic_distance(g2, gt) * 180 / np.pi
            rows.append({"index": i, "part_deg": float(e1.mean()), "part_deg_untwisted": float(e2.mean()),
                         "pelvis_deg": float(e1[0]), "turned": int(turned.sum())})  # fmt: skip
        keys = ("part_deg", "part_deg_untwisted", "pelvis_deg")
        m = {k: float(np.mean([r[k] for r in rows])) for k in keys}
        out.append({"split": split, **m, "rows": rows})
        print(f"| {split.replace('test_view_', '')} | {m['part_deg']:.1f} | {m['part_deg_untwisted']:.1f} | "
              f"{m['pelvis_deg']:.1f} | {[r['turned'] for r in rows]} |")  # fmt: skip
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "untwist_probe.json").write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
