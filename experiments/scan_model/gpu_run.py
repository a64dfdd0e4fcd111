"""A scan-model training cycle sized to a wall-clock budget on a GPU machine (one call of the device tool).

    python experiments/scan_model/gpu_run.py --budget 400 --out $OUT [--batch 8 16 32] [--probe-only] \
        [OVERRIDES]

1. Probe: the run's own config (the overrides of ``RUN7`` plus any given) on the GPU: seconds per
   training step (forward, losses, backward, Adam; one fixed batch, after warm-up) at each ``--batch``
   size, and seconds per training cloud made by one data worker.
2. Pick the batch size with the most clouds per second, counting the data workers (all cores but one) as
   a limit, and the number of steps that fills ``--budget`` seconds at 85 % of the probed rate.
3. Train that many steps with ``python -m arteq.train`` (a cosine cycle over exactly those steps), then
   copy the last and best checkpoints, the metrics CSV, the log and ``gpu_run.json`` (probe, choice, wall
   times) to ``--out``.

The all-ages body and the fixed sets are read from ``$ARTEQ_CACHE_DIR`` (carry a prebuilt cache: the GPU
machine has no ``anny``; with ``data.hand_curl=P``, curled hands in a share of the training clouds, carry
``body_models/anny_allages_hands.npz`` in it too: docs/data.md). Validation runs at each epoch end on the
cached validation set; test sets are left to a CPU run of ``python -m arteq.eval`` on the returned
checkpoint. ``--device cpu`` checks the whole script here (tiny ``--budget``);
experiments/scan_model/README.md, gpu7, has the calls. An override of a key that ``RUN7`` sets replaces
its value (:func:`with_overrides`).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[2]
CONF = str(ROOT / "conf")
#: run7: the athletic mix on top of run5's mix (experiments/scan_model/README.md), from run5's final weights.
RUN7 = [
    "+experiment=stage2",
    "model=arteq_local",
    "body_model=anny_allages",
    "data.shape_prior=allages",
    "data.augment=so3",
    "data.eval_augment=so3",
    "data.wide_poses=0.5",
    "data.train_pose_mix={id:0.4,ood:0.2,athletic:0.2,limb1:0.1,limb2:0.1}",
    "data.single_view.prob=0.5",
    "data.view_splits=[front,side,back,top]",
    "mean_pose_baseline=false",
]


def with_overrides(base: list[str], given: list[str]) -> list[str]:
    """``base`` with each key that ``given`` sets again left out, then ``given``: a key's value is replaced,
    not merged (Hydra merges a dict given twice, and refuses a key the first dict did not have, such as
    ``athletic_spine`` in ``data.train_pose_mix``)."""

    def key(o: str) -> str:
        return o.split("=", 1)[0].lstrip("+~")

    again = {key(o) for o in given}
    return [o for o in base if key(o) not in again] + list(given)


def probe(overrides: list[str], batches: list[int], steps: int, device: str) -> dict:
    from hydra import compose, initialize_config_dir

    from arteq.training.build import build_datamodule, build_module

    with initialize_config_dir(version_base="1.3", config_dir=CONF):
        extra = ["data.num_workers=0", f"data.batch_size={max(batches)}"]
        cfg = compose("train", overrides=[*overrides, *extra])
    torch.manual_seed(0)
    dm = build_datamodule(cfg)
    dm.setup("fit")
    ds = dm.train_dataloader().dataset
    t = time.perf_counter()
    n_items = 24
    for i in range(n_items):
        ds[i]
    data_s = (time.perf_counter() - t) / n_items
    big = next(iter(dm.train_dataloader()))
    module = build_module(cfg, stage=2).to(device)
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    opt = torch.optim.Adam(module.net.parameters(), lr=1e-4)
    out = {"data_s_per_cloud": data_s, "step_s": {}}
    for b in batches:
        batch = {k: (v[:b].to(device) if torch.is_tensor(v) else v) for k, v in big.items()}
        times = []
        for i in range(steps + 2):
            sync()
            t = time.perf_counter()
            loss = module._step(batch, use_gt_parts=False)[2]["loss"]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            sync()
            if i >= 2:
                times.append(time.perf_counter() - t)
        out["step_s"][b] = statistics.median(times)
        print(f"probe: batch {b}: {out['step_s'][b]:.4f} s/step", flush=True)
    print(f"probe: data {data_s:.4f} s per cloud per worker", flush=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--budget", type=float, required=True, help="seconds of training (the probe not counted)")
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--batch", type=int, nargs="+", default=[8, 16, 32])
    ap.add_argument("--run", type=Path, default=ROOT / ".gpu" / "run7")
    ap.add_argument("--init", default="experiments/pretrained/scan_run5_resume.ckpt")
    ap.add_argument("--lr", type=float, default=3e-4)
    ap.add_argument("--epochs", type=int, default=6, help="epochs of the cycle (one checkpoint each)")
    ap.add_argument("--probe-only", action="store_true")
    ap.add_argument("--device", default="cuda", help="cpu: check the script here")
    ap.add_argument("--probe-steps", type=int, default=8)
    ap.add_argument("overrides", nargs="*")
    a = ap.parse_args()
    a.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    workers = max(1, (os.cpu_count() or 2) - 1)
    report: dict = {
        "device": torch.cuda.get_device_name(0) if a.device == "cuda" else "cpu",
        "torch": torch.__version__,
        "workers": workers,
    }
    overrides = with_overrides(RUN7, a.overrides)
    report["probe"] = p = probe(overrides, a.batch, a.probe_steps, a.device)
    report["probe_wall_s"] = time.time() - t0
    rate = {b: b / max(s, b * p["data_s_per_cloud"] / workers) for b, s in p["step_s"].items()}
    batch = max(rate, key=rate.get)
    step_s = batch / rate[batch]
    steps = int(0.85 * a.budget / step_s) // a.epochs * a.epochs
    report.update(batch=batch, clouds_per_s=rate[batch], planned_steps=steps)
    print(f"chosen: batch {batch}, {steps} steps ({rate[batch]:.0f} clouds/s)", flush=True)
    (a.out / "gpu_run.json").write_text(json.dumps(report, indent=1))
    if a.probe_only or steps < a.epochs:
        return
    per_epoch = steps // a.epochs
    args = [
        *overrides,
        f"data.batch_size={batch}",
        f"data.train_size={per_epoch * batch}",
        f"data.num_workers={workers}",
        f"trainer.max_epochs={a.epochs}",
        f"stage1.ckpt={a.init}",
        f"model.optimizer.lr={a.lr}",
        "trainer.enable_progress_bar=false",
        "test=false",
        "callbacks.step_checkpoint.every_n_train_steps=200",
        f"hydra.run.dir={a.run}",
    ]
    log = a.out / "train.log"
    t1 = time.time()
    with open(log, "w") as fh:
        try:  # a hung or slow run is stopped well inside the call's limit; its checkpoints still come back
            rc = subprocess.call(
                [sys.executable, "-m", "arteq.train", *args],
                stdout=fh,
                stderr=subprocess.STDOUT,
                timeout=1.3 * a.budget + 60,
            )
        except subprocess.TimeoutExpired:
            rc = "timeout"
    report.update(train_rc=rc, train_wall_s=time.time() - t1, args=args)
    for f in [*(a.run / "checkpoints").glob("last*.ckpt"), *(a.run / "checkpoints").glob("epoch*.ckpt")]:
        shutil.copy(f, a.out / f.name)
    for f in a.run.rglob("metrics.csv"):
        shutil.copy(f, a.out / "metrics.csv")
    (a.out / "gpu_run.json").write_text(json.dumps(report, indent=1))
    print(json.dumps({k: v for k, v in report.items() if k != "args"}), flush=True)


if __name__ == "__main__":
    main()
