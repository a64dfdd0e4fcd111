"""Train (and evaluate) ArtEq: ``python -m arteq.train +experiment=stage2``.

A thin Hydra entry point over :func:`train`. One run folder per run (``outputs/<task>/<time>/``)
holds the resolved config (``.hydra/``), checkpoints, logs and, after testing, ``metrics.json`` /
``metrics.md``. For stage 2 the stage-1 initialisation is resolved as described in
``conf/train.yaml`` and recorded in ``metrics.json`` under ``stage1_init``.

Several processes (``trainer=ddp trainer.devices=N``): Lightning's launcher starts ranks 1..N-1 by
re-running this command when the first ``fit`` begins. Rank 0 decides the run plan (run folder,
checkpoint to resume, stage-1 initialisation) before that and hands it to the other ranks in the
environment (``ARTEQ_RUN_PLAN``); a callback checks at start-up that all ranks follow the same plan.
Rank 0 alone writes run files (metrics, reports, caches); the other ranks wait at a barrier.

Resume: ``ckpt_path=<file>`` continues from that checkpoint; ``resume=auto`` continues the newest run
of this task under ``${paths.output_root}/<task>/`` from its newest readable checkpoint (a step
checkpoint written every ``callbacks.step_checkpoint.every_n_train_steps`` steps, or the end-of-epoch
one), in that run's folder; ``resume=<run folder>`` names the run.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import torch
from omegaconf import DictConfig, OmegaConf

from arteq.training.build import build_datamodule, build_module
from arteq.training.validate import exit_on_config_error, validate_train_config

__all__ = ["build_datamodule", "build_module", "train", "main", "latest_checkpoint", "plan_run"]

log = logging.getLogger("arteq.train")


def _instantiate_dict(cfg: DictConfig | None) -> list[Any]:
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
    callbacks = _instantiate_dict(cfg.get("callbacks")) + list(extra_callbacks or [])
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


def latest_checkpoint(folder: Path) -> Path | None:
    """The checkpoint in ``folder`` to resume from: the readable one with the highest global step (the
    newest file on a tie). Unreadable ones (e.g. cut short by a kill) are skipped with a warning."""
    best: tuple[tuple[int, float], Path] | None = None
    for path in sorted(Path(folder).glob("*.ckpt")):
        try:
            ckpt = torch.load(path, map_location="cpu", weights_only=True, mmap=True)
            key = (int(ckpt["global_step"]), path.stat().st_mtime)
        except Exception as e:  # truncated, foreign or vanished file
            log.warning("resume: skipping unreadable checkpoint %s (%s)", path, type(e).__name__)
            continue
        if best is None or key > best[0]:
            best = (key, path)
    return None if best is None else best[1]


def _run_checkpoints(run: Path, stage: int) -> dict[str, str]:
    """``{stage: checkpoint}`` to resume a run folder: its own stage, else (stage 2) its inner stage 1."""
    own = latest_checkpoint(run / "checkpoints")
    if own is not None:
        return {str(stage): str(own)}
    if stage == 2:
        inner = latest_checkpoint(run / "stage1" / "checkpoints")
        if inner is not None:
            return {"1": str(inner)}
    return {}


def _newest_checkpoint_time(run: Path) -> float:
    files = [*run.glob("checkpoints/*.ckpt"), *run.glob("stage1/checkpoints/*.ckpt")]
    return max((f.stat().st_mtime for f in files), default=-1.0)


def plan_run(cfg: DictConfig) -> dict[str, Any]:
    """Where this run writes, which checkpoint(s) it resumes, and how stage 2 is initialised."""
    output_dir = Path(cfg.paths.output_dir)
    resume: dict[str, str] = {}
    resumed_run = None
    if cfg.get("ckpt_path"):
        resume[str(cfg.stage)] = str(cfg.ckpt_path)
    elif cfg.get("resume"):
        if cfg.resume == "auto":
            root = Path(cfg.paths.output_root) / cfg.task_name
            runs = [
                p for p in root.glob("*") if p.is_dir() and p.resolve() != output_dir.resolve()
            ]  # fmt: skip
            runs = sorted((r for r in runs if _newest_checkpoint_time(r) >= 0), key=_newest_checkpoint_time)
            for run in reversed(runs):
                if ckpts := _run_checkpoints(run, cfg.stage):
                    resumed_run, resume = run, ckpts
                    break
            if resumed_run is None:
                log.info(
                    "resume=auto: no earlier run of %r with a checkpoint under %s: new run",
                    cfg.task_name,
                    root,
                )
        else:
            resumed_run = Path(cfg.resume).expanduser()
            resume = _run_checkpoints(resumed_run, cfg.stage)
            if not resume:
                raise FileNotFoundError(f"resume={cfg.resume}: no readable checkpoint in that run folder")
        if resumed_run is not None:
            log.info("resuming run %s from %s (this invocation's own log stays in %s)", resumed_run,
                     resume, output_dir)  # fmt: skip
            output_dir = resumed_run
    stage1: dict[str, Any] | None = None
    if cfg.stage == 2 and cfg.stage1.init:
        if "2" in resume:
            stage1 = {"ckpt": None, "how": "not used: stage 2 resumed from a checkpoint"}
        elif "1" in resume:
            stage1 = {"ckpt": None, "how": "train"}
        elif cfg.stage1.ckpt:
            stage1 = {"ckpt": str(cfg.stage1.ckpt), "how": "given by stage1.ckpt"}
        elif cfg.stage1.search and (found := find_stage1_checkpoint(cfg)) is not None:
            stage1 = {"ckpt": str(found), "how": "found from a previous stage-1 run"}
        else:
            stage1 = {"ckpt": None, "how": "train"}
    return {
        "output_dir": str(output_dir),
        "resume": resume,
        "resumed_run": None if resumed_run is None else str(resumed_run),
        "stage1": stage1,
    }


#: Environment variable through which rank 0 hands its run plan to the ranks Lightning launches.
PLAN_ENV = "ARTEQ_RUN_PLAN"


def _launched_by_rank0() -> bool:
    """True in a process started by Lightning's launcher of a rank-0 process (local rank > 0)."""
    return os.environ.get("LOCAL_RANK", "0") != "0" and PLAN_ENV in os.environ


