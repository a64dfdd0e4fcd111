"""Scale on paper: FLOPs and peak tensor memory per sample of an ArtEq training step, 500..5000 points.

    python benchmarks/bench_scale.py                       # default + paper configs, all point counts
    python benchmarks/bench_scale.py --configs paper --points 5000 --forward-only
    python benchmarks/bench_scale.py --table results.jsonl # Markdown table + GPU estimates from saved rows

For each configuration (``default`` = conf/model/arteq.yaml as trained on CPU; ``paper`` =
``+experiment=paper``) and point count, one cloud (B = 1) goes through the stage-2 training step
(network + body model + placement + losses, then backward):

- FLOPs: ``torch.utils.flop_counter.FlopCounterMode`` (matrix products, einsum, attention; elementwise
  work such as the kernel-weight formation, gathers and norms is not counted);
- peak memory: the largest total of live tensor storages allocated during the step (activations, saved
  tensors, gradients; parameters and optimizer state excluded: they are per model, not per sample), from a
  dispatch-mode tracker (device-independent; what a GPU's caching allocator adds is not included);
- time: one un-instrumented step on this CPU, as process CPU time (wall time also saved; 2 shared cores:
  compare rows, not machines).

Rows are appended as JSON lines to ``--out`` (default benchmarks/results/bench_scale.jsonl).
"""

from __future__ import annotations

import argparse
import json
import math
import time
import weakref
from pathlib import Path

import torch
from torch.utils._python_dispatch import TorchDispatchMode
from torch.utils._pytree import tree_flatten
from torch.utils.flop_counter import FlopCounterMode

ROOT = Path(__file__).resolve().parents[1]


class PeakTensorMemory(TorchDispatchMode):
    """Peak of the total bytes of live tensor storages created inside the mode (views counted once)."""

    def __init__(self) -> None:
        super().__init__()
        self.current = 0
        self.peak = 0

    def _free(self, nbytes: int) -> None:
        self.current -= nbytes

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        out = func(*args, **(kwargs or {}))
        for t in tree_flatten(out)[0]:
            if not isinstance(t, torch.Tensor) or t.device.type == "meta":
                continue
            storage = t.untyped_storage()
            if getattr(storage, "_bench_tracked", False):
                continue
            storage._bench_tracked = True
            n = storage.nbytes()
            self.current += n
            self.peak = max(self.peak, self.current)
            weakref.finalize(storage, self._free, n)
        return out


def compose_cfg(config: str, points: int):
    from hydra import compose, initialize_config_dir

    overrides = [f"data.num_points={points}", "paths.output_dir=/tmp/unused"]
    if config == "paper":
        overrides.insert(0, "+experiment=paper")
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose("train", overrides=overrides)


def one_batch(cfg, points: int, batch: int = 1) -> dict[str, torch.Tensor]:
    from arteq.training.build import build_datamodule

    dm = build_datamodule(cfg)
    ds = dm.make_dataset("train")
    samples = [ds[i] for i in range(batch)]
    return {k: torch.stack([s[k] for s in samples]) for k in samples[0]}


