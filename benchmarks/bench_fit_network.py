"""The fitter's network pass (``Fitter._network``: a batch of 500-point clouds, the default four draws of
four scans) on CPU: wall, user and kernel seconds and minor page faults per call, with glibc's allocator as
it is (``ARTEQ_MALLOC_TUNE=0``) and tuned (:func:`arteq.runtime.tune_cpu_allocator`, what ``Fitter`` does).

    python benchmarks/bench_fit_network.py [--ckpt anny_scan] [--clouds 16] [--threads 2] [--calls 3]

Each setting runs in a fresh process (the allocator setting is process-wide); one warm-up call first.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import time


def one(args) -> dict:
    import numpy as np
    import torch

    from arteq.fit.api import Fitter

    torch.set_num_threads(args.threads)
    fitter = Fitter(ckpt=args.ckpt, device="cpu", anny=False, second_start=False)
    rng = np.random.default_rng(0)
    clouds = [rng.normal(0, 0.3, (fitter.net_points, 3)) for _ in range(args.clouds)]
    fitter._network(clouds)
    r0, t0 = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
    for _ in range(args.calls):
        fitter._network(clouds)
    r1, wall = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter() - t0
    n = args.calls
    user, kernel, faults = r1.ru_utime - r0.ru_utime, r1.ru_stime - r0.ru_stime, r1.ru_minflt - r0.ru_minflt
    return {"wall_s": wall / n, "user_s": user / n, "sys_s": kernel / n, "minor_faults": faults / n}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--clouds", type=int, default=16)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--calls", type=int, default=3)
    ap.add_argument("--child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        print(json.dumps(one(args)))
        return
    print(f"{args.clouds} clouds, {args.threads} threads, per call:\n")
    print("| allocator | wall s | user s | kernel s | minor faults |")
    print("|---|---:|---:|---:|---:|")
    for label, tune in (("glibc as is", "0"), ("tuned", "1")):
        env = {**os.environ, "ARTEQ_MALLOC_TUNE": tune}
        cmd = [sys.executable, __file__, "--child", "--ckpt", args.ckpt, "--clouds", str(args.clouds),
               "--threads", str(args.threads), "--calls", str(args.calls)]  # fmt: skip
        out = subprocess.run(cmd, env=env, capture_output=True, text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        cells = f"{r['wall_s']:.2f} | {r['user_s']:.2f} | {r['sys_s']:.2f} | {r['minor_faults']:.0f}"
        print(f"| {label} | {cells} |")


if __name__ == "__main__":
    main()