class SamePlanOnAllRanks(L.Callback):
    """Fails at start-up if the ranks of a distributed run would train different things (e.g. ranks
    started by an external launcher, each resolving ``resume=auto`` or the stage-1 search on its own)."""

    def __init__(self, plan: dict[str, Any]) -> None:
        self.plan = json.dumps(plan, sort_keys=True)

    def setup(self, trainer: L.Trainer, pl_module: L.LightningModule, stage: str) -> None:
        if trainer.world_size > 1:
            rank0 = trainer.strategy.broadcast(self.plan, src=0)
            if rank0 != self.plan:
                raise RuntimeError(
                    f"rank {trainer.global_rank} planned {self.plan}, rank 0 planned {rank0}: pass explicit "
                    "ckpt_path= / stage1.ckpt= when launching ranks yourself"
                )


def fit_and_test(
    cfg: DictConfig,
    stage: int,
    output_dir: Path,
    init_ckpt: Path | None = None,
    max_epochs: int | None = None,
    run_test: bool = True,
    resume_ckpt: str | None = None,
    plan: dict[str, Any] | None = None,
) -> tuple[dict[str, Any], L.Trainer]:
    """Train one stage in ``output_dir``; returns (paths and, if run_test, test metrics; the trainer)."""
    output_dir.mkdir(parents=True, exist_ok=True)
    datamodule = build_datamodule(cfg)
    module = build_module(cfg, stage)
    if init_ckpt is not None:
        module.load_net_weights(str(init_ckpt))
    extra = [SamePlanOnAllRanks(plan)] if plan is not None else []
    trainer = build_trainer(cfg, output_dir, max_epochs=max_epochs, resuming=bool(resume_ckpt),
                            extra_callbacks=extra)  # fmt: skip
    n_params = sum(p.numel() for p in module.net.parameters())
    log.info("stage %d: ArtEq network with %s parameters -> %s", stage, f"{n_params:,}", output_dir)
    if resume_ckpt:
        log.info("stage %d: resuming from %s", stage, resume_ckpt)
    t0 = time.time()
    trainer.fit(module, datamodule=datamodule, ckpt_path=resume_ckpt)
    result: dict[str, Any] = {
        "stage": stage,
        "parameters": n_params,
        "train_seconds": round(time.time() - t0, 1),
        "output_dir": str(output_dir),
        "best_ckpt": trainer.checkpoint_callback.best_model_path if trainer.checkpoint_callback else None,
        "last_ckpt": str(output_dir / "checkpoints" / "last.ckpt"),
    }
    if resume_ckpt:
        result["resumed_from"] = str(resume_ckpt)
    if run_test:
        from arteq.eval import test_module

        ckpt = result["best_ckpt"] or None
        result["metrics"] = test_module(module, datamodule, trainer, ckpt_path=ckpt)
    finish_wandb(trainer)
    return result, trainer


