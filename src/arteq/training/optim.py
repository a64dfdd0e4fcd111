"""Optimisers and learning-rate schedules from the config: ``model.optimizer`` / ``model.scheduler``.

Both are Hydra partials, completed here with what only the run knows (the parameters, the optimiser, the
number of steps)::

    optimizer: {_target_: torch.optim.AdamW, _partial_: true, lr: 1.0e-3, weight_decay: 0.01}
    scheduler: {_target_: arteq.training.optim.warmup_cosine, _partial_: true, warmup_steps: 20,
                min_lr_ratio: 0.05, interval: step}

``interval`` (``step`` | ``epoch``, default ``epoch``) is Lightning's, not the scheduler's: it is taken out
before the scheduler is built. A scheduler whose signature has ``total_steps`` gets the run's number of
optimiser steps. ``scheduler: null`` trains at a constant rate.

``conf/model/*.yaml`` write this form. The earlier form by name (``{name: adam, lr: ...}``,
``{name: cosine, warmup_steps: ...}``), which the configs held before and the checkpoints trained with them
hold in their hyper-parameters, is translated by :func:`optimizer_config` / :func:`scheduler_config`
(:data:`OPTIMIZERS`, :data:`SCHEDULERS`) to the same partials, so those checkpoints load and resume as
before.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np
import torch


class OptimConfigError(ValueError):
    """A bad ``model.optimizer`` / ``model.scheduler``: ``key``, the ``value`` given, what is ``allowed``."""

    def __init__(self, key: str, value: Any, allowed: str) -> None:
        super().__init__(f"{key}={value!r}: allowed: {allowed}")
        self.key, self.value, self.allowed = key, value, allowed


#: Optimisers of the earlier ``{name: ...}`` form and their classes.
OPTIMIZERS = {"adam": "torch.optim.Adam", "adamw": "torch.optim.AdamW"}
#: Schedules of the earlier ``{name: ...}`` form: target and Lightning interval (``none``: no schedule).
SCHEDULERS: dict[str, tuple[str, str] | None] = {
    "none": None,
    "cosine": ("arteq.training.optim.warmup_cosine", "step"),
    "step": ("torch.optim.lr_scheduler.StepLR", "epoch"),
}
#: Lightning's scheduler intervals.
INTERVALS = ("step", "epoch")
#: ``model.optimizer`` when none is given (the hyper-parameter recorded by :class:`ArtEqModule`).
DEFAULT_OPTIMIZER = {"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-4}
#: ``model.scheduler`` when none is given: a constant rate (``{name: none}``, what modules record for a
#: ``scheduler: null`` config).
DEFAULT_SCHEDULER = {"name": "none"}


def _one_form(key: str, cfg: Mapping[str, Any]) -> None:
    if "_target_" in cfg and "name" in cfg:  # e.g. a `+key._target_=...` override merged into the name form
        raise OptimConfigError(
            f"{key}.name", cfg["name"], f"no name beside {key}._target_ (drop it: `~{key}.name`)"
        )


def optimizer_config(cfg: Mapping[str, Any] | None) -> dict[str, Any]:
    """``model.optimizer`` as a Hydra partial (``_target_`` + ``_partial_: true``); the ``{name: ...}``
    form translated. Raises :class:`OptimConfigError` for an unknown name or a missing partial."""
    cfg = dict(cfg if cfg is not None else DEFAULT_OPTIMIZER)
    _one_form("model.optimizer", cfg)
    if "_target_" in cfg:
        if cfg.get("_partial_") is not True:
            raise OptimConfigError(
                "model.optimizer._partial_", cfg.get("_partial_"), "true (the parameters come when built)"
            )
        return cfg
    name = str(cfg.pop("name", "adam")).lower()
    if name not in OPTIMIZERS:
        raise OptimConfigError(
            "model.optimizer.name", name, f"{' | '.join(OPTIMIZERS)} (or a _target_ with _partial_: true)"
        )
    return {"_target_": OPTIMIZERS[name], "_partial_": True, **cfg}


def scheduler_config(cfg: Mapping[str, Any] | None) -> dict[str, Any] | None:
    """``model.scheduler`` as a Hydra partial with its ``interval``, or None (constant rate); the
    ``{name: ...}`` form translated."""
    if cfg is None:
        return None
    cfg = dict(cfg)
    _one_form("model.scheduler", cfg)
    if "_target_" in cfg:
        if cfg.get("_partial_") is not True:
            raise OptimConfigError(
                "model.scheduler._partial_", cfg.get("_partial_"), "true (the optimizer is added when built)"
            )
        cfg.setdefault("interval", "epoch")
    else:
        name = str(cfg.pop("name", "none")).lower()
        if name not in SCHEDULERS:
            raise OptimConfigError(
                "model.scheduler.name", name, f"{' | '.join(SCHEDULERS)} (or a _target_ with _partial_: true)"
            )
        if SCHEDULERS[name] is None:
            return None
        target, interval = SCHEDULERS[name]
        if name == "step":  # the earlier form's types and default
            step = cfg.get("step_size")
            if not isinstance(step, int) or isinstance(step, bool) or step < 1:
                raise OptimConfigError("model.scheduler.step_size", step, "an integer >= 1 (epochs a decay)")
            cfg = {"step_size": step, "gamma": float(cfg.get("gamma", 0.1))}
        cfg = {"_target_": target, "_partial_": True, **cfg, "interval": interval}
    if cfg["interval"] not in INTERVALS:
        raise OptimConfigError("model.scheduler.interval", cfg["interval"], " | ".join(INTERVALS))
    return cfg


def build_optimizer(
    cfg: Mapping[str, Any] | None, params: Iterable[torch.nn.Parameter]
) -> torch.optim.Optimizer:
    """The optimiser of ``model.optimizer`` over ``params``."""
    import hydra

    return hydra.utils.instantiate(optimizer_config(cfg))(params)


def build_scheduler(
    cfg: Mapping[str, Any] | None, optimizer: torch.optim.Optimizer, total_steps: int | Callable[[], int]
) -> dict[str, Any] | None:
    """Lightning's ``lr_scheduler`` entry (``{"scheduler", "interval"}``) of ``model.scheduler``, or None.

    ``total_steps``: the run's optimiser steps, or a function giving them, called only for a scheduler
    that takes ``total_steps``."""
    import hydra

    sched = scheduler_config(cfg)
    if sched is None:
        return None
    interval = sched.pop("interval")
    factory = hydra.utils.instantiate(sched)
    kwargs = {}
    if "total_steps" in inspect.signature(factory).parameters:
        kwargs["total_steps"] = int(total_steps() if callable(total_steps) else total_steps)
    return {"scheduler": factory(optimizer, **kwargs), "interval": interval}


def warmup_cosine(
    optimizer: torch.optim.Optimizer, total_steps: int, warmup_steps: int = 0, min_lr_ratio: float = 0.05
) -> torch.optim.lr_scheduler.LambdaLR:
    """Linear warm-up over ``warmup_steps`` optimiser steps, then a cosine from the configured rate down to
    ``min_lr_ratio`` of it at ``total_steps``."""
    warmup, min_ratio = int(warmup_steps), float(min_lr_ratio)

    def factor(step: int) -> float:
        if step < warmup:
            return (step + 1) / warmup
        t = min(1.0, (step - warmup) / max(1, total_steps - warmup))
        # plain float: a numpy scalar in the scheduler state breaks weights_only checkpoint loading
        return float(min_ratio + (1 - min_ratio) * 0.5 * (1 + np.cos(np.pi * t)))

    return torch.optim.lr_scheduler.LambdaLR(optimizer, factor)
