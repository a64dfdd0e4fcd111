"""Evaluate a trained ArtEq checkpoint on the ID and OOD test sets: ``python -m arteq.eval ckpt_path=...``.

Writes ``metrics.json`` and ``metrics.md`` (a Markdown table) into the run folder. Metrics: part
accuracy (%), V2V (cm, all vertices), MPJPE (cm, the 22 body joints), mean global rotation error per
part (degrees); no alignment of any kind: the fitted body is placed by the model itself.
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import hydra
import lightning as L
import roma
import torch
import torch.nn.functional as F
from omegaconf import DictConfig, OmegaConf

from arteq.body.skeleton import local_to_global
from arteq.models.placement import estimate_translation
from arteq.training.metrics import BodyFitMetrics
from arteq.training.module import TEST_SPLITS, ArtEqModule

log = logging.getLogger("arteq.eval")

METRIC_KEYS = ("part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg")


def _nest(flat: dict[str, Any]) -> dict[str, dict[str, float]]:
    out: dict[str, dict[str, float]] = {}
    for key, value in flat.items():
        split, _, name = key.partition("/")
        if split in TEST_SPLITS and name:
            out.setdefault(split, {})[name] = float(value)
        elif split.endswith("_rot_per_part") and split[: -len("_rot_per_part")] in TEST_SPLITS:
            out.setdefault(split[: -len("_rot_per_part")], {}).setdefault("rot_err_deg_per_part", {})
            out[split[: -len("_rot_per_part")]]["rot_err_deg_per_part"][name] = float(value)
    return out


def test_module(module: ArtEqModule, datamodule, trainer: L.Trainer, ckpt_path: str | None = None) -> dict:
    """Run ``trainer.test`` on [test_id, test_ood]; return ``{split: {metric: value}}``."""
    trainer.test(module, datamodule=datamodule, ckpt_path=ckpt_path or None, verbose=False)
    return _nest({k: v.item() if torch.is_tensor(v) else v for k, v in trainer.callback_metrics.items()})


@torch.no_grad()
def evaluate_mean_pose(cfg: DictConfig, train_samples: int = 256) -> dict[str, dict[str, float]]:
    """The floor: predict the training set's mean pose and mean shape, placed like ArtEq places bodies.

    Mean local rotation per joint = SO(3) projection of the average training rotation matrix (training
    poses before any rotation augmentation);
    betas = 0 (the shape space's mean). Translation uses the ground-truth part labels (generous).
    """
    from arteq.training.build import build_datamodule, build_module

    dm = build_datamodule(cfg)
    dm.setup("fit")
    module = build_module(cfg, stage=cfg.stage)
    body = module.body
    # the training poses without rotation augmentation: with so3 augmentation the mean root
    # orientation would be meaningless, and this floor is about the pose distribution itself
    train_ds = dm.make_dataset("train")
    n = min(train_samples, len(train_ds))
    poses = torch.stack([train_ds.source_sample(i)["pose"] for i in range(n)])
    poses = roma.rotvec_to_rotmat(poses.double())
    mean_local = roma.special_procrustes(poses.mean(0)).float()  # [22, 3, 3]
    dm.setup("test")
    out: dict[str, dict[str, float]] = {}
    for split, loader in zip(TEST_SPLITS, dm.test_dataloader()):
        # this process's own evaluation (run on rank 0 only in a distributed run): no cross-rank sync
        metric = BodyFitMetrics(sync_on_compute=False)
        for batch in loader:
            b = batch["points"].shape[0]
            gt = module.ground_truth(batch)
            pose = mean_local.expand(b, -1, -1, -1)
            pred = body(betas=torch.zeros(b, body.num_betas), pose=pose)
            onehot = F.one_hot(batch["labels"], module.net.num_parts).float()
            t = estimate_translation(pred.vertices, module.centroid_matrix, batch["points"], onehot)
            metric.update(
                pred.vertices + t[:, None], gt["vertices"], pred.joints + t[:, None], gt["joints"],
                local_to_global(pose), gt["global_rotmats"],
                torch.full_like(batch["labels"], -1), batch["labels"],
            )  # fmt: skip
        values = metric.compute()
        values.pop("rot_err_deg_per_part")
        values.pop("part_acc")  # no segmentation: not applicable
        out[split] = {k: float(v) for k, v in values.items()}
    return out


def _fmt(x: Any) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.2f}"


def metrics_table(rows: dict[str, dict[str, dict[str, float]]]) -> str:
    """Markdown table: one row per method, ID and OOD columns for each metric."""
    head = "| method | " + " | ".join(f"{s} {m}" for m in METRIC_KEYS for s in ("ID", "OOD")) + " |"
    sep = "|---|" + "---:|" * (2 * len(METRIC_KEYS))
    lines = [head, sep]
    for name, res in rows.items():
        cells = [_fmt(res.get(s, {}).get(m)) for m in METRIC_KEYS for s in TEST_SPLITS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_metrics(summary: dict[str, Any], output_dir: Path) -> None:
    """Write ``metrics.json`` (everything) and ``metrics.md`` (the table) atomically."""
    output_dir.mkdir(parents=True, exist_ok=True)
    rows = {"ArtEq": summary.get("metrics", {})}
    if "mean_pose_baseline" in summary:
        rows["mean pose (floor)"] = summary["mean_pose_baseline"]
    md = [f"# {summary.get('task_name', 'run')}: test metrics", "", metrics_table(rows), ""]
    md.append("part_acc in %, v2v/mpjpe in cm (MPJPE over the 22 body joints), rot_err in degrees.")
    for name, text in (
        ("metrics.json", json.dumps(summary, indent=2, default=str)),
        ("metrics.md", "\n".join(md)),
    ):
        tmp = output_dir / f".{name}.tmp"
        tmp.write_text(text + "\n")
        tmp.replace(output_dir / name)
    log.info("metrics written to %s\n%s", output_dir / "metrics.md", metrics_table(rows))


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
    from arteq.training.validate import validate_eval_config

    from arteq.pretrained import resolve_checkpoint

    try:  # a path, or the name of a shipped model (`ckpt_path=anny22`)
        ckpt = resolve_checkpoint(cfg.ckpt_path)
    except FileNotFoundError as err:
        raise FileNotFoundError(f"ckpt_path={cfg.ckpt_path}: {err}") from None
    validate_eval_config(cfg)
    module = ArtEqModule.load_from_checkpoint(str(ckpt), map_location="cpu", weights_only=True)
    cfg.body_model = OmegaConf.create(module.hparams.body_model)
    from arteq.training.build import build_datamodule

    datamodule = build_datamodule(cfg)
    trainer = hydra.utils.instantiate(cfg.trainer, logger=False, callbacks=[])
    metrics = test_module(module, datamodule, trainer)
    out_dir = Path(cfg.output_dir) if cfg.get("output_dir") else default_output_dir(ckpt)
    summary = {"task_name": f"eval {ckpt}", "ckpt_path": str(ckpt), "metrics": metrics}
    if trainer.is_global_zero:
        write_metrics(summary, out_dir)
    trainer.strategy.barrier("arteq.eval: metrics written")
    return summary


@hydra.main(version_base="1.3", config_path="../../conf", config_name="eval")
def main(cfg: DictConfig) -> None:
    from arteq.training.validate import exit_on_config_error

    with exit_on_config_error("arteq.eval"):
        evaluate(cfg)


if __name__ == "__main__":
    main()