def train(cfg: DictConfig) -> dict[str, Any]:
    """Run the configured stage (and stage 1 first if stage 2 needs it); return the summary."""
    validate_train_config(cfg)
    if _launched_by_rank0():
        plan = json.loads(os.environ[PLAN_ENV])
    else:
        plan = plan_run(cfg)
        os.environ[PLAN_ENV] = json.dumps(plan)  # inherited by the ranks Lightning will launch
    L.seed_everything(cfg.seed, workers=True)
    output_dir = Path(plan["output_dir"])
    summary: dict[str, Any] = {
        "task_name": cfg.task_name,
        "config": OmegaConf.to_container(cfg, resolve=True),
    }
    if plan["resumed_run"]:
        summary["resumed_run"] = plan["resumed_run"]
    init_ckpt = None
    if plan["stage1"] is not None:
        s1 = plan["stage1"]
        how = s1["how"]
        if how == "train":
            log.info("stage 2: no stage-1 checkpoint given or found -> training stage 1 first")
            s1_run, _ = fit_and_test(
                cfg, 1, output_dir / "stage1", max_epochs=cfg.stage1.epochs, run_test=False,
                resume_ckpt=plan["resume"].get("1"), plan=plan,
            )  # fmt: skip
            summary["stage1_run"] = s1_run
            init_ckpt, how = Path(s1_run["last_ckpt"]), "trained first in this run"
        elif s1["ckpt"] is not None:
            init_ckpt = Path(s1["ckpt"])
            if not init_ckpt.is_file():
                raise FileNotFoundError(f"stage1.ckpt={init_ckpt}: no such checkpoint file")
        if init_ckpt is not None:
            log.info("stage 2: initialising from stage-1 checkpoint %s (%s)", init_ckpt, how)
        summary["stage1_init"] = {"ckpt": None if init_ckpt is None else str(init_ckpt), "how": how}
    result, trainer = fit_and_test(
        cfg, cfg.stage, output_dir, init_ckpt=init_ckpt, run_test=cfg.test,
        resume_ckpt=plan["resume"].get(str(cfg.stage)), plan=plan,
    )  # fmt: skip
    summary.update(result)
    if cfg.test and trainer.is_global_zero:  # run files: rank 0 only; the other ranks wait below
        if cfg.mean_pose_baseline:
            from arteq.training.floor import evaluate_mean_pose

            summary["mean_pose_baseline"] = evaluate_mean_pose(cfg)
        from arteq.eval import write_metrics
        from arteq.results import method_name

        write_metrics(summary, output_dir, method_name(cfg))
    trainer.strategy.barrier("arteq.train: run files written")
    return summary


@hydra.main(version_base="1.3", config_path="../../conf", config_name="train")
def main(cfg: DictConfig) -> float | None:
    from arteq.runtime import tune_cpu_allocator

    tune_cpu_allocator()
    with exit_on_config_error("arteq.train"):
        summary = train(cfg)
    metrics = summary.get("metrics", {})
    # Returned for Hydra sweepers: the OOD vertex error.
    return metrics.get("test_ood", {}).get("v2v_cm")


if __name__ == "__main__":
    main()
