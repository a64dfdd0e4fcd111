"""Probe: the network's left / right split on single views, with the torso's centre where the network finds
it (the centroid of the torso's points), at the true torso's middle (oracle), and moved away from the camera
by ``d`` cm along the fitter's estimated camera direction (``torso_shift``,
:func:`arteq.fit.partial.torso_shift`).

Network alone, the shipped model, the first ``--scans`` scans of each view set (run.py's), each scan as
the fitter prepares it and one draw of 500 points; per view and arm: part accuracy (each point's label
against its nearest scan point's true part) and the share of points given the mirror part of their true one
(a left / right swap). Full scans are not one-sided: no shift (their rows show the oracle only).

    OMP_NUM_THREADS=2 python experiments/single_view/torso_centre_probe.py --scans 16 \\
        > experiments/single_view/torso_middle/centre_probe.txt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from run import scans  # noqa: E402

ORACLE: dict[str, torch.Tensor | None] = {"centre": None}


def main() -> None:
    import arteq.models.arteq_net as net_module
    from arteq.fit.api import Fitter, resample
    from arteq.fit.partial import PARTIAL_SCORE, facing_direction, one_sidedness, torso_shift
    from arteq.models.sides import LEFT_PARTS, RIGHT_PARTS, TORSO_PARTS

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=16)
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--depths-cm", type=int, nargs="*", default=[6, 9, 12, 15])
    args = ap.parse_args()

    frame = net_module.torso_frame

    def oracle_frame(points, weights, rotmats, eps=1e-6, parts=TORSO_PARTS):
        centre, left = frame(points, weights, rotmats, eps, parts)
        return (centre if ORACLE["centre"] is None else ORACLE["centre"].to(centre.dtype)), left

    net_module.torso_frame = oracle_frame
    f = Fitter(ckpt=args.ckpt, device="cpu", anny=False, refine=False)
    body = f.module.body
    data = scans(args.scans, body)
    mirror = np.arange(22)
    mirror[list(LEFT_PARTS)], mirror[list(RIGHT_PARTS)] = RIGHT_PARTS, LEFT_PARTS
    torso = torch.isin(body.part_labels, torch.tensor(TORSO_PARTS))
    print(f"{args.ckpt}, {args.scans} scans per view: part accuracy % / left-right swaps % of the points")
    print("| view | network | oracle | " + " | ".join(f"{d} cm" for d in args.depths_cm) + " |")
    print("|---|" + "---|" * (2 + len(args.depths_cm)))
    for split in ("test_view_full", "test_view_front", "test_view_side", "test_view_back", "test_view_top"):
        d = data[split]
        arms = ["network", "oracle", *args.depths_cm]
        res: dict = {a: [] for a in arms}
        for i in range(args.scans):
            pts = d["points"][i].double().numpy()
            it = f.prepare(pts)
            x = resample(it["centred"], f.net_points, np.random.default_rng(f.seed))
            truth = d["labels"][i].numpy()[cKDTree(pts - it["center"]).query(x)[1]]
            with torch.no_grad():
                gt = body(
                    betas=d["betas"][i : i + 1], pose=d["pose"][i : i + 1], transl=d["transl"][i : i + 1]
                )
            middle = gt.vertices[0][torso].double().mean(0).numpy() - it["center"]
            cloud = resample(it["centred"], 4000, np.random.default_rng(f.seed))  # as the fitter's modes
            score, view = one_sidedness(cloud)
            one_sided = score > PARTIAL_SCORE
            if one_sided:
                view = facing_direction(cloud, view)
            for arm in arms:
                shift = None
                if isinstance(arm, int):
                    if not one_sided:
                        continue
                    shift = torch.tensor(torso_shift(view, arm / 100))[None]
                ORACLE["centre"] = torch.tensor(middle)[None] if arm == "oracle" else None
                with torch.no_grad():
                    p = f.module(torch.as_tensor(x, dtype=torch.float32)[None], torso_shift=shift)
                label = p["part_probs"][0].argmax(-1).numpy()
                res[arm].append(
                    ((label == truth).mean(), ((label != truth) & (label == mirror[truth])).mean())
                )
            ORACLE["centre"] = None
        cells = []
        for arm in arms:
            v = np.array(res[arm])
            cells.append("-" if not len(v) else f"{v[:, 0].mean() * 100:.1f} / {v[:, 1].mean() * 100:.1f}")
        print(f"| {split.replace('test_view_', '')} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
