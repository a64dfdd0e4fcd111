"""Evaluate a trained ArtEq checkpoint on the ID and OOD test sets: ``python -m arteq.eval ckpt_path=...``.

Writes ``metrics.json`` and ``metrics.md`` (a Markdown table) into the run folder. Metrics: part
accuracy (%), V2V (cm, all vertices), MPJPE (cm, the 22 body joints), mean global rotation error per
part (degrees); no alignment of any kind: the fitted body is placed by the model itself. With
``data.view_splits=[front,side,back,top]`` (any subset) the cached single-view test sets are evaluated too,
after the full-surface ones: ``metrics.json`` gets ``test_view_<view>`` entries, ``metrics.md`` their columns.
Test sets drawn with ``data.shape_prior=allages`` (the all-ages body) are also broken down per age band and
per build (:mod:`arteq.training.breakdown`): ``metrics.json["breakdown"]`` and tables in ``metrics.md``.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path
from typing import Any

import hydra
import lightning as L
from omegaconf import DictConfig

from arteq.io import runs
from arteq.paths import conf_dir
from arteq.results import breakdown_markdown, method_name, metrics_markdown, metrics_table, summary_rows
from arteq.training.build import build_datamodule
from arteq.training.module import ArtEqModule

log = logging.getLogger("arteq.eval")


def test_module(module: ArtEqModule, datamodule, trainer: L.Trainer, ckpt_path: str | None = None) -> dict:
    """Run ``trainer.test`` on the datamodule's test sets (``data.test_splits``, then the single-view sets of
    ``data.view_splits``); return ``{split: {metric: value}}``."""
    trainer.test(module, datamodule=datamodule, ckpt_path=ckpt_path or None, verbose=False)
    return module.test_results


def module_breakdown(module: ArtEqModule) -> dict[str, Any]:
    """The last :func:`test_module` run's metrics per age band and build (``{split: {grouping: ...}}``;
    empty unless its test sets were drawn with the all-ages prior)."""
    return dict(getattr(module, "test_breakdown", None) or {})


def write_metrics(summary: dict[str, Any], output_dir: Path, method: str) -> None:
    """Write ``metrics.json`` (everything) and ``metrics.md`` (the table: ``method``'s row, and the
    mean-pose floor's if the summary has one; then the per-age-band and per-build tables when the summary
    has a ``breakdown``) atomically, and log the table."""
    rows = summary_rows(summary, method)
    markdown = metrics_markdown(summary.get("task_name", "run"), rows)
    if summary.get("breakdown"):
        markdown += "\n\n" + breakdown_markdown(summary["breakdown"])
    path = runs.write_metrics(output_dir, summary, markdown)
    log.info("metrics written to %s\n%s", path, metrics_table(rows))


def default_output_dir(ckpt: Path) -> Path:
    """A training checkpoint's run folder; for any other file (a shipped model), this eval's own folder."""
    if ckpt.parent.name == "checkpoints":
        return ckpt.parent.parent
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        return Path(HydraConfig.get().runtime.output_dir)
    return Path.cwd() / "outputs" / "eval"


def evaluate(cfg: DictConfig) -> dict[str, Any]:
    """Load ``cfg.ckpt_path`` and evaluate it on the configured test sets.

    Works on several processes too (``+trainer.strategy=ddp trainer.devices=N``): each rank tests its
    shard of the sets, metrics are summed over ranks, and rank 0 alone writes the files.
    """
    from arteq.pretrained import resolve_checkpoint
    from arteq.training.validate import validate_eval_config

    try:  # a path, or the name of a shipped model (`ckpt_path=anny22`)
        ckpt = resolve_checkpoint(cfg.ckpt_path)
    except FileNotFoundError as err:
        raise FileNotFoundError(f"ckpt_path={cfg.ckpt_path}: {err}") from None
    validate_eval_config(cfg)
    module = runs.load_module(ckpt)
    # test data on the checkpoint's body (the one it was trained on; conf's body_model is not used): a
    # copy of the module's, which the trainer moves to its device
    # (data.fps_points: auto is resolved against the checkpoint's network)
    datamodule = build_datamodule(cfg, body=copy.deepcopy(module.body), net=module.hparams.net)
    trainer = hydra.utils.instantiate(cfg.trainer, logger=False, callbacks=[])
    metrics = test_module(module, datamodule, trainer)
    out_dir = Path(cfg.output_dir) if cfg.get("output_dir") else default_output_dir(ckpt)
    summary = {"task_name": f"eval {ckpt}", "ckpt_path": str(ckpt), "metrics": metrics}
    if breakdown := module_breakdown(module):
        summary["breakdown"] = breakdown
    if trainer.is_global_zero:
        trained = {"model": {"net": module.hparams.net}, "data": module.hparams.data}
        write_metrics(summary, out_dir, method_name(trained))
    trainer.strategy.barrier("arteq.eval: metrics written")
    return summary


@hydra.main(version_base="1.3", config_path=str(conf_dir()), config_name="eval")
def main(cfg: DictConfig) -> None:
    from arteq.runtime import tune_cpu_allocator
    from arteq.training.validate import exit_on_config_error

    tune_cpu_allocator()  # as arteq.train: large temporaries reused, not page-faulted in again
    with exit_on_config_error("arteq.eval"):
        evaluate(cfg)


if __name__ == "__main__":
    main()
