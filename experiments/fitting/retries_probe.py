"""Retries (``Fitter(retries=K)``) on the user-scan suite's acrobatic, children and adults groups: each scan's
V2V, status and retry record (every fit's surface score, the one kept), one JSON line per scan.

    OMP_NUM_THREADS=1 python experiments/fitting/retries_probe.py --seed 0 \
        > experiments/fitting/retries/suite_seed0.jsonl

Made experiments/fitting/retries/suite_seed{0,1}.jsonl (experiments/fitting/retries.md); the same scans as
``user_scans.py --seed S`` (the Anny export off: V2V does not depend on it).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from user_scans import people_scans

    from arteq.fit import Fitter

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0, help="seed of the suite's scans")
    ap.add_argument("--retries", type=int, default=3)
    ap.add_argument("--retry-above", type=float, default=None, help="cm (default: the Fitter's)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    scans = [s for s in people_scans(a.seed) if s.group in ("acrobatic", "adults", "children")]
    f = Fitter(ckpt="anny_scan", device="cpu", anny=False, retries=a.retries, retry_above_cm=a.retry_above)
    for sc in scans:
        t = time.perf_counter()
        r = f.fit_points(sc.points, name=sc.name)
        v2v = (
            None
            if r.vertices is None
            else float(np.linalg.norm(r.vertices - sc.vertices, axis=1).mean() * 100)
        )
        row = {"group": sc.group, "name": sc.name, "v2v": v2v and round(v2v, 2), "status": r.status,
               "retry": r.retry, "t": round(time.perf_counter() - t, 2)}  # fmt: skip
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
