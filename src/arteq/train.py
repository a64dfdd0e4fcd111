"""Train (and evaluate) ArtEq: ``python -m arteq.train +experiment=stage2``.

A thin Hydra entry point over :func:`train`. One run folder per run (``outputs/<task>/<time>/``)
holds the resolved config (``.hydra/``), checkpoints, CSV logs and, after testing,
``metrics.json`` / ``metrics.md``. For stage 2 the stage-1 initialisation is resolved as described
in ``conf/train.yaml`` and recorded in ``metrics.json`` under ``stage1_init``.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from omegaconf import DictConfig, OmegaConf

from arteq.training.build import build_datamodule, build_module

__all__ = ["build_datamodule", "build_module", "train", "main"]

log = logging.getLogger("arteq.train")


def _instantiate_dict(cfg: DictConfig | None) -> list[Any]:
    if not cfg:
        return []
    return [hydra.utils.instantiate(c) for c in cfg.values() if c is not None and "_target_" in c]


def build_trainer(
    cfg: DictConfig, output_dir: Path, max_epochs: int | None = None, resuming: bool = False
) -> L.Trainer:
    callbacks = _instantiate_dict(cfg.get("callbacks"))
    for cb in callbacks:  # keep checkpoints inside the (sub-)run folder
        if isinstance(cb, L.pytorch.callbacks.ModelCheckpoint):
            cb.dirpath = str(output_dir / "checkpoints")
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


#: Data settings a found stage-1 checkpoint must share with the stage-2 run (what the clouds look like).
STAGE1_DATA_KEYS = ("source", "num_points", "augment", "noise_std", "density_contrast", "density_wavelength",
                    "beta_scale", "amass_root")  # fmt: skip


def _data_signature(data: dict | None) -> dict:
    data = data or {}
    return {k: data.get(k) for k in STAGE1_DATA_KEYS}


def _checkpoint_net_config(path: Path) -> dict | None:
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # unreadable or foreign file: not a candidate
        return None
    hp = ckpt.get("hyper_parameters", {})
    keys = {"net": "net", "body": "body_model", "stage": "stage", "data": "data"}
    return {k: hp.get(key) for k, key in keys.items()}


def find_stage1_checkpoint(cfg: DictConfig) -> Path | None:
    """Newest ``last.ckpt`` of a previous stage-1 run with the same network, body model and kind of
    data (``STAGE1_DATA_KEYS``: e.g. a stage 1 trained without rotation augmentation is not reused by an
    augmented stage 2)."""
    root = Path(cfg.paths.output_root) / "stage1"
    want_net = OmegaConf.to_container(cfg.model.net, resolve=True)
    want_body = {
        k: v for k, v in OmegaConf.to_container(cfg.body_model, resolve=True).items() if k != "_target_"
    }
    want_data = _data_signature(OmegaConf.to_container(cfg.data, resolve=True))
    candidates = sorted(root.glob("*/checkpoints/last.ckpt"), key=lambda p: p.stat().st_mtime, reverse=True)
    for path in candidates:
        info = _checkpoint_net_config(path)
        if info is None or info["stage"] != 1:
            continue
        net = dict(info["net"] or {})
        net.pop("num_betas", None)
        if (
            net == {k: v for k, v in want_net.items() if k != "num_betas"}
            and info["body"] == want_body
            and _data_signature(info["data"]) == want_data
        ):
            return path
    return None


def fit_and_test(
    cfg: DictConfig,
    stage: int,
    output_dir: Path,
    init_ckpt: Path | None = None,
    max_epochs: int | None = None,
    run_test: bool = True,
) -> dict[str, Any]:
    """Train one stage in ``output_dir``; returns paths and (if run_test) test metrics."""
    output_dir.mkdir(parents=True, exist_ok=True)
    datamodule = build_datamodule(cfg)
    module = build_module(cfg, stage)
    if init_ckpt is not None:
        module.load_net_weights(str(init_ckpt))
    resume = cfg.get("ckpt_path") if stage == cfg.stage else None
    trainer = build_trainer(cfg, output_dir, max_epochs=max_epochs, resuming=bool(resume))
    n_params = sum(p.numel() for p in module.net.parameters())
    log.info("stage %d: ArtEq network with %s parameters -> %s", stage, f"{n_params:,}", output_dir)
    t0 = time.time()
    trainer.fit(module, datamodule=datamodule, ckpt_path=resume)
    result: dict[str, Any] = {
        "stage": stage,
        "parameters": n_params,
        "train_seconds": round(time.time() - t0, 1),
        "output_dir": str(output_dir),
        "best_ckpt": trainer.checkpoint_callback.best_model_path if trainer.checkpoint_callback else None,
        "last_ckpt": str(output_dir / "checkpoints" / "last.ckpt"),
    }
    if run_test:
        from arteq.eval import test_module

        ckpt = result["best_ckpt"] or None
        result["metrics"] = test_module(module, datamodule, trainer, ckpt_path=ckpt)
    finish_wandb(trainer)
    return result


def train(cfg: DictConfig) -> dict[str, Any]:
    """Run the configured stage (and stage 1 first if stage 2 needs it); return the summary."""
    L.seed_everything(cfg.seed, workers=True)
    output_dir = Path(cfg.paths.output_dir)
    summary: dict[str, Any] = {
        "task_name": cfg.task_name,
        "config": OmegaConf.to_container(cfg, resolve=True),
    }
    init_ckpt = None
    if cfg.stage == 2 and cfg.stage1.init:
        if cfg.stage1.ckpt:
            init_ckpt = Path(cfg.stage1.ckpt)
            if not init_ckpt.is_file():
                raise FileNotFoundError(f"stage1.ckpt={init_ckpt}: no such checkpoint file")
            how = "given by stage1.ckpt"
        elif cfg.stage1.search and (found := find_stage1_checkpoint(cfg)) is not None:
            init_ckpt, how = found, "found from a previous stage-1 run"
        else:
            log.info("stage 2: no stage-1 checkpoint given or found -> training stage 1 first")
            s1 = fit_and_test(cfg, 1, output_dir / "stage1", max_epochs=cfg.stage1.epochs, run_test=False)
            summary["stage1_run"] = s1
            init_ckpt, how = Path(s1["last_ckpt"]), "trained first in this run"
        log.info("stage 2: initialising from stage-1 checkpoint %s (%s)", init_ckpt, how)
        summary["stage1_init"] = {"ckpt": str(init_ckpt), "how": how}
    result = fit_and_test(cfg, cfg.stage, output_dir, init_ckpt=init_ckpt, run_test=cfg.test)
    summary.update(result)
    if cfg.test and cfg.mean_pose_baseline:
        from arteq.eval import evaluate_mean_pose

        summary["mean_pose_baseline"] = evaluate_mean_pose(cfg)
    if cfg.test:
        from arteq.eval import write_metrics

        write_metrics(summary, output_dir)
    return summary


@hydra.main(version_base="1.3", config_path="../../conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    from arteq.runtime import tune_cpu_allocator

    tune_cpu_allocator()
    summary = train(cfg)
    metrics = summary.get("metrics", {})
    # Returned for Hydra sweepers: the OOD vertex error.
    return metrics.get("test_ood", {}).get("v2v_cm")


if __name__ == "__main__":
    main()
