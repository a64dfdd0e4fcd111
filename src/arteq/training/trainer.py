"""The Lightning ``Trainer`` of a run, from the config: trainer, callbacks and loggers as ``conf/`` says.

Where a stage writes and for how many epochs come from the YAML: ``trainer.default_root_dir``, every
checkpoint callback's ``dirpath`` and every logger's ``save_dir`` interpolate ``${paths.output_dir}``,
and ``trainer.max_epochs`` is the stage's epochs. :func:`stage_config` derives the config of one stage
from the run's (its folder, ``<run>/stage1`` for a stage 1 trained inside a stage-2 run; its epochs;
the CSV version of a resumed run, which goes beside the earlier log instead of replacing it; the wandb
names); :func:`build_trainer` instantiates what that config says and changes nothing.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, open_dict


def instantiate_all(cfg: DictConfig | None) -> list[Any]:
    """The objects of the ``_target_`` entries of a config group with several members (``callbacks``)."""
    if not cfg:
        return []
    return [hydra.utils.instantiate(c) for c in cfg.values() if c is not None and "_target_" in c]


def _loggers(cfg: DictConfig) -> dict[str, Any]:
    return {n: lg for n, lg in (cfg.get("logger") or {}).items() if lg is not None and "_target_" in lg}


def stage_config(
    cfg: DictConfig, output_dir: str | Path, max_epochs: int | None = None, resuming: bool = False
) -> DictConfig:
    """The config of one stage writing into ``output_dir``: a copy of ``cfg`` with ``paths.output_dir``
    set to it (the trainer, checkpoint callbacks and loggers follow through their interpolations),
    ``trainer.max_epochs`` set to ``max_epochs`` when given (an inner stage 1: ``stage1.epochs``), a
    ``resumed-<time>`` CSV version when ``resuming`` (CSVLogger would delete the earlier metrics.csv),
    and the wandb group and run name where ``logger.wandb`` leaves them null (:func:`wandb_run_names`).
    ``cfg`` itself is not changed."""
    changes: dict[str, Any] = {"paths": {"output_dir": str(output_dir)}}
    if max_epochs is not None:
        changes["trainer"] = {"max_epochs": int(max_epochs)}
    loggers = _loggers(cfg)
    logger_changes: dict[str, Any] = {}
    if resuming and "csv" in loggers:
        logger_changes["csv"] = {"version": time.strftime("resumed-%Y%m%d-%H%M%S")}
    if "wandb" in loggers:
        logger_changes["wandb"] = wandb_run_names(cfg, Path(output_dir), loggers["wandb"])
    if logger_changes:
        changes["logger"] = logger_changes
    out = copy.deepcopy(cfg)
    with open_dict(out):  # a custom logger config may lack a key set here
        out.merge_with(changes)
    return out


def build_trainer(cfg: DictConfig, extra_callbacks: list[L.Callback] | None = None) -> L.Trainer:
    """``cfg.trainer`` with the configured callbacks (plus ``extra_callbacks``) and loggers; ``cfg`` is a
    stage's config (:func:`stage_config`)."""
    callbacks = instantiate_all(cfg.get("callbacks")) + list(extra_callbacks or [])
    loggers = [hydra.utils.instantiate(lg) for lg in _loggers(cfg).values()]
    return hydra.utils.instantiate(cfg.trainer, callbacks=callbacks, logger=loggers or False)


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
