"""Two-process DDP on CPU (gloo) through `python -m arteq.train trainer=ddp`, on a tiny configuration.

One run checks: rank 0 alone writes the run files; the CSV log is written once; no Lightning warning
about epoch-level logging without sync_dist; the ranks train on disjoint samples whose union is the
one-process epoch, different every epoch; the test sets are split over the ranks without padding or
duplicates; and the 2-process test metrics equal a 1-process evaluation of the same checkpoint.
"""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from conftest import subprocess_env

ROOT = Path(__file__).resolve().parents[1]
#: Beyond the tiny presets: two epochs of every batch (the ranks' union is the epoch), every step logged,
#: an odd test set (a padding sampler would duplicate a sample on one rank).
DDP = ["data.test_size=5", "trainer.max_epochs=2", "~trainer.limit_train_batches",
       "trainer.log_every_n_steps=1"]  # fmt: skip


def _train_cmd(tmp_path: Path, tiny: tuple[str, ...], *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "arteq.train", "+experiment=stage1", *tiny, *DDP,
        f"paths.output_root={tmp_path / 'out'}", f"data.cache_root={tmp_path / 'cache'}", *extra,
    ]  # fmt: skip


def test_two_process_ddp_run(tmp_path, tiny_overrides):
    run = tmp_path / "out" / "run"
    cmd = _train_cmd(
        tmp_path, tiny_overrides, "trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2",
        f"paths.output_dir={run}", f"hydra.run.dir={run}",
        "+callbacks.record._target_=helpers.record.RecordBatches",
    )  # fmt: skip
    proc = subprocess.run(cmd, cwd=ROOT, env=subprocess_env(), capture_output=True, text=True, timeout=600)
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-4000:]

    # --- run files: rank 0 only, logs once
    summary = json.loads((run / "metrics.json").read_text())
    assert "sync_dist" not in out, "epoch-level metrics logged without sync_dist"
    rank0_log = (run / "train.log").read_text()
    rank1_log = (run / "train_ddp_process_1.log").read_text()
    assert "metrics written to" in rank0_log and "metrics written to" not in rank1_log
    assert "cached test_id set" in rank0_log and "cached" not in rank1_log  # caches: rank 0 creates them
    csvs = list(run.glob("**/metrics.csv"))
    assert len(csvs) == 1
    rows = list(csv.DictReader(csvs[0].open()))
    assert sum(1 for r in rows if r.get("val/v2v_cm")) == 2  # one row per epoch, not one per rank
    assert sum(1 for r in rows if r.get("test_id/v2v_cm")) == 1

    # --- training samples: disjoint over ranks, union = the 1-process epoch, new every epoch
    rec = [torch.load(run / f"record_rank{r}.pt", weights_only=False) for r in (0, 1)]
    assert all(r["world_size"] == 2 for r in rec)

    def epoch_set(r, e):
        return {tuple(b.tolist()) for ep, batch in r["train"] if ep == e for b in batch}

    from arteq.data import BodyScanDataModule
    from arteq.data.dataset import EpochSampler

    dm = BodyScanDataModule(body_model={"name": "anny22"}, num_points=200, train_size=8, cache=False)
    train_ds = dm.make_dataset("train")
    for e in (0, 1):
        s0, s1 = epoch_set(rec[0], e), epoch_set(rec[1], e)
        assert len(s0) == len(s1) == 4 and not s0 & s1
        single = {tuple(train_ds[i]["betas"].tolist()) for i in EpochSampler(8).epoch_indices(e)}
        assert s0 | s1 == single
    assert not (epoch_set(rec[0], 0) | epoch_set(rec[1], 0)) & (epoch_set(rec[0], 1) | epoch_set(rec[1], 1))

    # --- test sets: every sample exactly once over the ranks (5 = 3 + 2, no padding)
    for split in (0, 1):
        centers = torch.cat([b for r in rec for i, b in r["test"] if i == split])
        assert centers.shape[0] == 5 and torch.unique(centers, dim=0).shape[0] == 5

    # --- 2-process test metrics == 1-process evaluation of the same checkpoint
    from hydra import compose, initialize_config_dir

    from arteq.eval import evaluate

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose(
            "eval",
            overrides=[f"ckpt_path={summary['best_ckpt']}", f"output_dir={tmp_path / 'ev'}",
                       "data.num_points=200", "data.test_size=5", "data.batch_size=2", "data.num_workers=0",
                       f"data.cache_root={tmp_path / 'cache'}", "trainer.enable_progress_bar=false"],
        )  # fmt: skip
    single = evaluate(cfg)["metrics"]
    for split in ("test_id", "test_ood"):
        for key in ("part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg"):
            assert summary["metrics"][split][key] == pytest.approx(single[split][key], rel=1e-5, abs=1e-6), (
                split,
                key,
            )
        per_part = summary["metrics"][split]["rot_err_deg_per_part"]
        assert per_part == pytest.approx(single[split]["rot_err_deg_per_part"], rel=1e-5, abs=1e-5)
