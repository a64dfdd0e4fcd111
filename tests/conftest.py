"""Shared test settings: tiny network / run configs, config composition, body models.

The constants ``TINY_NET`` (ArtEqNet keyword arguments), ``TINY_OVERRIDES`` / ``TINY_PN2_OVERRIDES``
(Hydra overrides) are the single place where "tiny" is defined; tests import them, with
:func:`compose_config` and :func:`subprocess_env`, from here (``from conftest import ...``). Fixtures:
``tiny_pn2_overrides`` (a fresh copy of the PointNet++ list), ``anny22`` and ``toy_body`` (body models
built once per session).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

import arteq  # noqa: F401  (registers the resolvers conf/ uses)
from arteq.paths import conf_dir

CONF = str(conf_dir())
ROOT = Path(__file__).resolve().parents[1]


def subprocess_env() -> dict[str, str]:
    """Environment for a training subprocess: this checkout's sources, 1 thread, no inherited rank/plan."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(ROOT / "src"), str(ROOT / "tests")])
    env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    env.pop("LOCAL_RANK", None)
    env.pop("ARTEQ_RUN_PLAN", None)
    return env


#: ArtEqNet keyword arguments of a tiny network (seconds per step on a CPU).
TINY_NET = {
    "backbone": {"channels": [8, 8, 8, 8], "neighbours": [16, 8, 16, 8], "kernel": "ico13"},
    "segmenter": {"hidden": 32},
    "pose_head": {"dim": 32, "heads": 4, "mlp_hidden": 32},
    "shape_head": {"dim": 32, "heads": 4, "mlp_hidden": 32},
}
#: Hydra overrides of conf/train.yaml for a tiny run (200 points, a few clouds, one epoch).
TINY_OVERRIDES = [
    "data.num_points=200", "data.train_size=8", "data.val_size=4", "data.test_size=4",
    "data.batch_size=2", "data.num_workers=0", "trainer.max_epochs=1", "+trainer.limit_train_batches=2",
    "trainer.enable_progress_bar=false", "model.net.backbone.channels=[8,8,8,8]",
    "model.net.backbone.neighbours=[16,8,16,8]", "model.net.segmenter.hidden=32",
    "model.net.pose_head.dim=32", "model.net.pose_head.heads=4", "model.net.pose_head.mlp_hidden=32",
    "model.net.shape_head.dim=32", "model.net.shape_head.mlp_hidden=32", "mean_pose_baseline=false",
]  # fmt: skip
#: Hydra overrides shrinking the PointNet++ baseline (model=pointnet2).
TINY_PN2_OVERRIDES = [
    "model.net.npoints=[32,8]", "model.net.sa_channels=[[8],[16]]", "model.net.global_channels=[16]",
    "model.net.fp_channels=[8,8]", "model.net.head_hidden=8", "model.net.seg_hidden=8",
]  # fmt: skip


def compose_config(overrides: list[str], config_name: str = "train", hydra_config: bool = True):
    """``conf/<config_name>.yaml`` composed with ``overrides`` (Hydra config included unless
    ``hydra_config=False``: what ``train()`` / ``evaluate()`` get in a test)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name, overrides=overrides, return_hydra_config=hydra_config)


@pytest.fixture()
def tiny_pn2_overrides() -> list[str]:
    return list(TINY_PN2_OVERRIDES)


@pytest.fixture(scope="session")
def anny22():
    """The default body model (cached build), shared by the tests of a session."""
    from arteq.body import create_body

    return create_body({"name": "anny22"})


@pytest.fixture(scope="session")
def toy_body():
    """The procedural toy body (no file needed)."""
    from arteq.body import create_body

    return create_body({"name": "toy"})