def sample_time(cfg, n: int = 4) -> float:
    """CPU seconds to generate one training cloud on one thread (what a data worker does)."""
    from arteq.training.build import build_datamodule

    ds = build_datamodule(cfg).make_dataset("train")
    ds[0]  # warm-up (body model, caches)
    t0 = time.process_time()  # CPU time: robust to other jobs on a shared machine
    for i in range(1, n + 1):
        ds[i]
    return (time.process_time() - t0) / n


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def measure(config: str, points: int, forward_only: bool, device: str = "cpu") -> dict:
    from arteq.training.build import build_module

    torch.manual_seed(0)
    dev = torch.device(device)
    cfg = compose_cfg(config, points)
    module = build_module(cfg, stage=2).to(dev)
    batch = {k: v.to(dev) for k, v in one_batch(cfg, points).items()}
    n_params = sum(p.numel() for p in module.net.parameters())
    row = {
        "config": config,
        "points": points,
        "params": n_params,
        "threads": torch.get_num_threads(),
        "device": "cpu" if dev.type == "cpu" else torch.cuda.get_device_name(dev),
    }
    with torch.no_grad(), FlopCounterMode(display=False) as flops, PeakTensorMemory() as mem:
        t0 = time.perf_counter()
        module._step(batch, use_gt_parts=False)
        row["fwd_instrumented_s"] = round(time.perf_counter() - t0, 2)
    row["fwd_flops"] = flops.get_total_flops()
    row["fwd_peak_bytes"] = mem.peak

    if not forward_only:
        module.zero_grad(set_to_none=True)
        with FlopCounterMode(display=False) as flops, PeakTensorMemory() as mem:
            _, _, losses = module._step(batch, use_gt_parts=False)
            losses["loss"].backward()
        row["train_flops"] = flops.get_total_flops()
        row["train_peak_bytes"] = mem.peak
        module.zero_grad(set_to_none=True)
        _sync(dev)
        t0, c0 = time.perf_counter(), time.process_time()
        _, _, losses = module._step(batch, use_gt_parts=False)
        losses["loss"].backward()
        _sync(dev)
        row["train_step_s"] = round(time.perf_counter() - t0, 3)
        row["train_step_cpu_s"] = round(time.process_time() - c0, 2)  # less sensitive to other jobs
    return row


# ---------------------------------------------------------------------------------------------- report
#: Stated GPU assumptions for the estimates (dense peak rates, NVIDIA data sheets).
GPU = {
    "name": "H100 SXM 80 GB",
    "fp32_tflops": 67.0,
    "tf32_tflops": 495.0,
    "bf16_tflops": 989.0,
    "mem_gb": 80,
}
UTILISATION = 0.25  # of peak FLOP rate: the model is gather- and memory-bound, far from matmul peak
PAPER_EPOCH = {"train_size": 4000, "val_size": 128, "batch_size": 8, "num_workers": 8}


def _fmt_bytes(b: float) -> str:
    return f"{b / 2**20:,.0f} MiB" if b < 2**30 else f"{b / 2**30:,.2f} GiB"


def _extrapolate(latest: dict, config: str, points: int, fwd: dict) -> tuple[float, float] | None:
    """Training FLOPs and peak memory of a forward-only row, from the rows of the same config measured
    in full: FLOPs = forward x the train / forward ratio (constant over N); memory linear in N through
    the two largest measured N."""
    same = sorted((n, x) for (c, n), x in latest.items() if c == config and "train_flops" in x)
    if len(same) < 2:
        return None
    ratio = sum(x["train_flops"] / x["fwd_flops"] for _, x in same) / len(same)
    (n1, x1), (n2, x2) = same[-2:]
    slope = (x2["train_peak_bytes"] - x1["train_peak_bytes"]) / (n2 - n1)
    return fwd["fwd_flops"] * ratio, x2["train_peak_bytes"] + slope * (points - n2)


def _estimate_text(r: dict, train_f: float, train_mem: float, estimated: bool, gen_s: float | None) -> str:
    steps = PAPER_EPOCH["train_size"] / PAPER_EPOCH["batch_size"]
    flops_epoch = train_f * PAPER_EPOCH["train_size"] + r["fwd_flops"] * PAPER_EPOCH["val_size"]
    fp32, tf32 = GPU["fp32_tflops"], GPU["tf32_tflops"]
    t_fp32 = flops_epoch / (fp32 * 1e12 * UTILISATION)
    t_tf32 = flops_epoch / (tf32 * 1e12 * UTILISATION)
    static = 16 * r["params"]  # fp32 weights + grads + Adam moments
    largest = math.floor((GPU["mem_gb"] * 1e9 * 0.9 - static) / train_mem)
    how = " (training FLOPs and memory extrapolated from the forward pass)" if estimated else ""
    text = (
        f"Estimates for `+experiment=paper` (5000 points, {PAPER_EPOCH['train_size']} clouds per epoch, "
        f"batch {PAPER_EPOCH['batch_size']}: {steps:.0f} steps) on one {GPU['name']} at "
        f"{UTILISATION:.0%} of its peak FLOP rate{how}:\n"
        f"- compute: {flops_epoch / 1e12:,.1f} TFLOP per epoch -> {t_fp32:,.0f} s per epoch in float32 "
        f"({fp32:.0f} TFLOP/s peak), {t_tf32:,.0f} s with TF32 matmuls ({tf32:.0f}); "
        f"15 epochs (3 + 12): {15 * t_fp32 / 60:,.0f} / {15 * t_tf32 / 60:,.0f} min;\n"
    )
    if gen_s:
        rate = PAPER_EPOCH["num_workers"] / gen_s
        text += (
            f"- data: {PAPER_EPOCH['num_workers']} workers generate about {rate:,.0f} clouds/s "
            f"-> {PAPER_EPOCH['train_size'] / rate:,.0f} s per epoch at least;\n"
        )
    text += (
        f"- memory: {_fmt_bytes(train_mem)} per sample in training -> largest batch in {GPU['mem_gb']} GB "
        f"(90% usable, {_fmt_bytes(static)} of weights, grads and Adam state): about {largest}."
    )
    return text


