"""Invalid config values fail at start-up, before anything is built, with one line naming the key
and the values allowed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir

from arteq.training.validate import ConfigError, validate_train_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", autouse=True)
def _hydra():
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        yield


def _cfg(*overrides: str):
    return compose("train", overrides=["paths.output_dir=/tmp/unused", *overrides])


def test_default_and_paper_configs_are_valid():
    validate_train_config(_cfg())
    validate_train_config(_cfg("+experiment=paper"))
    validate_train_config(_cfg("model=pointnet2"))
    validate_train_config(_cfg("trainer=ddp", "trainer.devices=2"))


@pytest.mark.parametrize(
    "override, key, allowed",
    [
        ("data.num_points=0", "data.num_points=0", "integer >= 1"),
        ("model.optimizer.lr=-0.001", "model.optimizer.lr=-0.001", "> 0"),
        ("+model.net.arch=transformer", "model.net.arch='transformer'", "arteq | pointnet2"),
        ("data.batch_size=100", "data.batch_size=100", "1..64: at most data.val_size=64"),
        ("data.eval_batch_size=200", "data.eval_batch_size=200", "at most data.val_size=64"),
        ("data.batch_size=500", "data.batch_size=500", "1..400: at most the training samples"),
        ("model.net.backbone.strides=[8,8,8,8]", "model.net.backbone.strides=[8, 8, 8, 8]",
         "needs data.num_points >= 4096"),
        ("body_model.model_path=/no/such/anny22.npz", "body_model.model_path='/no/such/anny22.npz'",
         "no such file"),
        ("body_model=smpl", "body_model.model_path=(not set)", "SMPL model file"),
        ("trainer.precision=8-mixed", "trainer.precision='8-mixed'", "bf16-mixed"),
        ("data.augment=so2", "data.augment='so2'", "none | so3 | z"),
        ("stage=3", "stage=3", "1 (ground-truth"),
        ("callbacks.step_checkpoint.every_n_train_steps=-5", "every_n_train_steps=-5", ">= 0"),
        ("resume=sometimes", "resume='sometimes'", "auto"),
    ],
)  # fmt: skip
def test_bad_value_names_key_and_allowed_values(override, key, allowed):
    with pytest.raises(ConfigError) as info:
        validate_train_config(_cfg(override))
    msg = str(info.value)
    assert "\n" not in msg
    assert key in msg and allowed in msg, msg


def test_batch_size_is_per_process_in_ddp():
    validate_train_config(
        _cfg("trainer=ddp", "trainer.devices=2", "data.batch_size=200", "data.eval_batch_size=8")
    )
    with pytest.raises(ConfigError, match=r"data.batch_size=201: allowed: 1..200.*2 processes share"):
        validate_train_config(_cfg("trainer=ddp", "trainer.devices=2", "data.batch_size=201"))


def test_command_line_exits_with_one_line_before_training(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), OMP_NUM_THREADS="1")
    proc = subprocess.run(
        [sys.executable, "-m", "arteq.train", "data.num_points=0", f"paths.output_root={tmp_path}"],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert proc.returncode == 2
    errors = [line for line in proc.stderr.splitlines() if "config error" in line]
    assert errors == ["arteq.train: config error: data.num_points=0: allowed: an integer >= 1 "
                      "(500..5000 in the paper's study; 5000 = paper)"], proc.stderr[-2000:]  # fmt: skip
    assert "Traceback" not in proc.stderr
    assert not list(tmp_path.glob("**/checkpoints")) and not list(tmp_path.glob("**/*.ckpt"))
