"""Per-batch FPS cost in a loader worker (``data.fps_points``, :class:`arteq.data.FpsCollate`) against in
the training step (the backbone's own FPS), at paper scale (5000 -> 2500 points, batch 8). CPU only.
Prints a Markdown table of process CPU time (1 thread) and wall time.

python benchmarks/bench_fps_workers.py [--repeats 3] [--batch 8] [--points 5000]   (the torch loop: once)

Rows: what one worker spends per batch on generating its samples (anny22 body) and collating them with
and without FPS, and what the step spends on FPS without precomputed indices (the CPU numpy loop; on a
GPU, the torch loop of ``points / 2`` sequential steps, about 4 small kernels each, see benchmarks/README.md)
and with them (shape / range checks and a slice).
"""

from __future__ import annotations

import argparse
import time

import torch
from torch.utils.data import default_collate

from arteq.data import BodyScanDataModule, FpsCollate
from arteq.equivariant import EquivariantBackbone
from arteq.geometry.pointops import _fps_torch, centroid_nearest_index


def _time(fn, repeats: int) -> tuple[float, float]:
    """(CPU ms, wall ms) of the call with the least CPU time: CPU time is what a worker or the step pays,
    and it holds on a shared machine where wall time depends on the other jobs."""
    best = (float("inf"), float("inf"))
    for _ in range(repeats):
        c, t = time.process_time(), time.perf_counter()
        fn()
        best = min(best, (time.process_time() - c, time.perf_counter() - t))
    return best[0] * 1e3, best[1] * 1e3


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--points", type=int, default=5000)
    a = ap.parse_args()
    torch.set_num_threads(1)  # as in a loader worker
    dm = BodyScanDataModule(body_model={"name": "anny22"}, num_points=a.points, train_size=64, cache=False)
    ds = dm.make_dataset("train")
    items = [ds[i] for i in range(a.batch)]
    bb = EquivariantBackbone()  # the paper's backbone: strides 2, 1, 2, 1
    m = bb.fps_size(a.points)
    collate = FpsCollate(m)
    batch = collate(items)
    pts, idx = batch["points"], batch["fps_idx"]
    assert torch.equal(idx, bb.compute_fps(pts))

    def given():  # the backbone's handling of a given fps_idx (checks + slice), as in forward
        if idx.dim() != 2 or idx.shape[0] != pts.shape[0] or idx.shape[1] < m or idx.dtype != torch.long:
            raise AssertionError
        sel = idx[:, :m]
        assert int(sel.min()) >= 0 and int(sel.max()) < a.points

    start = centroid_nearest_index(pts)
    rows = [
        ("worker", f"generate {a.batch} samples (BodyScanDataset, anny22)",
         _time(lambda: [ds[i] for i in range(a.batch)], max(1, a.repeats - 1))),
        ("worker", "default collate", _time(lambda: default_collate(items), a.repeats)),
        ("worker", f"FpsCollate({m}): collate + FPS", _time(lambda: collate(items), a.repeats)),
        ("step", "backbone FPS, no fps_idx (numpy loop, CPU)", _time(lambda: bb.compute_fps(pts), a.repeats)),
        ("step", "backbone FPS, torch loop (the GPU path, run on CPU)",
         _time(lambda: _fps_torch(pts.double(), start, m), 1)),
        ("step", "fps_idx given: checks + slice", _time(given, a.repeats)),
    ]  # fmt: skip
    print(
        f"torch {torch.__version__}, 1 thread, B={a.batch}, {a.points} -> {m} points, best of {a.repeats}\n"
    )
    print("| where | what | CPU ms per batch | wall ms |\n|---|---|---:|---:|")
    for where, what, (cpu, wall) in rows:
        print(f"| {where} | {what} | {cpu:.2f} | {wall:.2f} |")


if __name__ == "__main__":
    main()