def report(rows: list[dict]) -> str:
    latest: dict[tuple[str, int], dict] = {}
    gen: dict[int, float] = {}
    for r in rows:  # the newest row per (config, points), merging forward-only and full rows
        if r["config"] == "data":
            gen[r["points"]] = r["sample_gen_cpu_s"]
            continue
        key = (r["config"], r["points"])
        latest[key] = {**latest.get(key, {}), **{k: v for k, v in r.items() if v is not None}}
    lines = [
        "| config | points | params | fwd GFLOP | train GFLOP | fwd peak / sample | train peak / sample "
        "| train step CPU s | cloud gen CPU s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    notes = []
    for (config, points), r in sorted(latest.items()):
        train_f, train_mem = r.get("train_flops"), r.get("train_peak_bytes")
        estimated = train_f is None and (ext := _extrapolate(latest, config, points, r)) is not None
        if estimated:
            train_f, train_mem = ext
        mark = " (est.)" if estimated else ""
        train_f_s = "–" if train_f is None else f"{train_f / 1e9:,.1f}{mark}"
        train_m_s = "–" if train_mem is None else _fmt_bytes(train_mem) + mark
        lines.append(
            f"| {config} | {points} | {r['params']:,} | {r['fwd_flops'] / 1e9:,.1f} | {train_f_s} | "
            f"{_fmt_bytes(r['fwd_peak_bytes'])} | {train_m_s} | {r.get('train_step_cpu_s', '–')} | "
            f"{gen.get(points, '–')} |"
        )
        if config == "paper" and points == 5000 and train_f is not None:
            notes.append(_estimate_text(r, train_f, train_mem, estimated, gen.get(points)))
    return "\n".join(lines) + "".join("\n\n" + n for n in notes)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--configs", default="default,paper")
    ap.add_argument("--points", default="500,1000,2500,5000")
    ap.add_argument("--forward-only", action="store_true", help="skip backward (paper config at 5000 points)")
    ap.add_argument("--out", default=str(ROOT / "benchmarks" / "results" / "bench_scale.jsonl"))
    ap.add_argument("--table", default=None, help="only print the table from this JSON-lines file")
    ap.add_argument("--device", default="cpu", help="cpu or cuda (FLOPs and memory do not depend on it)")
    ap.add_argument("--data", action="store_true", help="only time cloud generation (CPU s per cloud)")
    args = ap.parse_args()
    if args.table:
        print(report([json.loads(x) for x in Path(args.table).read_text().splitlines() if x.strip()]))
        return
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    for config in ["data"] if args.data else args.configs.split(","):
        for n in (int(x) for x in args.points.split(",")):
            if args.data:
                gen_s = sample_time(compose_cfg("default", n))
                row = {"config": "data", "points": n, "sample_gen_cpu_s": round(gen_s, 4)}
            else:
                row = measure(config, n, args.forward_only, args.device)
            row["torch"] = torch.__version__
            row["when"] = time.strftime("%Y-%m-%d %H:%M")
            print(json.dumps(row), flush=True)
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")
    print(report([json.loads(x) for x in out.read_text().splitlines() if x.strip()]))


if __name__ == "__main__":
    main()
