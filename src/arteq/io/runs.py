"""Run folders: where a run keeps its files, and how every command finds, reads and writes them.

A run folder (``outputs/<task>/<time>/``, or ``outputs/multirun/<task>/<time>/<job>/``) holds::

    .hydra/config.yaml          the composed config (Hydra)
    checkpoints/epoch*.ckpt     the best checkpoint (monitored metric); checkpoints/last.ckpt
    csv/metrics.csv             per-step / per-epoch logs (CSVLogger)
    metrics.json, metrics.md    test results (everything / the Markdown table), written together
    stage1/                     a stage-1 run trained inside a stage-2 run (same layout, no metrics)

A sweep is any folder holding run folders. Importing this module loads neither Lightning nor torch
(a report reads run folders without them); :func:`load_module` imports the LightningModule
(and with it Lightning and torch) when it is called.
"""

from __future__ import annotations

import csv
import json
import logging
import math
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arteq.io.fits import AtomicFiles
from arteq.results import architecture, base_method_name, config_get, method_name

log = logging.getLogger(__name__)

METRICS_JSON = "metrics.json"
METRICS_MD = "metrics.md"
CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.ckpt"
BEST_CHECKPOINT_GLOB = "epoch*.ckpt"
CONFIG_YAML = ".hydra/config.yaml"
CSV_METRICS = "csv/metrics.csv"


# ------------------------------------------------------------------ checkpoints and config
def checkpoint_dir(run_dir: str | Path) -> Path:
    """``<run>/checkpoints``: where the checkpoint callback of a run writes."""
    return Path(run_dir) / CHECKPOINT_DIR


def last_checkpoint(run_dir: str | Path) -> Path:
    """``<run>/checkpoints/last.ckpt`` (may not exist yet)."""
    return checkpoint_dir(run_dir) / LAST_CHECKPOINT


def find_checkpoint(run_dir: str | Path, which: str = "best") -> Path:
    """A run's checkpoint: ``best`` = the monitored one (``epoch*.ckpt``, newest name), falling back to
    ``last.ckpt``; ``last`` = ``last.ckpt`` only."""
    if which not in ("best", "last"):
        raise ValueError(f"find_checkpoint: which must be 'best' or 'last', got {which!r}")
    run_dir = Path(run_dir)
    if which == "best":
        ckpts = sorted(checkpoint_dir(run_dir).glob(BEST_CHECKPOINT_GLOB))
        if ckpts:
            return ckpts[-1]
    last = last_checkpoint(run_dir)
    if last.is_file():
        return last
    wanted = f"{CHECKPOINT_DIR}/{BEST_CHECKPOINT_GLOB} or " if which == "best" else ""
    raise FileNotFoundError(f"{run_dir}: no {wanted}{CHECKPOINT_DIR}/{LAST_CHECKPOINT}")


def run_dir_of(ckpt: str | Path) -> Path:
    """The run folder of a checkpoint file (``<run>/checkpoints/x.ckpt`` -> ``<run>``)."""
    return Path(ckpt).parent.parent


def newest_last_checkpoints(root: str | Path) -> list[Path]:
    """``last.ckpt`` of every run directly under ``root``, newest first (e.g. earlier stage-1 runs)."""
    paths = Path(root).glob(f"*/{CHECKPOINT_DIR}/{LAST_CHECKPOINT}")
    return sorted(paths, key=lambda p: p.stat().st_mtime, reverse=True)


def read_checkpoint(path: str | Path, mmap: bool = False) -> dict[str, Any]:
    """A checkpoint file's dict on the CPU, read with ``torch.load(weights_only=True)`` (tensors and plain
    Python only: no pickled code runs); ``mmap`` maps the tensors instead of reading them (metadata only)."""
    import torch

    return torch.load(str(path), map_location="cpu", weights_only=True, mmap=mmap)


def load_module(run_or_ckpt: str | Path | None = None, which: str = "best", map_location: str = "cpu"):
    """The trained :class:`arteq.training.ArtEqModule` of a run folder (its ``which`` checkpoint), of a
    checkpoint file, or of a shipped model by name (``anny22``; None: the default one, see
    :mod:`arteq.pretrained`), in eval mode. Loaded with ``weights_only=True``; the body is rebuilt from
    its config, never read from the checkpoint. The one loader of trained modules."""
    from arteq.pretrained import resolve_checkpoint
    from arteq.training.module import ArtEqModule

    if run_or_ckpt is not None and Path(run_or_ckpt).is_dir():
        ckpt = find_checkpoint(run_or_ckpt, which)
    else:
        ckpt = resolve_checkpoint(run_or_ckpt)
    module = ArtEqModule.load_from_checkpoint(str(ckpt), map_location=map_location, weights_only=True)
    return module.eval()


def read_config(run_dir: str | Path, resolve: bool = False) -> dict[str, Any]:
    """A run's composed config (``.hydra/config.yaml``) as plain Python."""
    from omegaconf import OmegaConf

    path = Path(run_dir) / CONFIG_YAML
    if not path.is_file():
        raise FileNotFoundError(f"{path}: not found (is {run_dir} a training run folder?)")
    return OmegaConf.to_container(OmegaConf.load(path), resolve=resolve)


def data_kwargs(config: dict[str, Any]) -> dict[str, Any]:
    """Keyword arguments of :class:`arteq.data.BodyScanDataModule` from a run's config (its ``data``
    section without ``_target_`` and ``body_model``; pass the body separately)."""
    return {k: v for k, v in (config.get("data") or {}).items() if k not in ("_target_", "body_model")}


