"""Figures of ``python -m arteq.report``: convergence, error per body part, qualitative OOD fits."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np  # noqa: E402
from matplotlib.figure import Figure

from arteq.body.skeleton import JOINT_NAMES  # noqa: E402
from arteq.io.runs import Run, body_config, data_kwargs, load_module  # noqa: E402

log = logging.getLogger("arteq.report")


def _label(run: Run) -> str:
    return f"{run.method} ({run.num_points} pts)" if run.num_points is not None else run.method


def convergence_plot(runs: list[Run], out: Path) -> Path:
    """Validation V2V, MPJPE and part accuracy per epoch, one line per run with curves."""
    keys = [
        ("val/v2v_cm", "val V2V (cm)"),
        ("val/mpjpe_cm", "val MPJPE (cm)"),
        ("val/part_acc", "val part acc (%)"),
    ]
    fig = Figure(figsize=(15, 4))
    axes = fig.subplots(1, 3)
    for run in runs:
        if not run.curves:
            continue
        for ax, (key, _) in zip(axes, keys):
            pts = [(c.get("epoch", i), c[key]) for i, c in enumerate(run.curves) if key in c]
            if pts:
                x, y = zip(*pts)
                ax.plot(np.asarray(x) + 1, y, marker="o", label=_label(run))
    for ax, (_, title) in zip(axes, keys):
        ax.set_xlabel("epoch")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return out


def per_part_plot(runs: list[Run], out: Path) -> Path:
    """Global rotation error per body part (test_id and test_ood), grouped bars per run."""
    with_parts = [r for r in runs if "rot_err_deg_per_part" in r.metrics.get("test_ood", {})]
    fig = Figure(figsize=(14, 7))
    axes = fig.subplots(2, 1, sharex=True)
    width = 0.8 / max(1, len(with_parts))
    x = np.arange(len(JOINT_NAMES))
    for ax, split in zip(axes, ("test_id", "test_ood")):
        for i, run in enumerate(with_parts):
            per = run.metrics.get(split, {}).get("rot_err_deg_per_part") or {}
            y = [per.get(j, np.nan) for j in JOINT_NAMES]
            ax.bar(x + (i - (len(with_parts) - 1) / 2) * width, y, width, label=_label(run))
        ax.set_ylabel(f"{split} rot err (deg)")
        ax.grid(axis="y", alpha=0.3)
    axes[0].legend(fontsize=7, ncol=2)
    axes[1].set_xticks(x, JOINT_NAMES, rotation=60, ha="right", fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return out


def _scatter(ax, pts: np.ndarray, color: str, title: str, size: float = 1.0) -> None:
    ax.scatter(pts[:, 0], pts[:, 1], s=size, c=color, linewidths=0)
    ax.set_title(title, fontsize=8)
    ax.set_aspect("equal")
    ax.axis("off")


def qualitative_figure(runs: list[Run], out: Path, samples: int = 3, max_methods: int = 5) -> Path | None:
    """Input cloud, ground truth and each network run's fit for the first ``samples`` OOD clouds.

    The clouds are the test_ood set of the first run's data config; every network (at most
    ``max_methods``, each from its run's checkpoint) fits those same clouds. Front view (x right, y up).
    Returns None if no run has a checkpoint.
    """
    import torch

    from arteq.data import BodyScanDataModule

    nets = []
    for run in runs:
        if run.arch == "fitter" or len(nets) >= max_methods:
            continue
        try:
            module = load_module(run.path)
        except Exception as e:  # no checkpoint, or one of an older code version: leave the run out
            log.warning("%s: left out of the qualitative figure (%s: %s)", run.path, type(e).__name__, e)
            continue
        nets.append((run, module))
    if not nets:
        return None
    first = nets[0][0]
    data = data_kwargs(first.config)
    data.update(test_size=max(samples, 1), num_workers=0)
    dm = BodyScanDataModule(body_model=body_config(first.config), **data)
    ds = dm.fixed_set("test_ood")
    items = [ds[i] for i in range(min(samples, len(ds)))]
    batch = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    body = dm.body
    with torch.no_grad():
        gt = body(betas=batch["betas"], pose=batch["pose"], transl=batch["transl"]).vertices
    preds = []
    for run, module in nets:
        with torch.no_grad():
            preds.append((_label(run), module(batch["points"])["vertices"]))
    n = len(items)
    cols = 2 + len(preds)
    fig = Figure(figsize=(2.4 * cols, 2.8 * n))
    axes = fig.subplots(n, cols, squeeze=False)
    step = max(1, gt.shape[1] // 3000)
    for i in range(n):
        _scatter(axes[i, 0], batch["points"][i].numpy(), "0.2", "input cloud", 1.5)
        _scatter(axes[i, 1], gt[i, ::step].numpy(), "tab:green", "ground truth")
        for j, (name, v) in enumerate(preds):
            v2v = float((v[i] - gt[i]).norm(dim=-1).mean()) * 100
            _scatter(axes[i, 2 + j], v[i, ::step].numpy(), "tab:blue", f"{name}\nV2V {v2v:.1f} cm")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    return out
