"""Invalid config values fail at start-up, before anything is built, with one line naming the key
and the values allowed."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

from arteq.paths import conf_dir
from arteq.training import validate
from arteq.training.validate import ConfigError, validate_train_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module", autouse=True)
def _hydra():
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        yield


def _cfg(*overrides: str):
    return compose("train", overrides=["paths.output_dir=/tmp/unused", *overrides])


def test_default_and_paper_configs_are_valid():
    validate_train_config(_cfg())
    validate_train_config(_cfg("+experiment=paper"))
    validate_train_config(_cfg("model=pointnet2"))
    validate_train_config(_cfg("trainer=ddp", "trainer.devices=2"))
    validate_train_config(_cfg("body_model=anny_allages", "data.shape_prior=allages",
                               "data.train_pose_mix={id:0.4,ood:0.4,limb1:0.1,limb2:0.1}"))  # fmt: skip


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
        ("data.shape_prior=adults", "data.shape_prior='adults'", "normal | allages"),
        ("data.shape_prior=allages", "data.shape_prior='allages'", "use body_model=anny_allages"),
        ("data.train_pose_mix={id:1,extreme:1}", "data.train_pose_mix=", "id | ood | limb1 | limb2"),
        ("data.train_pose_mix={id:-1}", "data.train_pose_mix=", "weights >= 0"),
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


# ---------------------------------------------------------------- every validated name list = its consumer's


def test_bodies_are_create_bodys_and_toy_is_accepted():
    from arteq.body import create_body
    from arteq.body.model import BodyModelFileError

    for name in ("toy", "anny_allages"):  # built without a file: no model_path needed
        validate_train_config(_cfg(f"body_model.name={name}"))
    assert isinstance(create_body({"name": "toy"}), torch.nn.Module)
    for name in validate.BODY_MODELS:  # each gets past create_body's dispatch (no "unknown body model")
        if name == "toy":
            continue
        with pytest.raises(BodyModelFileError):
            create_body({"name": name, "model_path": "/no/such/body.npz"})
    with pytest.raises(ValueError, match="unknown body model"):
        create_body({"name": "smplx"})
    with pytest.raises(ConfigError, match="body_model.name='smplx': allowed: .*anny22.*toy"):
        validate_train_config(_cfg("body_model.name=smplx"))


def test_augments_architectures_losses_and_splits_are_their_owners():
    from arteq.data.dataset import AUGMENTS, augmentation_rotation, seeded_generator
    from arteq.models.registry import ARCHITECTURES
    from arteq.results import TEST_SPLITS
    from arteq.training.losses import DEFAULT_WEIGHTS

    assert validate.AUGMENTS is AUGMENTS
    for kind in validate.AUGMENTS:
        assert augmentation_rotation(kind, seeded_generator(kind)).shape == (3, 3)
    assert validate.ARCHS == tuple(ARCHITECTURES)
    assert all(isinstance(ARCHITECTURES[a].load(), type) for a in validate.ARCHS)
    with pytest.raises(ConfigError) as info:
        validate_train_config(_cfg("+model.loss_weights.chamfer=1.0"))
    assert str(info.value).endswith(" | ".join(DEFAULT_WEIGHTS))
    cfg = _cfg()
    with open_dict(cfg):
        cfg.data.test_splits = list(TEST_SPLITS)
        validate_train_config(cfg)
        cfg.data.test_splits = ["test_id", "test_hard"]
    with pytest.raises(
        ConfigError, match="data.test_splits=.*test_hard.*allowed: a non-empty list of test_id"
    ):
        validate_train_config(cfg)


def test_parent_modes_are_the_pose_heads():
    from arteq.models.heads import PARENT_MODES, parent_mode

    for mode in (*PARENT_MODES, True, False):
        validate_train_config(_cfg(f"model.net.parent_conditioning={str(mode).lower()}"))
        assert parent_mode(mode) in PARENT_MODES
    with pytest.raises(ConfigError) as info:
        validate_train_config(_cfg("model.net.parent_conditioning=sideways"))
    assert "parent_conditioning='sideways': allowed: invariant | aligned | none" in str(info.value)
    with pytest.raises(ValueError, match="sideways"):  # what validate refuses, the pose head refuses too
        parent_mode("sideways")


def test_precisions_are_lightnings():
    from typing import get_args

    import lightning as L
    from lightning.fabric.connector import _PRECISION_INPUT_STR, _convert_precision_to_unified_args

    assert {"32-true", "bf16-mixed", "16-mixed", "64", "bf16", "transformer-engine"} <= set(
        validate.PRECISIONS
    )
    for p in validate.PRECISIONS:
        value = int(p) if p.isdigit() else p
        assert _convert_precision_to_unified_args(value) in get_args(_PRECISION_INPUT_STR), p
    validate_train_config(_cfg("trainer.precision=bf16-true"))
    with pytest.raises(ValueError, match="8-mixed"):  # what validate refuses, Lightning refuses too
        L.Trainer(precision="8-mixed", logger=False)


def test_data_sources_are_the_datamodules():
    from arteq.data import BodyScanDataModule

    with pytest.raises(ValueError) as info:
        BodyScanDataModule(source="mocap", body_model={"name": "toy"})
    for source in validate.DATA_SOURCES:
        assert repr(source) in str(info.value)


def _by_name(key: str, value: str) -> list[str]:
    """``model.<key>`` replaced whole by ``value``, the earlier form by name (conf/model/ writes partials)."""
    return [f"~model.{key}", f"+model.{key}={value}"]


@pytest.mark.parametrize(
    "overrides",
    [
        [],  # the shipped partials
        ["model.optimizer._target_=torch.optim.AdamW", "+model.optimizer.weight_decay=0.01"],
        ["model.scheduler=null"],
        ["model.scheduler._target_=torch.optim.lr_scheduler.ExponentialLR", "~model.scheduler.warmup_steps",
         "~model.scheduler.min_lr_ratio", "+model.scheduler.gamma=0.9", "model.scheduler.interval=epoch"],
        _by_name("optimizer", "{name:adamw,lr:0.001,weight_decay:0.01}"),
        _by_name("scheduler", "{name:none}"),
        _by_name("scheduler", "{name:step,step_size:2}"),
        _by_name("optimizer", "{name: adamw, lr: 1.0e-3}"),  # as docs/training.md writes it
    ],
)  # fmt: skip
def test_optimizer_and_scheduler_by_name_or_partial(overrides):
    validate_train_config(_cfg(*overrides))


@pytest.mark.parametrize(
    "overrides, message",
    [
        (_by_name("optimizer", "{name:sgd,lr:0.001}"), "model.optimizer.name='sgd': allowed: adam | adamw"),
        (_by_name("scheduler", "{name:linear}"),
         "model.scheduler.name='linear': allowed: none | cosine | step"),
        (_by_name("scheduler", "{name:step}"), "model.scheduler.step_size=None: allowed: an integer >= 1"),
        (["+model.optimizer.name=adam"],
         "model.optimizer.name='adam': allowed: no name beside model.optimizer._target_"),
        (["~model.optimizer._partial_"], "model.optimizer._partial_=None: allowed: true"),
        (["model.optimizer._target_=torch.optim.Nope"],
         "model.optimizer._target_='torch.optim.Nope': allowed: an importable optimizer"),
        (["model.scheduler.interval=batch"], "model.scheduler.interval='batch': allowed: step | epoch"),
    ],
)  # fmt: skip
def test_bad_optimizer_or_scheduler_names_the_key(overrides, message):
    with pytest.raises(ConfigError) as info:
        validate_train_config(_cfg(*overrides))
    assert message in str(info.value), str(info.value)
