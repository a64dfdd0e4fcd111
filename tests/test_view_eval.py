"""The single-view test sets (``data.view_splits``) in the test loop: metrics.json / metrics.md and the config
check, on the tiny presets (tests/conftest.py)."""

from __future__ import annotations

import csv
import json
import math

import pytest

from arteq.data.single_view import VIEW_SPLITS as SIMULATOR_VIEW_SPLITS
from arteq.results import (
    ALL_TEST_SPLITS,
    METRIC_KEYS,
    SPLIT_LABELS,
    TEST_SPLITS,
    VIEW_NAMES,
    VIEW_SPLITS,
    metrics_table,
    view_split,
)
from arteq.training.validate import ConfigError, validate_eval_config, validate_train_config


def test_view_split_names_are_defined_once_beside_the_test_splits():
    assert VIEW_SPLITS == SIMULATOR_VIEW_SPLITS  # the simulator's view sets, in its order
    assert ALL_TEST_SPLITS == (*TEST_SPLITS, *VIEW_SPLITS)
    assert all(s in SPLIT_LABELS for s in ALL_TEST_SPLITS)
    assert [view_split(v) for v in VIEW_NAMES] == list(VIEW_SPLITS)
    assert [view_split(s) for s in VIEW_SPLITS] == list(VIEW_SPLITS)
    assert view_split("under") is None and view_split("test_view_under") is None and view_split(3) is None
    # a table without view results has the columns it had; with them, they come after the full-surface ones
    row = {"test_id": {"part_acc": 50.0}, "test_ood": {"part_acc": 40.0}}
    assert "view" not in metrics_table({"m": row})
    head = metrics_table({"m": {**row, "test_view_front": {"part_acc": 30.0}}}).splitlines()[0]
    assert head.index("OOD part_acc") < head.index("front-view part_acc") < head.index("ID v2v_cm")


def test_bad_view_name_is_a_config_error(tiny_config, tmp_path):
    for name in ("train", "eval"):
        check = validate_train_config if name == "train" else validate_eval_config
        extra = ("ckpt_path=x.ckpt",) if name == "eval" else (f"paths.output_dir={tmp_path}",)
        check(tiny_config("data.view_splits=[front,test_view_top]", *extra, config_name=name))  # both forms
        with pytest.raises(
            ConfigError, match=r"data.view_splits=\['front', 'under'\]: allowed: a list of front"
        ):
            check(tiny_config("data.view_splits=[front,under]", *extra, config_name=name))


def test_datamodule_takes_view_names_and_runs_them_after_the_test_splits(toy_body, tmp_path):
    from arteq.data import BodyScanDataModule

    dm = BodyScanDataModule(
        body_model=toy_body, num_points=64, test_size=2, batch_size=2, test_splits=["test_id"],
        view_splits=["top", "test_view_front"], cache_root=str(tmp_path),
    )  # fmt: skip
    assert dm.view_splits == ("test_view_front", "test_view_top")
    assert dm.test_loader_splits == ("test_id", "test_view_front", "test_view_top")
    with pytest.raises(ValueError, match="data.view_splits must be a subset of .*front"):
        BodyScanDataModule(body_model=toy_body, view_splits=["under"])


def test_tiny_train_and_test_writes_the_view_metrics(tmp_path, tiny_config):
    from arteq.train import train

    out = tmp_path / "run"
    cfg = tiny_config(
        "+experiment=stage1", f"paths.output_root={tmp_path}", f"paths.output_dir={out}",
        f"data.cache_root={tmp_path / 'cache'}", "data.view_splits=[front]",
    )  # fmt: skip
    summary = train(cfg)
    metrics = json.loads((out / "metrics.json").read_text())["metrics"]
    assert list(metrics) == [*TEST_SPLITS, "test_view_front"] == list(summary["metrics"])
    for key in METRIC_KEYS:
        assert math.isfinite(metrics["test_view_front"][key]), key
    assert len(metrics["test_view_front"]["rot_err_deg_per_part"]) == 22
    md = (out / "metrics.md").read_text()
    assert "front-view part_acc" in md and "front-view v2v_cm" in md and "side-view" not in md
    # the logged keys (CSV logger) under the split's name
    logged = set()
    for path in out.rglob("metrics.csv"):
        with open(path) as f:
            logged |= set(next(csv.reader(f)))
    assert {f"test_view_front/{k}" for k in METRIC_KEYS} <= logged
