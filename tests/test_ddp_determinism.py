"""Same seed -> same metrics to the last digit on CPU, also with 2 dataloader workers; and the local
dashboard: `logger=tensorboard` and several loggers at once (`logger=[csv,tensorboard]`)."""

from __future__ import annotations

import csv

import pytest
import torch

from conftest import compose_config

#: Beyond the tiny presets (with the micro network): 128 points, every one of the 4 steps trained and logged.
RUN = ["+experiment=stage1", "data.num_points=128", "data.val_size=2", "data.test_size=3",
       "~trainer.limit_train_batches", "trainer.log_every_n_steps=1"]  # fmt: skip


@pytest.fixture(scope="module")
def runs(tmp_path_factory, tiny_micro_overrides):
    from arteq.train import train

    tmp = tmp_path_factory.mktemp("det")
    out = {}
    for name, extra in {
        "w2_a": ["data.num_workers=2", "logger=[csv,tensorboard]"],
        "w2_b": ["data.num_workers=2", "logger=tensorboard"],
    }.items():
        overrides = [*tiny_micro_overrides, *RUN, *extra, f"paths.output_dir={tmp / name}",
                     f"data.cache_root={tmp / 'cache'}"]  # fmt: skip
        cfg = compose_config(overrides, hydra_config=False)
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
