"""Probe: how far a cluttered scan's fit lies from the clean scan's, and how far the clean scan's own fit
moves with another resampling seed, under refinement settings given on the command line (issue 19's
clutter goal: within 1 cm, mean vertex distance).

    OMP_NUM_THREADS=1 python experiments/fitting/clutter_spread.py [--people 0,1] [--arm NAME:KEY=V,KEY=V ...]

(``net_draws`` and ``second_start`` are Fitter settings, the other keys refinement settings.)

Per arm and body of the user suite's clutter group (``user_scans.people_scans(seed)``, 3 bodies per seed):
V2V of the clean fit to the truth, clean (seed 1) vs clean (seed 0), stray and room vs clean (seed 0), all cm;
and the same for the network alone (``refine=False``) in the first arm, which says how much of the spread
the refinement inherits from its start.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def _d(a, b) -> float:
    return float(np.linalg.norm(a.vertices - b.vertices, axis=1).mean() * 100)


def main() -> None:
    import user_scans as us

    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--people", default="0,1", help="user-suite seeds whose clutter bodies are used")
    ap.add_argument("--arm", action="append", default=[], help="NAME:KEY=VALUE,... refinement settings")
    ap.add_argument("--network", action="store_true", help="also the network alone (refine=False)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    arms = [("default", [])] + [
        (s.split(":", 1)[0], [x for x in s.split(":", 1)[1].split(",") if x]) for s in a.arm
    ]
    bodies = []
    for seed in (int(s) for s in a.people.split(",")):
        scans = [s for s in us.people_scans(seed) if s.group == "clutter"]
        for k in range(0, len(scans), 2):  # stray, room of one body
            bodies.append((f"p{seed} {scans[k].name.split(':')[0]}", scans[k], scans[k + 1]))
    fitter_keys = {"net_draws": int, "second_start": lambda v: False if v in ("0", "false", "no") else v}
    runs = []
    for n, items in arms:  # Fitter settings by name, the rest refinement settings
        kw = {k: fitter_keys[k](v) for k, _, v in (x.partition("=") for x in items) if k in fitter_keys}
        rest = [x for x in items if x.partition("=")[0] not in fitter_keys]
        runs.append((n, dict(refine_config=RefineConfig.from_strings(rest), **kw)))
    if a.network:
        runs = [("network alone", dict(refine=False))] + runs
    for name, kw in runs:
        f0 = Fitter(ckpt="anny_scan", device="cpu", anny=False, points=5000, seed=0, **kw)
        f1 = Fitter(ckpt="anny_scan", device="cpu", anny=False, points=5000, seed=1, **kw)
        rows, t0 = [], time.perf_counter()
        for label, stray, room in bodies:
            c0 = f0.fit_points(stray.clean_points)
            c1 = f1.fit_points(stray.clean_points)
            s0 = f0.fit_points(stray.points)
            r0 = f0.fit_points(room.points)
            v2v = float(np.linalg.norm(c0.vertices - stray.vertices, axis=1).mean() * 100)
            rows.append((label, v2v, _d(c1, c0), _d(s0, c0), _d(r0, c0)))
        print(f"## {name} ({time.perf_counter() - t0:.0f} s)")
        print("| body | V2V clean | clean seed 1 vs 0 | stray vs clean | room vs clean |")
        print("|---|---:|---:|---:|---:|")
        for r in rows:
            print(f"| {r[0]} | " + " | ".join(f"{x:.2f}" for x in r[1:]) + " |")
        m = np.array([r[1:] for r in rows])
        print("| mean | " + " | ".join(f"{x:.2f}" for x in m.mean(0)) + " |")
        print("| worst | " + " | ".join(f"{x:.2f}" for x in m.max(0)) + " |", flush=True)


if __name__ == "__main__":
    main()
