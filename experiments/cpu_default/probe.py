"""Short training probe used to tune the CPU default (experiments/cpu_default/README.md).

Trains ``STEPS`` steps of the configured stage with Adam (``LR``, 20 warm-up steps, then constant,
gradient clipping 1.0) and every ``EVERY`` steps prints the mean training losses and the metrics on the
first 32 validation clouds twice: with predicted part pooling ("pred") and with ground-truth pooling
("gt", which isolates the pose head). Usage (from the repository root):

    STEPS=300 LR=3e-3 OMP_NUM_THREADS=1 .venv/bin/python experiments/cpu_default/probe.py stage=1 [overrides]
"""

import json
import os
import sys
import time
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir

from arteq.train import build_datamodule, build_module
from arteq.training.metrics import BodyFitMetrics

torch.manual_seed(0)
steps, every = int(os.environ.get("STEPS", 300)), int(os.environ.get("EVERY", 100))
lr = float(os.environ.get("LR", 1e-3))
conf = str(Path(__file__).resolve().parents[2] / "conf")
with initialize_config_dir(config_dir=conf, version_base="1.3"):
    cfg = compose("train", overrides=sys.argv[1:])
dm = build_datamodule(cfg)
dm.setup("fit")
m = build_module(cfg, stage=cfg.stage)
opt = torch.optim.Adam(m.net.parameters(), lr)
sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: min(1.0, (s + 1) / 20))
val = list(dm.val_dataloader())[: max(1, 32 // cfg.data.batch_size)]


def evaluate(use_gt: bool) -> dict:
    m.eval()
    met = BodyFitMetrics()
    with torch.no_grad():
        for b in val:
            pred, gt, _ = m._step(b, use_gt_parts=use_gt)
            m._update(met, pred, gt)
    m.train()
    v = met.compute()
    per_part = v.pop("rot_err_deg_per_part")
    out = {k: round(float(x), 2) for k, x in v.items()}
    out["rot_per_part"] = [round(float(x)) for x in per_part]
    return out


step, t0, hist = 0, time.time(), []
while step < steps:
    for b in dm.train_dataloader():
        _, _, losses = m._step(b, use_gt_parts=cfg.stage == 1)
        opt.zero_grad()
        losses["loss"].backward()
        torch.nn.utils.clip_grad_norm_(m.net.parameters(), 1.0)
        opt.step()
        sched.step()
        step += 1
        hist.append({k: float(v.detach()) for k, v in losses.items()})
        if step % every == 0 or step == steps:
            recent = hist[-every:]
            avg = {k: round(sum(h[k] for h in recent) / len(recent), 4) for k in hist[-1]}
            row = {"step": step, "t": round(time.time() - t0), "loss": avg}
            row.update(pred=evaluate(False), gt=evaluate(True))
            print(json.dumps(row), flush=True)
        if step >= steps:
            break
