"""Shared test settings: the tiny presets, config composition, body models.

"Tiny" is defined once, in the config group the package ships: ``conf/scale/tiny.yaml`` (the run: a few
clouds of 200 points, two steps, one epoch) and ``conf/tiny_net/<name>.yaml`` (the networks: ``arteq``,
``arteq_micro``, ``pointnet2``). Tests take them through fixtures:

* ``tiny_overrides``: the Hydra overrides selecting both (``+scale=tiny``, ``+tiny_net=arteq``);
  ``tiny_micro_overrides`` the same with the smaller ``arteq_micro`` network; ``tiny_pn2_overrides``
  the PointNet++ network preset alone (``+tiny_net=pointnet2``, with a config that picks PointNet++);
* ``tiny_config``: composes ``conf/train.yaml`` (or ``eval.yaml``) with ``tiny_overrides`` and more;
* ``tiny_net`` / ``tiny_pn2_net``: the network presets as constructor keyword arguments;
  ``tiny_net_200`` adds the ball radii the configs give 200 points;
* ``anny22``, ``toy_body``: body models built once per session.

Module-level code can call the functions behind them (:func:`preset_overrides`, :func:`net_preset`,
:func:`compose_config`, :func:`subprocess_env`) with ``from conftest import ...``.
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


def preset_overrides(net: str | None = "arteq") -> list[str]:
    """Overrides selecting the tiny run (``conf/scale/tiny.yaml``) and, unless ``net`` is None, the network
    preset ``conf/tiny_net/<net>.yaml``."""
    return ["+scale=tiny"] + ([f"+tiny_net={net}"] if net else [])


def net_preset(name: str = "arteq") -> dict:
    """``conf/tiny_net/<name>.yaml`` as keyword arguments of its network (ArtEqNet, PointNet2Regressor)."""
    from omegaconf import OmegaConf

    return OmegaConf.to_container(OmegaConf.load(Path(CONF) / "tiny_net" / f"{name}.yaml"), resolve=True)


#: The former constants, now read from the presets (for code written against them; tests take the fixtures).
TINY_NET = net_preset("arteq")
TINY_OVERRIDES = preset_overrides("arteq")
TINY_PN2_OVERRIDES = ["+tiny_net=pointnet2"]


def compose_config(overrides: list[str], config_name: str = "train", hydra_config: bool = True):
    """``conf/<config_name>.yaml`` composed with ``overrides`` (Hydra config included unless
    ``hydra_config=False``: what ``train()`` / ``evaluate()`` get in a test)."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        return compose(config_name, overrides=overrides, return_hydra_config=hydra_config)


@pytest.fixture(scope="session")
def tiny_overrides() -> tuple[str, ...]:
    """``("+scale=tiny", "+tiny_net=arteq")``: the run and network presets."""
    return tuple(preset_overrides("arteq"))


@pytest.fixture(scope="session")
def tiny_micro_overrides() -> tuple[str, ...]:
    """``("+scale=tiny", "+tiny_net=arteq_micro")``: the run preset with the smaller network."""
    return tuple(preset_overrides("arteq_micro"))


@pytest.fixture(scope="session")
def tiny_pn2_overrides() -> tuple[str, ...]:
    """``("+tiny_net=pointnet2",)``: the PointNet++ network preset (for configs that pick PointNet++)."""
    return ("+tiny_net=pointnet2",)


@pytest.fixture()
def tiny_config():
    """``tiny_config(*overrides, config_name="train", hydra_config=False)``: the config composed with the
    tiny presets first, then ``overrides`` (``eval.yaml`` has no network: the run preset alone)."""

    def make(*overrides: str, config_name: str = "train", hydra_config: bool = False):
        presets = preset_overrides("arteq" if config_name == "train" else None)
        return compose_config([*presets, *overrides], config_name, hydra_config)

    return make


@pytest.fixture(scope="session")
def tiny_net() -> dict:
    """The tiny ArtEq network preset as ``ArtEqNet`` keyword arguments (shared by the session: copy it
    before changing it)."""
    return net_preset("arteq")


@pytest.fixture(scope="session")
def tiny_net_200(tiny_net) -> dict:
    """``tiny_net`` with the backbone's ball radii for 200 points, as the composed tiny config has them
    (the paper's radii scaled by point density, conf/model/arteq.yaml)."""
    radii = list(compose_config(preset_overrides("arteq"), hydra_config=False).model.net.backbone.radii)
    assert radii and len(radii) == len(tiny_net["backbone"]["channels"])
    return {**tiny_net, "backbone": {**tiny_net["backbone"], "radii": radii}}


@pytest.fixture(scope="session")
def tiny_pn2_net() -> dict:
    """The tiny PointNet++ preset as ``PointNet2Regressor`` keyword arguments."""
    return net_preset("pointnet2")


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
