"""Same seed -> same metrics to the last digit on CPU, also with 2 dataloader workers; and the local
dashboard: `logger=tensorboard` and several loggers at once (`logger=[csv,tensorboard]`)."""

from __future__ import annotations

import csv
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

CONF = str(Path(__file__).resolve().parents[1] / "conf")
TINY = [
    "+experiment=stage1", "data.num_points=128", "data.train_size=8", "data.val_size=2", "data.test_size=3",
    "data.batch_size=2", "trainer.max_epochs=1", "trainer.enable_progress_bar=false",
    "trainer.log_every_n_steps=1", "model.net.backbone.channels=[4,4,4,4]",
    "model.net.backbone.neighbours=[8,8,8,8]", "model.net.segmenter.hidden=16", "model.net.pose_head.dim=16",
    "model.net.pose_head.heads=2", "model.net.pose_head.mlp_hidden=16", "model.net.shape_head.dim=16",
    "model.net.shape_head.heads=2", "model.net.shape_head.mlp_hidden=16", "mean_pose_baseline=false",
]  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    from arteq.train import train

    tmp = tmp_path_factory.mktemp("det")
    out = {}
    for name, extra in {
        "w2_a": ["data.num_workers=2", "logger=[csv,tensorboard]"],
        "w2_b": ["data.num_workers=2", "logger=tensorboard"],
    }.items():
        with initialize_config_dir(config_dir=CONF, version_base="1.3"):
            cfg = compose("train", overrides=[*TINY, *extra, f"paths.output_dir={tmp / name}",
                                              f"data.cache_root={tmp / 'cache'}"])  # fmt: skip
        out[name] = (train(cfg), tmp / name)
    return out


def test_same_seed_same_metrics_to_the_last_digit(runs):
    (a, _), (b, _) = runs["w2_a"], runs["w2_b"]
    assert a["metrics"] == b["metrics"]  # exact float equality, every metric and every part
    wa = torch.load(a["last_ckpt"], weights_only=True)["state_dict"]
    wb = torch.load(b["last_ckpt"], weights_only=True)["state_dict"]
    assert all(torch.equal(wa[k], wb[k]) for k in wa)


def test_tensorboard_and_several_loggers(runs):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    for name in ("w2_a", "w2_b"):  # logger=[csv,tensorboard] and logger=tensorboard (which includes csv)
        run = runs[name][1]
        assert list((run / "tensorboard").glob("events.out.tfevents.*"))
        acc = EventAccumulator(str(run / "tensorboard"))  # all event files of the run (fit, test)
        acc.Reload()
        tags = acc.Tags()["scalars"]
        assert "train/loss" in tags and "val/v2v_cm" in tags and "test_ood/v2v_cm" in tags
        assert len(acc.Scalars("train/loss")) == 4  # every step (log_every_n_steps=1)
        rows = list(csv.DictReader(open(run / "csv" / "metrics.csv")))
        assert sum(1 for r in rows if r.get("train/loss")) == 4
