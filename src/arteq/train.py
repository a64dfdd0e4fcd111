"""Train (and evaluate) ArtEq: ``python -m arteq.train +experiment=stage2``.

plan -> instantiate -> fit -> test -> write. The plan (:mod:`arteq.training.plan`) says where the run
writes, what it resumes and how stage 2 gets its stage-1 weights (``conf/train.yaml``: given, found, or
trained first inside this run); the body is built once and shared by every stage
(:mod:`arteq.training.build`); each stage fits and tests with a trainer of :mod:`arteq.training.trainer`;
the mean-pose floor is :mod:`arteq.training.floor`. The run folder (``outputs/<task>/<time>/``, see
:mod:`arteq.io.runs`) ends with ``metrics.json`` / ``metrics.md``; ``stage1_init`` records the stage-1
initialisation.

Several processes (``trainer=ddp trainer.devices=N``): Lightning's launcher starts ranks 1..N-1 by
re-running this command when the first ``fit`` begins; they follow rank 0's plan. Rank 0 alone writes
run files (metrics, reports, caches); the other ranks wait at a barrier.
"""

from __future__ import annotations

import logging
import time
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig, OmegaConf
from torch import nn

from arteq.io.runs import last_checkpoint
from arteq.models.registry import display_name
from arteq.paths import conf_dir
from arteq.results import architecture, method_name
from arteq.training.build import build_body, build_datamodule, build_module
from arteq.training.plan import (
    SamePlanOnAllRanks,
    find_stage1_checkpoint,
    latest_checkpoint,
    plan_run,
    shared_plan,
)
from arteq.training.trainer import build_trainer, finish_wandb, stage_config
from arteq.training.validate import exit_on_config_error, validate_train_config

__all__ = ["build_datamodule", "build_module", "find_stage1_checkpoint", "latest_checkpoint", "main",
           "plan_run", "train"]  # fmt: skip

log = logging.getLogger("arteq.train")


def fit_and_test(
    cfg: DictConfig, stage: int, output_dir: Path, body: nn.Module, plan: dict[str, Any],
    init_ckpt: Path | None = None, max_epochs: int | None = None, run_test: bool = True,
) -> tuple[dict[str, Any], L.Trainer]:  # fmt: skip
    """Train one stage in ``output_dir``; returns (paths and, if run_test, test metrics; the trainer)."""
    from arteq.eval import module_breakdown, test_module

    output_dir.mkdir(parents=True, exist_ok=True)
    resume_ckpt = plan["resume"].get(str(stage))
    # this stage's config: its folder and epochs in paths.output_dir / trainer.max_epochs, read from there
    # by the trainer, the checkpoint callbacks and the loggers (conf/)
    cfg = stage_config(cfg, output_dir, max_epochs=max_epochs, resuming=bool(resume_ckpt))
    datamodule, module = build_datamodule(cfg, body), build_module(cfg, stage, body)
    reinit: list[str] = []
    if init_ckpt is not None:
        reinit = module.load_net_weights(str(init_ckpt), bool(cfg.stage1.get("reinit_mismatched", False)))
        if reinit:
            log.info("stage %d: %d tensors of another shape in %s keep their fresh initialisation: %s", stage,
                     len(reinit), init_ckpt, ", ".join(reinit))  # fmt: skip
    trainer = build_trainer(cfg, extra_callbacks=[SamePlanOnAllRanks(plan)])
    n_params = sum(p.numel() for p in module.net.parameters())
    net_name = display_name(architecture(cfg))  # ArtEq, PointNet++ (models/registry.py)
    log.info("stage %d: %s network with %s parameters -> %s", stage, net_name, f"{n_params:,}", output_dir)
    if resume_ckpt:
        log.info("stage %d: resuming from %s", stage, resume_ckpt)
    t0 = time.time()
    trainer.fit(module, datamodule=datamodule, ckpt_path=resume_ckpt)
    best = trainer.checkpoint_callback.best_model_path if trainer.checkpoint_callback else None
    result: dict[str, Any] = {"stage": stage, "parameters": n_params,
                              "train_seconds": round(time.time() - t0, 1), "output_dir": str(output_dir),
                              "best_ckpt": best, "last_ckpt": str(last_checkpoint(output_dir))}  # fmt: skip
    if reinit:
        result["reinitialised"] = reinit
    if resume_ckpt:
        result["resumed_from"] = str(resume_ckpt)
    if run_test:
        result["metrics"] = test_module(module, datamodule, trainer, ckpt_path=best or None)
        if breakdown := module_breakdown(module):  # all-ages test sets: per age band and build
            result["breakdown"] = breakdown
    finish_wandb(trainer)
    return result, trainer


def train(cfg: DictConfig) -> dict[str, Any]:
    """Run the configured stage (and stage 1 first if stage 2 needs it); return the summary."""
    validate_train_config(cfg)
    plan = shared_plan(cfg)
    L.seed_everything(cfg.seed, workers=True)
    output_dir, body = Path(plan["output_dir"]), build_body(cfg)
    summary: dict[str, Any] = {
        "task_name": cfg.task_name,
        "config": OmegaConf.to_container(cfg, resolve=True),
    }
    if plan["resumed_run"]:
        summary["resumed_run"] = plan["resumed_run"]
    init_ckpt = None
    if (s1 := plan["stage1"]) is not None:
        how = s1["how"]
        if how == "train":
            log.info("stage 2: no stage-1 checkpoint given or found -> training stage 1 first")
            s1_run, _ = fit_and_test(cfg, 1, output_dir / "stage1", body, plan, max_epochs=cfg.stage1.epochs,
                                     run_test=False)  # fmt: skip
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
        cfg, cfg.stage, output_dir, body, plan, init_ckpt=init_ckpt, run_test=cfg.test
    )
    summary.update(result)
    if cfg.test and trainer.is_global_zero:  # run files: rank 0 only; the other ranks wait below
        from arteq.eval import write_metrics
        from arteq.training.floor import evaluate_mean_pose

        if cfg.mean_pose_baseline:
            summary["mean_pose_baseline"] = evaluate_mean_pose(cfg, body=body)
        write_metrics(summary, output_dir, method_name(cfg))
    trainer.strategy.barrier("arteq.train: run files written")
    return summary


@hydra.main(version_base="1.3", config_path=str(conf_dir()), config_name="train")
def main(cfg: DictConfig) -> float | None:
    from arteq.runtime import tune_cpu_allocator

    tune_cpu_allocator()
    with exit_on_config_error("arteq.train"):
        summary = train(cfg)
    # Returned for Hydra sweepers: the OOD vertex error.
    return summary.get("metrics", {}).get("test_ood", {}).get("v2v_cm")


if __name__ == "__main__":
    main()
