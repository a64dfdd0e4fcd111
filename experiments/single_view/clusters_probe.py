"""What the clean-up's cluster step removes from held-out single-view scans given as bare points (no camera
position), with and without the one-sided rule (``CleanConfig.one_sided_views``): per scan the points taken
for separate objects, their true parts, and the ``second_body`` flag. Run from the repository root::

    OMP_NUM_THREADS=1 python experiments/single_view/clusters_probe.py --scans 32 --out experiments/single_view/readings/clusters_probe.md
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch

from arteq.body.skeleton import JOINT_NAMES
from arteq.fit.clean import CODES, CleanConfig, clean_scan

HERE = Path(__file__).resolve().parent


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=32, help="scans per view")
    ap.add_argument("--ckpt", default="anny_scan", help="the model whose body the sets are made on")
    ap.add_argument("--splits", nargs="*", default=["front", "side", "back", "top"])
    ap.add_argument("--out", default=None, help="write the table here (markdown)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    import sys

    sys.path.insert(0, str(HERE))
    from run import scans

    from arteq.fit.api import Fitter

    body = Fitter(ckpt=args.ckpt, device="cpu", anny=False, refine=False).module.body
    data = scans(args.scans, body)
    lines = [
        f"# Separate clusters removed from single views without their camera ({args.ckpt}'s body, "
        f"{args.scans} scans per view)",
        "",
        "Written by `experiments/single_view/clusters_probe.py` (its docstring has the command). Per scan with "
        "anything removed as a separate cluster: points removed without / with the one-sided rule, the true "
        "parts of those removed without it (parts with >= 5 points), flags, seconds of `clean_scan` "
        "without / with.",
        "",
        "| view | scan | removed, rule off | removed, rule on | true parts (rule off) | flags (on) | s off / on |",
        "|---|---:|---:|---:|---|---|---|",
    ]
    totals = {}
    for view in args.splits:
        d = data[f"test_view_{view}"]
        tot = [0, 0, 0]
        for i in range(args.scans):
            pts, labels = d["points"][i].double().numpy(), d["labels"][i].numpy()
            t0 = time.perf_counter()
            off = clean_scan(pts, CleanConfig(one_sided_views=False))
            t1 = time.perf_counter()
            on = clean_scan(pts)
            t2 = time.perf_counter()
            a, b = off.codes == CODES["cluster"], on.codes == CODES["cluster"]
            if not (a.any() or b.any()):
                continue
            tot[0] += int(a.sum())
            tot[1] += int(b.sum())
            tot[2] += 1
            parts, cnt = np.unique(labels[a], return_counts=True)
            names = ", ".join(f"{JOINT_NAMES[p]} {c}" for p, c in zip(parts, cnt) if c >= 5)
            lines.append(f"| {view} | {i} | {a.sum()} | {b.sum()} | {names} | {','.join(on.flags)} | "
                         f"{t1 - t0:.3f} / {t2 - t1:.3f} |")  # fmt: skip
        totals[view] = tot
    lines += [
        "",
        "| view | scans with clusters removed | points removed, rule off | rule on |",
        "|---|---:|---:|---:|",
    ]
    lines += [f"| {v} | {t[2]} of {args.scans} | {t[0]} | {t[1]} |" for v, t in totals.items()]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text)


if __name__ == "__main__":
    main()
