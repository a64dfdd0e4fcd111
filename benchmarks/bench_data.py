"""Data pipeline throughput: training samples/s (5000-point clouds) with 0 and 2 loader workers.

``python benchmarks/bench_data.py [--body anny22] [--num-points 5000] [--batches 20]``

Prints a Markdown table. Other processes share the CPU on a small machine: numbers are indicative.
"""

from __future__ import annotations

import argparse
import time

import torch

from arteq.data import BodyScanDataModule


def bench(body: str, num_points: int, workers: int, batches: int, batch_size: int, augment: str) -> float:
    dm = BodyScanDataModule(
        body_model={"name": body},
        num_points=num_points,
        train_size=batches * batch_size + 2 * batch_size,
        batch_size=batch_size,
        num_workers=workers,
        augment=augment,
    )
    dm.setup("fit")
    loader = dm.train_dataloader()
    it = iter(loader)
    next(it)  # warm-up (worker start, first forward)
    t0 = time.perf_counter()
    n = 0
    for _ in range(batches):
        n += next(it)["points"].shape[0]
    dt = time.perf_counter() - t0
    del it
    return n / dt


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--body", default="anny22")
    ap.add_argument("--num-points", type=int, default=5000)
    ap.add_argument("--batches", type=int, default=20)
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--augment", default="so3")
    args = ap.parse_args()
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, body {args.body}, "
        f"{args.num_points} points, batch {args.batch_size}, augment {args.augment}"
    )
    print("| workers | samples/s | ms/sample |\n|---|---|---|")
    for workers in (0, 2):
        sps = bench(args.body, args.num_points, workers, args.batches, args.batch_size, args.augment)
        print(f"| {workers} | {sps:.1f} | {1000 / sps:.1f} |")


if __name__ == "__main__":
    main()
