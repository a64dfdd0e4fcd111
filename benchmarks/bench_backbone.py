"""EquivariantBackbone speed and peak memory on CPU; prints a Markdown table.

python benchmarks/bench_backbone.py [--repeats 1]

Each configuration runs in a fresh subprocess so that its peak RSS (ru_maxrss, minus the RSS after
building the model and inputs) is its own. Times are the best of ``--repeats`` runs after no warm-up.
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time

import torch

CONFIGS = [("paper24", 8, 1000), ("ico13", 8, 1000), ("paper24", 2, 5000), ("ico13", 2, 5000)]


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_one(kernel: str, b: int, n: int, mode: str, repeats: int) -> dict:
    from arteq.equivariant import EquivariantBackbone

    torch.manual_seed(0)
    m = EquivariantBackbone(kernel=kernel)
    x = torch.rand(b, n, 3) * torch.tensor([0.6, 0.3, 1.7])  # body-sized box, metres
    fps = m.compute_fps(x)
    base = _rss_mb()
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        if mode == "fwd":
            with torch.no_grad():
                m(x, fps_idx=fps)
        else:
            m(x, fps_idx=fps).square().mean().backward()
        best = min(best, time.perf_counter() - t)
    return {"time_s": best, "peak_mb": _rss_mb() - base, "params": sum(p.numel() for p in m.parameters())}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=1)
    ap.add_argument("--one", nargs=4, metavar=("KERNEL", "B", "N", "MODE"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:
        k, b, n, mode = a.one
        print(json.dumps(run_one(k, int(b), int(n), mode, a.repeats)))
        return
    print(f"torch {torch.__version__}, {torch.get_num_threads()} threads, best of {a.repeats}\n")
    print("| kernel | B | N | params | fwd s | fwd peak MB | fwd+bwd s | fwd+bwd peak MB |")
    print("|---|---|---|---|---|---|---|---|")
    for kernel, b, n in CONFIGS:
        res = {}
        for mode in ("fwd", "fwdbwd"):
            cmd = [
                sys.executable,
                __file__,
                "--repeats",
                str(a.repeats),
                "--one",
                kernel,
                str(b),
                str(n),
                mode,
            ]
            res[mode] = json.loads(subprocess.run(cmd, check=True, capture_output=True, text=True).stdout)
        f, fb = res["fwd"], res["fwdbwd"]
        print(
            f"| {kernel} | {b} | {n} | {f['params']:,} | {f['time_s']:.1f} | {f['peak_mb']:.0f} | "
            f"{fb['time_s']:.1f} | {fb['peak_mb']:.0f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
