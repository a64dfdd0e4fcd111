"""The Lightning ``Trainer`` of a run: callbacks and loggers from the config, wandb run names.

Checkpoints of every checkpoint callback go to ``<output_dir>/checkpoints`` (a stage 1 trained inside a
stage-2 run has its own ``output_dir``, ``<run>/stage1``); a resumed run's CSV log goes beside the
earlier one instead of replacing it.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig

from arteq.io.runs import checkpoint_dir


def instantiate_all(cfg: DictConfig | None) -> list[Any]:
    """The objects of the ``_target_`` entries of a config group with several members (``callbacks``)."""
    if not cfg:
        return []
    return [hydra.utils.instantiate(c) for c in cfg.values() if c is not None and "_target_" in c]


def build_trainer(
    cfg: DictConfig,
    output_dir: Path,
    max_epochs: int | None = None,
    resuming: bool = False,
    extra_callbacks: list[L.Callback] | None = None,
) -> L.Trainer:
    """``cfg.trainer`` with the configured callbacks (plus ``extra_callbacks``) and loggers, writing
    into ``output_dir``; ``max_epochs`` overrides the config's (an inner stage 1)."""
    callbacks = instantiate_all(cfg.get("callbacks")) + list(extra_callbacks or [])
    for cb in callbacks:  # keep checkpoints inside the (sub-)run folder
        if isinstance(cb, L.pytorch.callbacks.ModelCheckpoint):
            cb.dirpath = str(checkpoint_dir(output_dir))
    loggers = []
    for name, lg_cfg in (cfg.get("logger") or {}).items():
        if lg_cfg is not None and "_target_" in lg_cfg:
            extra = {}
            if resuming and name == "csv":  # CSVLogger would delete the earlier metrics.csv
                extra["version"] = time.strftime("resumed-%Y%m%d-%H%M%S")
            if name == "wandb":
                extra.update(wandb_run_names(cfg, output_dir, lg_cfg))
            loggers.append(hydra.utils.instantiate(lg_cfg, save_dir=str(output_dir), **extra))
    kwargs: dict[str, Any] = {"default_root_dir": str(output_dir)}
    if max_epochs is not None:
        kwargs["max_epochs"] = max_epochs
    return hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False, **kwargs)


def wandb_run_names(cfg: DictConfig, output_dir: Path, lg_cfg: DictConfig) -> dict[str, str]:
    """Dashboard group and run name: one wandb run per (sweep job, stage), grouped by sweep.

    Multirun: group = ``<task>/<sweep folder>``, name = ``job<N>: <overrides>``; single run: group =
    task name, name = run folder. A stage 1 trained inside a stage-2 run gets a ``/stage1`` suffix.
    Values set explicitly in ``logger.wandb`` win.
    """
    group, name = cfg.task_name, Path(cfg.paths.output_dir).name
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
        if hc.mode == RunMode.MULTIRUN:
            group = f"{cfg.task_name}/{Path(hc.sweep.dir).name}"
            name = f"job{hc.job.num}" + (f": {hc.job.override_dirname}" if hc.job.override_dirname else "")
    except (ValueError, ImportError):  # not running under Hydra (tests, notebooks)
        pass
    if output_dir != Path(cfg.paths.output_dir):
        name = f"{name}/{output_dir.name}"
    out = {}
    if not lg_cfg.get("group"):
        out["group"] = group
    if not lg_cfg.get("name"):
        out["name"] = name
    return out


def finish_wandb(trainer: L.Trainer) -> None:
    """Close the wandb run of ``trainer`` so that the next stage / sweep job opens its own run."""
    from lightning.pytorch.loggers import WandbLogger

    for lg in trainer.loggers:
        if isinstance(lg, WandbLogger):
            lg.experiment.finish()
