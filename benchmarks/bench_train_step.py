"""One full training step (forward + losses + backward + Adam) of the default config, on CPU.

python benchmarks/bench_train_step.py [--points 500 1000 2500 5000] [--steps 6] [--impl fast|reference|both]
python benchmarks/bench_train_step.py --profile            # torch.profiler table of the default step
python benchmarks/bench_train_step.py --old-tree /path/to/older/checkout   # also time that tree's code
python benchmarks/bench_train_step.py --impl fast --old-tree DIR --old-override --override model=arteq_local
    --rounds 3   # (one command) that tree's default network against today's part-local one, interleaved

Each (points, impl) runs in a fresh subprocess so that its peak RSS is its own. The batch is generated
once per run by the project's own datamodule (stage-2 training batches, batch size of the config); the
step is ``module.training_step`` + backward + ``optimizer.step`` exactly as Lightning runs it (no
Lightning loop overhead). ``--impl reference`` runs the backbone's reference implementation (gather-form
group conv, scatter-backward re-indexing, gather 3-NN upsampling: the code before the speed-up,
``arteq.equivariant.reference_ops``), ``fast`` the default. ``--old-tree DIR`` adds rows ``old``: the same
step with the code and configs of another checkout (e.g. a ``git worktree`` of the commit before the
speed-up), its allocator tuned like the other rows where that tree has the tuning (as is before it), in the
same run, so that ratios are measured back to back. Reported:
median seconds per step over ``--steps`` steps after one warm-up step, steps/s, and peak RSS growth
during the steps.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

CONF = str(Path(__file__).resolve().parents[1] / "conf")


def _rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def build(points: int, overrides: list[str], conf: str = CONF):
    from hydra import compose, initialize_config_dir

    from arteq.training.build import build_datamodule, build_module

    with initialize_config_dir(version_base="1.3", config_dir=conf):
        cfg = compose(
            "train",
            overrides=[f"data.num_points={points}", "data.num_workers=0", "data.cache=false", *overrides],
        )
    torch.manual_seed(0)
    dm = build_datamodule(cfg)
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    module = build_module(cfg, stage=2)
    return module, batch


def run_one(points: int, impl: str, steps: int, overrides: list[str], malloc: str, conf: str) -> dict:
    import contextlib

    if impl == "old":  # another checkout's code (on PYTHONPATH): no reference switch
        switch = contextlib.nullcontext()
        if malloc == "tuned":
            try:  # the same allocator as the other rows where that tree has the tuning
                from arteq.runtime import tune_cpu_allocator

                tune_cpu_allocator()
            except ImportError:
                pass
    else:
        from arteq.equivariant import reference_ops
        from arteq.runtime import tune_cpu_allocator

        if malloc == "tuned":
            tune_cpu_allocator()
        switch = reference_ops(impl == "reference")
    module, batch = build(points, overrides, conf)
    opt = torch.optim.Adam(module.net.parameters(), lr=1e-4)
    base = _rss_mb()
    times = []
    with switch:
        for i in range(steps + 1):
            t = time.perf_counter()
            loss = module._step(batch, use_gt_parts=False)[2]["loss"]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if i:
                times.append(time.perf_counter() - t)
    med = statistics.median(times)
    return {
        "step_s": med,
        "steps_per_s": 1.0 / med,
        "peak_mb": _rss_mb() - base,
        "batch": batch["points"].shape[0],
    }


def profile(points: int, overrides: list[str], rows: int) -> None:
    from torch.profiler import ProfilerActivity
    from torch.profiler import profile as tprofile

    from arteq.runtime import tune_cpu_allocator

    tune_cpu_allocator()
    module, batch = build(points, overrides)
    opt = torch.optim.Adam(module.net.parameters(), lr=1e-4)

    def step():
        loss = module._step(batch, use_gt_parts=False)[2]["loss"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()

    step()
    with tprofile(activities=[ProfilerActivity.CPU]) as prof:
        for _ in range(3):
            step()
    print(prof.key_averages().table(sort_by="self_cpu_time_total", row_limit=rows, max_name_column_width=40))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--points", type=int, nargs="+", default=[500, 1000, 2500, 5000])
    ap.add_argument("--steps", type=int, default=6)
    ap.add_argument("--impl", choices=["fast", "reference", "both"], default="both")
    ap.add_argument("--profile", action="store_true", help="profile the default step (first --points value)")
    ap.add_argument("--rows", type=int, default=25)
    ap.add_argument("--override", nargs="*", default=[], help="extra Hydra overrides (e.g. model sizes)")
    ap.add_argument(
        "--malloc",
        choices=["default", "tuned"],
        default="tuned",
        help="glibc allocator: as is, or arteq.runtime.tune_cpu_allocator() (what the entry points do)",
    )
    ap.add_argument("--old-tree", type=Path, help="another checkout: its src/ and conf/ give rows 'old'")
    ap.add_argument(
        "--old-override",
        nargs="*",
        default=None,
        help="Hydra overrides for the --old-tree rows instead of --override (e.g. the old default network "
        "against --override model=arteq_local)",
    )
    ap.add_argument("--rounds", type=int, default=1, help="repeat every row this many times, interleaved")
    ap.add_argument("--conf", default=CONF, help=argparse.SUPPRESS)
    ap.add_argument("--one", nargs=2, metavar=("POINTS", "IMPL"), help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.profile:
        profile(a.points[0], a.override, a.rows)
        return
    if a.one:
        print(json.dumps(run_one(int(a.one[0]), a.one[1], a.steps, a.override, a.malloc, a.conf)))
        return
    impls = ["reference", "fast"] if a.impl == "both" else [a.impl]
    if a.old_tree:
        impls = ["old", *impls]
    print(
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, allocator {a.malloc}, "
        f"median of {a.steps} steps\n"
    )
    base_impl = impls[0]
    print(f"| points | impl | batch | s/step | steps/s | peak MB | speed-up vs {base_impl} |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for n in [p for p in a.points for _ in range(a.rounds)]:
        ref = None
        for impl in impls:
            env = None
            conf = CONF
            if impl == "old":
                env = dict(os.environ, PYTHONPATH=str(a.old_tree.resolve() / "src"))
                conf = str(a.old_tree.resolve() / "conf")
            cmd = [
                sys.executable,
                __file__,
                "--one",
                str(n),
                impl,
                "--steps",
                str(a.steps),
                "--malloc",
                a.malloc,
                "--conf",
                conf,
            ]
            overrides = a.old_override if impl == "old" and a.old_override is not None else a.override
            cmd += ["--override", *overrides]
            out = subprocess.run(cmd, capture_output=True, text=True, check=False, env=env)
            if out.returncode != 0:
                print(f"| {n} | {impl} | failed: {out.stderr.strip().splitlines()[-1]} |||||")
                continue
            r = json.loads(out.stdout.strip().splitlines()[-1])
            if impl == base_impl:
                ref = r["step_s"]
            ratio = f"{ref / r['step_s']:.2f}x" if ref and impl != base_impl else ""
            print(
                f"| {n} | {impl} | {r['batch']} | {r['step_s']:.3f} | {r['steps_per_s']:.2f} | "
                f"{r['peak_mb']:.0f} | {ratio} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
