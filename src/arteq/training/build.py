"""Build the datamodule and the LightningModule from a composed config (``conf/train.yaml``).

Kept apart from :mod:`arteq.train`: that file is also ``__main__`` under ``python -m arteq.train``, and
importing it a second time from there would load a second copy of it.
"""

from __future__ import annotations

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf

from arteq.training.module import ArtEqModule


def build_datamodule(cfg: DictConfig) -> L.LightningDataModule:
    """The configured :class:`arteq.data.BodyScanDataModule` (``cfg.data``) on ``cfg.body_model``."""
    return hydra.utils.instantiate(cfg.data, body_model=OmegaConf.to_container(cfg.body_model, resolve=True))


def build_module(cfg: DictConfig, stage: int) -> ArtEqModule:
    """The :class:`ArtEqModule` of ``cfg.model`` for ``stage`` (1 or 2)."""
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
    )
