"""The run plan: where a run writes, which checkpoint(s) it resumes, and how stage 2 is initialised.

:func:`plan_run` decides it from the config (``ckpt_path``, ``resume``, ``stage1.*``; see
``conf/train.yaml``) before anything is built. In a distributed run rank 0 decides it alone and hands
it to the ranks Lightning launches in the environment (:func:`shared_plan`); the
:class:`SamePlanOnAllRanks` callback checks at start-up that every rank follows the same plan.

Resume: ``ckpt_path=<file>`` continues from that checkpoint; ``resume=auto`` continues the newest run of
this task under ``${paths.output_root}/<task>/`` from its newest readable checkpoint, in that run's
folder; ``resume=<run folder>`` names the run. Stage 1 for stage 2: ``stage1.ckpt``, else the newest
matching stage-1 run (:func:`find_stage1_checkpoint`), else it is trained first inside the run.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import lightning as L
from omegaconf import DictConfig, OmegaConf

from arteq.io.runs import checkpoint_dir, newest_last_checkpoints, read_checkpoint

log = logging.getLogger("arteq.train")

#: Data settings a found stage-1 checkpoint must share with the stage-2 run (what the clouds look like).
STAGE1_DATA_KEYS = ("source", "num_points", "augment", "noise_std", "density_contrast", "density_wavelength",
                    "beta_scale", "amass_root", "amass", "wide_poses", "shape_prior",
                    "train_pose_mix")  # fmt: skip
#: Values that settings added after a checkpoint was written have when it does not name them: an older
#: stage-1 checkpoint matches a config that sets them so (what the network / data did before the option).
ADDED_DEFAULTS = {
    "net": {
        "backbone": {"normalize": False},
        "pose_head": {"logit_eps": None, "geometry": False},
        "segmenter": {"group_pool": "mean"},
        "sides": "learned",
        "side_scale": 0.02,
    },
    "data": {"wide_poses": 0.0, "shape_prior": "normal", "train_pose_mix": None},
}
#: Environment variable through which rank 0 hands its run plan to the ranks Lightning launches.
PLAN_ENV = "ARTEQ_RUN_PLAN"


def _with_added_defaults(value: Any, defaults: dict) -> Any:
    """``value`` (a config mapping) with the keys of ``defaults`` it lacks filled in (recursively)."""
    if not isinstance(value, dict):
        return value
    out = dict(value)
    for k, d in defaults.items():
        if isinstance(d, dict):
            if isinstance(out.get(k), dict):
                out[k] = _with_added_defaults(out[k], d)
        elif k not in out:
            out[k] = d
    return out


def _data_signature(data: dict | None) -> dict:
    data = _with_added_defaults(dict(data or {}), ADDED_DEFAULTS["data"])
    return {k: data.get(k) for k in STAGE1_DATA_KEYS}


def _checkpoint_net_config(path: Path) -> dict | None:
    try:
        ckpt = read_checkpoint(path)
    except Exception:  # unreadable or foreign file: not a candidate
        return None
    hp = ckpt.get("hyper_parameters", {})
    keys = {"net": "net", "body": "body_model", "stage": "stage", "data": "data"}
    return {k: hp.get(key) for k, key in keys.items()}


def find_stage1_checkpoint(cfg: DictConfig) -> Path | None:
    """Newest ``last.ckpt`` of a previous stage-1 run with the same network, body model and kind of
    data (``STAGE1_DATA_KEYS``: e.g. a stage 1 trained without rotation augmentation is not reused by an
    augmented stage 2)."""
    want_net = _with_added_defaults(
        OmegaConf.to_container(cfg.model.net, resolve=True), ADDED_DEFAULTS["net"]
    )
    want_net.pop("num_betas", None)
    want_body = {
        k: v for k, v in OmegaConf.to_container(cfg.body_model, resolve=True).items() if k != "_target_"
    }
    want_data = _data_signature(OmegaConf.to_container(cfg.data, resolve=True))
    for path in newest_last_checkpoints(Path(cfg.paths.output_root) / "stage1"):
        info = _checkpoint_net_config(path)
        if info is None or info["stage"] != 1:
            continue
        net = _with_added_defaults(dict(info["net"] or {}), ADDED_DEFAULTS["net"])
        net.pop("num_betas", None)
        if net == want_net and info["body"] == want_body and _data_signature(info["data"]) == want_data:
            return path
    return None


def latest_checkpoint(folder: Path) -> Path | None:
    """The checkpoint in ``folder`` to resume from: the readable one with the highest global step (the
    newest file on a tie). Unreadable ones (e.g. cut short by a kill) are skipped with a warning."""
    best: tuple[tuple[int, float], Path] | None = None
    for path in sorted(Path(folder).glob("*.ckpt")):
        try:
            ckpt = read_checkpoint(path, mmap=True)
            key = (int(ckpt["global_step"]), path.stat().st_mtime)
        except Exception as e:  # truncated, foreign or vanished file
            log.warning("resume: skipping unreadable checkpoint %s (%s)", path, type(e).__name__)
            continue
        if best is None or key > best[0]:
            best = (key, path)
    return None if best is None else best[1]


def _run_checkpoints(run: Path, stage: int) -> dict[str, str]:
    """``{stage: checkpoint}`` to resume a run folder: its own stage, else (stage 2) its inner stage 1."""
    own = latest_checkpoint(checkpoint_dir(run))
    if own is not None:
        return {str(stage): str(own)}
    if stage == 2:
        inner = latest_checkpoint(checkpoint_dir(run / "stage1"))
        if inner is not None:
            return {"1": str(inner)}
    return {}


def _newest_checkpoint_time(run: Path) -> float:
    files = [*run.glob("checkpoints/*.ckpt"), *run.glob("stage1/checkpoints/*.ckpt")]
    return max((f.stat().st_mtime for f in files), default=-1.0)


def _resume(cfg: DictConfig, output_dir: Path) -> tuple[Path | None, dict[str, str]]:
    """(the run folder resumed or None, ``{stage: checkpoint}`` to resume)."""
    if cfg.get("ckpt_path"):
        return None, {str(cfg.stage): str(cfg.ckpt_path)}
    if not cfg.get("resume"):
        return None, {}
    if cfg.resume != "auto":
        run = Path(cfg.resume).expanduser()
        if not (resume := _run_checkpoints(run, cfg.stage)):
            raise FileNotFoundError(f"resume={cfg.resume}: no readable checkpoint in that run folder")
        return run, resume
    root = Path(cfg.paths.output_root) / cfg.task_name
    runs = [p for p in root.glob("*") if p.is_dir() and p.resolve() != output_dir.resolve()]
    runs = sorted((r for r in runs if _newest_checkpoint_time(r) >= 0), key=_newest_checkpoint_time)
    for run in reversed(runs):
        if resume := _run_checkpoints(run, cfg.stage):
            return run, resume
    log.info("resume=auto: no earlier run of %r with a checkpoint under %s: new run", cfg.task_name, root)
    return None, {}


def _stage1(cfg: DictConfig, resume: dict[str, str]) -> dict[str, Any] | None:
    """How stage 2 gets its stage-1 weights: ``{"ckpt": path or None, "how": ...}``; None for stage 1
    or ``stage1.init=false``."""
    if cfg.stage != 2 or not cfg.stage1.init:
        return None
    if "2" in resume:
        return {"ckpt": None, "how": "not used: stage 2 resumed from a checkpoint"}
    if "1" in resume:
        return {"ckpt": None, "how": "train"}
    if cfg.stage1.ckpt:
        return {"ckpt": str(cfg.stage1.ckpt), "how": "given by stage1.ckpt"}
    if cfg.stage1.search and (found := find_stage1_checkpoint(cfg)) is not None:
        return {"ckpt": str(found), "how": "found from a previous stage-1 run"}
    return {"ckpt": None, "how": "train"}


def plan_run(cfg: DictConfig) -> dict[str, Any]:
    """Where this run writes, which checkpoint(s) it resumes, and how stage 2 is initialised."""
    output_dir = Path(cfg.paths.output_dir)
    resumed_run, resume = _resume(cfg, output_dir)
    if resumed_run is not None:
        log.info("resuming run %s from %s (this invocation's own log stays in %s)", resumed_run,
                 resume, output_dir)  # fmt: skip
        output_dir = resumed_run
    return {
        "output_dir": str(output_dir),
        "resume": resume,
        "resumed_run": None if resumed_run is None else str(resumed_run),
        "stage1": _stage1(cfg, resume),
    }


def shared_plan(cfg: DictConfig) -> dict[str, Any]:
    """The run plan every rank follows: rank 0 (or a single process) plans and leaves the plan in the
    environment, which the ranks Lightning launches inherit and read instead of planning again."""
    if os.environ.get("LOCAL_RANK", "0") != "0" and PLAN_ENV in os.environ:  # launched by rank 0
        return json.loads(os.environ[PLAN_ENV])
    plan = plan_run(cfg)
    os.environ[PLAN_ENV] = json.dumps(plan)
    return plan


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
