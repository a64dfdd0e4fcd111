"""How far the estimated camera direction of a single-view scan is from the simulator's camera (degrees):
``one_sidedness``'s estimate and ``facing_direction``'s refinement of it, per view. The scans are the cached
view test sets (``run.py``'s), each regenerated once to read its camera (and checked against the cache).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/direction_probe.py --scans 32 \
        --out experiments/single_view/facing/direction_probe.md
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def cameras(body, n: int, split: str) -> list[np.ndarray]:
    """The simulator's camera of each of the first ``n`` scans of ``split``, in the scans' (centred) frame."""
    import arteq.data.single_view as sv
    from arteq.data import BodyScanDataModule

    dm = BodyScanDataModule(body_model=body, num_points=5000, test_size=n, view_splits=list(sv.VIEW_SPLITS))
    ds = dm.make_dataset(split)
    seen, orig = [], sv.single_view_scan

    def record(*args, **kwargs):
        out = orig(*args, **kwargs)
        seen.append(out["camera"].double().numpy())
        return out

    sv.single_view_scan = record
    try:
        out = []
        for i in range(n):
            seen.clear()
            item = ds[i]
            out.append((seen[0] - item["center"].double().numpy(), item["points"]))
    finally:
        sv.single_view_scan = orig
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--scans", type=int, default=32)
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    import run

    from arteq.fit.api import Fitter
    from arteq.fit.api import resample
    from arteq.fit.partial import facing_direction, one_sidedness

    body = Fitter(ckpt=a.ckpt, device="cpu", anny=False, refine=False).module.body
    data = run.scans(a.scans, body)

    def angle(x, y):
        return float(np.degrees(np.arccos(np.clip(x @ y / np.linalg.norm(x) / np.linalg.norm(y), -1, 1))))

    lines = ["| view | scans | one_sidedness median / mean / worst | facing_direction median / mean / worst | "
             "better / worse by > 2 deg | s per scan (facing_direction) |", "|---|---|---|---|---|---|"]  # fmt: skip
    for view in ("front", "side", "back", "top"):
        split = f"test_view_{view}"
        first, refined, secs = [], [], []
        for i, (cam, pts) in enumerate(cameras(body, a.scans, split)):
            assert torch.allclose(pts, data[split]["points"][i], atol=1e-5), "regenerated scan differs"
            p = pts.double().numpy()
            to_cam = cam - p.mean(0)
            cloud = resample(p - p.mean(0), 4000, np.random.default_rng(0))  # as the fitter does (uncleaned)
            _, d0 = one_sidedness(cloud)
            t = time.perf_counter()
            d1 = facing_direction(cloud, d0)
            secs.append(time.perf_counter() - t)
            first.append(angle(d0, to_cam))
            refined.append(angle(d1, to_cam))
        f, r = np.array(first), np.array(refined)
        row = (f"| {view} | {a.scans} | {np.median(f):.1f} / {f.mean():.1f} / {f.max():.1f} | "
               f"{np.median(r):.1f} / {r.mean():.1f} / {r.max():.1f} | {(r < f - 2).sum()} / {(r > f + 2).sum()} | "
               f"{np.median(secs):.3f} |")  # fmt: skip
        lines.append(row)
        print(row, flush=True)
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).write_text(f"`{' '.join(sys.argv)}`\n\n{text}")


if __name__ == "__main__":
    main()