def body_config(config: dict[str, Any]) -> dict[str, Any]:
    """A run's ``body_model`` section without ``_target_`` (as checkpoints record it; empty: the
    default body), for :func:`arteq.body.create_body`."""
    return {k: v for k, v in (config.get("body_model") or {}).items() if k != "_target_"}


# ------------------------------------------------------------------ test results
def write_metrics(run_dir: str | Path, summary: dict[str, Any], markdown: str) -> Path:
    """Write ``metrics.json`` (the whole summary) and ``metrics.md`` (``markdown``) together, atomically:
    both appear, or neither changes. Returns the ``metrics.md`` path."""
    run_dir = Path(run_dir)
    with AtomicFiles() as files:
        text = json.dumps(summary, indent=2, default=str) + "\n"
        files.write_bytes(run_dir / METRICS_JSON, text.encode())
        files.write_bytes(run_dir / METRICS_MD, (markdown + "\n").encode())
    return run_dir / METRICS_MD


def read_metrics(run_dir: str | Path) -> dict[str, Any]:
    """A run's ``metrics.json``, checked to hold a ``metrics`` mapping."""
    path = Path(run_dir) / METRICS_JSON
    try:
        summary = json.loads(path.read_text())
    except FileNotFoundError:
        raise FileNotFoundError(f"{path}: not found") from None
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(summary, dict) or not isinstance(summary.get("metrics"), dict):
        raise ValueError(
            f"{path}: expected an object with a 'metrics' mapping {{test_id: ..., test_ood: ...}}"
        )
    return summary


def read_curves(run_dir: str | Path) -> list[dict[str, float]]:
    """Per-epoch validation rows of a run's ``csv/metrics.csv`` (rows holding ``val/v2v_cm``)."""
    path = Path(run_dir) / CSV_METRICS
    if not path.is_file():
        return []
    rows = []
    with path.open(newline="") as f:
        for row in csv.DictReader(f):
            if row.get("val/v2v_cm") not in (None, ""):
                rows.append({k: float(v) for k, v in row.items() if v not in (None, "")})
    return rows


# ------------------------------------------------------------------ runs of a sweep
@dataclass
class Run:
    """One run folder with test results: its ``metrics.json``, config and (optional) curves.

    Fitter evaluations (``python -m arteq.optim_fit.evaluate``) are runs too: their summary names the
    ``method``, their ``arch`` is ``"fitter"``.
    """

    path: Path
    summary: dict[str, Any]
    config: dict[str, Any]
    curves: list[dict[str, float]] = field(default_factory=list)

    @property
    def metrics(self) -> dict[str, dict[str, Any]]:
        return self.summary.get("metrics") or {}

    @property
    def arch(self) -> str:
        return "fitter" if self.summary.get("method") else architecture(self.config)

    @property
    def augment(self) -> str:
        return str(config_get(self.config, "data.augment", "none"))

    @property
    def num_points(self) -> int | None:
        n = config_get(self.config, "data.num_points")
        return int(n) if n is not None else None

    @property
    def parent_conditioning(self) -> bool:
        from arteq.models.heads import parent_mode

        return parent_mode(config_get(self.config, "model.net.parent_conditioning", True)) != "none"

    @property
    def base_name(self) -> str:
        """Method without its augmentation suffix (``ArtEq``, ``ArtEq nc``, ``PointNet++``...)."""
        return str(self.summary["method"]) if self.summary.get("method") else base_method_name(self.config)

    @property
    def method(self) -> str:
        return str(self.summary["method"]) if self.summary.get("method") else method_name(self.config)

    @property
    def inference_ms(self) -> float | None:
        """Per-sample time: the fitter's seconds per sample, or a measured network forward time."""
        fit = self.summary.get("fit")
        if fit:
            vals = [v["seconds_per_sample"] for v in fit.values() if "seconds_per_sample" in v]
            return 1000 * sum(vals) / len(vals) if vals else None
        return self.summary.get("inference_ms")

    @property
    def mtime(self) -> float:
        return (self.path / METRICS_JSON).stat().st_mtime

    def metric(self, split: str, key: str) -> float | None:
        v = self.metrics.get(split, {}).get(key)
        return None if v is None or (isinstance(v, float) and math.isnan(v)) else float(v)


def load_run(run_dir: str | Path) -> Run:
    """Read ``metrics.json`` (required), the config (``metrics.json["config"]``, else
    ``.hydra/config.yaml``) and the curves of one run folder."""
    run_dir = Path(run_dir)
    summary = read_metrics(run_dir)
    config = summary.get("config") or {}
    if not config and (run_dir / CONFIG_YAML).is_file():
        config = read_config(run_dir)
    return Run(run_dir, summary, config, read_curves(run_dir))


def find_runs(dirs: Iterable[str | Path]) -> list[Run]:
    """Every run under ``dirs`` (a folder with ``metrics.json``; a stage-1 sub-run has none)."""
    runs = []
    for d in map(Path, dirs):
        if not d.exists():
            raise FileNotFoundError(f"{d}: no such run or sweep folder")
        found = sorted(p.parent for p in d.rglob(METRICS_JSON))
        if not found:
            log.warning("%s: no %s found under it", d, METRICS_JSON)
        runs += [load_run(p) for p in found]
    return runs


def latest_by(runs: Iterable[Run], key: Callable[[Run], Hashable]) -> dict[Hashable, Run]:
    """Newest run (by ``metrics.json`` mtime) per ``key(run)``."""
    out: dict[Hashable, Run] = {}
    for r in sorted(runs, key=lambda r: r.mtime):
        out[key(r)] = r
    return out
