"""Build the body, the datamodule and the LightningModule from a composed config (``conf/train.yaml``).

Kept apart from :mod:`arteq.train`: that file is also ``__main__`` under ``python -m arteq.train``, and
importing it a second time from there would load a second copy of it.

A run builds its body once (:func:`build_body`) and hands it to every datamodule and module it makes:
the datamodules share it (CPU, sample generation), each module gets a copy of its own (a module moves
its body to its device).
"""

from __future__ import annotations

import copy
from collections.abc import Mapping
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf
from torch import nn

from arteq.body.factory import create_body
from arteq.body.model import BodyModel
from arteq.training.module import ArtEqModule


def build_body(cfg: DictConfig) -> BodyModel:
    """The body model of ``cfg.body_model``, instantiated from its ``_target_`` (``conf/body_model/``:
    :func:`arteq.body.create_body`); a config without one goes to ``create_body``."""
    if "_target_" in cfg.body_model:
        return hydra.utils.instantiate(cfg.body_model)
    return create_body(cfg.body_model)


def build_datamodule(
    cfg: DictConfig, body: nn.Module | None = None, net: Mapping[str, Any] | None = None
) -> L.LightningDataModule:
    """The configured :class:`arteq.data.BodyScanDataModule` (``cfg.data``) on ``body``, or on a body
    built from ``cfg.body_model`` when none is given. ``net`` (default ``cfg.model.net``) is the network
    the batches are for: ``data.fps_points: auto`` is resolved against it."""
    if body is None:
        body = OmegaConf.to_container(cfg.body_model, resolve=True)
    if net is None and cfg.get("model") is not None:
        net = OmegaConf.to_container(cfg.model.net, resolve=True)
    return hydra.utils.instantiate(cfg.data, body_model=body, net=net)


def build_module(cfg: DictConfig, stage: int, body: nn.Module | None = None) -> ArtEqModule:
    """The :class:`ArtEqModule` of ``cfg.model`` for ``stage`` (1 or 2), with a copy of ``body`` (built
    from ``cfg.body_model`` when none is given)."""
    return ArtEqModule(
        net=cfg.model.net,
        body_model=cfg.body_model,
        stage=stage,
        loss_weights=cfg.model.loss_weights,
        optimizer=cfg.model.optimizer,
        scheduler=cfg.model.scheduler,
        markers=cfg.model.markers,
        marker_weight=cfg.model.marker_weight,
        data=cfg.data,
        body=None if body is None else copy.deepcopy(body).train(),  # a new module is in training mode
    )
