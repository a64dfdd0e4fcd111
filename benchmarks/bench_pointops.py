"""Point-op timings against the simplest correct implementation (CPU). Prints a Markdown table.

python benchmarks/bench_pointops.py [--repeats 2]
"""

from __future__ import annotations

import argparse
import time

import torch

from arteq.geometry.pointops import _fps_torch, ball_query, farthest_point_sample, knn, three_nn_interpolate


def _time(fn, repeats):
    best = float("inf")
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best * 1e3


def knn_full_sort(q: torch.Tensor, r: torch.Tensor, k: int) -> torch.Tensor:
    return torch.cdist(q.double(), r.double()).argsort(-1)[..., :k]


def interp_simple(q, r, f):
    d, i = torch.cdist(q.double(), r.double()).square().topk(3, largest=False)
    w = 1 / (d + 1e-8)
    w = (w / w.sum(-1, keepdim=True)).to(f.dtype)
    g = torch.stack([f[b][i[b]] for b in range(f.shape[0])])
    return (g * w[..., None, None]).sum(2)


def rows_for(b: int, repeats: int) -> list[tuple]:
    x = torch.rand(b, 5000, 3)
    c = x[:, :1250]
    f = torch.randn(b, 1250, 60, 64)
    return [
        (
            f"FPS 5000 -> 2500, B={b}",
            "plain torch float64 loop",
            _time(lambda: _fps_torch(x.double(), torch.zeros(b, dtype=torch.long), 2500), repeats),
            "farthest_point_sample (numpy loop on CPU)",
            _time(lambda: farthest_point_sample(x, 2500), repeats),
        ),
        (
            f"kNN 1250 x 5000, k=32, B={b}",
            "cdist + full argsort",
            _time(lambda: knn_full_sort(c, x, 32), repeats),
            "torch chunked topk",
            _time(lambda: knn(c, x, 32, backend="torch"), repeats),
        ),
        (
            f"kNN 1250 x 5000, k=32, B={b}",
            "cdist + full argsort",
            None,
            "scipy cKDTree (auto)",
            _time(lambda: knn(c, x, 32, backend="scipy"), repeats),
        ),
        (
            f"ball query 2500 x 5000, r=0.08, k=64, B={b}",
            "cdist + full argsort",
            _time(lambda: knn_full_sort(x[:, :2500], x, 64), repeats),
            "ball_query (auto)",
            _time(lambda: ball_query(x[:, :2500], x, 0.08, 64), repeats),
        ),
        (
            f"3-NN interp 5000 <- 1250, 60x64 feats, B={b}",
            "cdist + topk + stack",
            _time(lambda: interp_simple(x, c, f), repeats),
            "three_nn_interpolate",
            _time(lambda: three_nn_interpolate(x, c, f), repeats),
        ),
    ]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=2)
    a = ap.parse_args()
    torch.manual_seed(0)
    rows = [r for b in (1, 8) for r in rows_for(b, a.repeats)]
    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, best of {a.repeats}\n")
    print("| op | simplest | ms | ours | ms | speed-up |\n|---|---|---|---|---|---|")
    for op, sname, st, oname, ot in rows:
        s = "" if st is None else f"{st:.0f}"
        sp = "" if st is None else f"{st / ot:.1f}x"
        print(f"| {op} | {sname if st is not None else '(as above)'} | {s} | {oname} | {ot:.0f} | {sp} |")


if __name__ == "__main__":
    main()
