"""Start-up checks of a composed config: a bad value fails before anything is built or trained.

Each problem raises :class:`ConfigError` with one line naming the key, the value given and the values
allowed, e.g. ``data.num_points=0: allowed: an integer >= 1 (the paper uses 5000)``. The entry points
(``python -m arteq.train`` / ``arteq.eval``) print that line and exit with status 2 instead of a traceback.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import MissingMandatoryValue

from arteq.body.model import ANNY_BODIES, BODY_NAMES
from arteq.data.datamodule import TRAIN_MIX_SOURCES
from arteq.data.dataset import AUGMENTS
from arteq.data.shapes import SHAPE_PRIORS
from arteq.models.heads import PARENT_MODES
from arteq.models.registry import ARCHITECTURES, DEFAULT_ARCH
from arteq.models.sides import SIDE_MODES
from arteq.results import TEST_SPLITS, VIEW_NAMES, view_split
from arteq.training import optim
from arteq.training.losses import DEFAULT_WEIGHTS

# The allowed values come from the code that consumes them (tests/test_config_validation.py pins each list
# to its consumer); only what that code keeps no list of is spelled out here.


def _lightning_precisions() -> tuple[str, ...]:
    """Every ``trainer.precision`` Lightning accepts (its ``_PRECISION_INPUT`` type), as strings."""
    from typing import get_args

    from lightning.fabric.connector import _PRECISION_INPUT

    return tuple(str(v) for group in get_args(_PRECISION_INPUT) for v in get_args(group))


#: Values of ``trainer.precision``: Lightning's names and aliases (``32``, ``bf16``...).
PRECISIONS = _lightning_precisions()
#: Architectures of ``model.net.arch`` (:data:`arteq.models.registry.ARCHITECTURES`).
ARCHS = tuple(ARCHITECTURES)
#: Bodies :func:`arteq.body.create_body` builds: those of :func:`arteq.body.model.load_body_model`
#: (:data:`~arteq.body.model.BODY_NAMES`) and the procedural ``toy`` body it builds itself.
BODY_MODELS = (*BODY_NAMES, "toy")
#: Bodies built without a file from the user (``body_model.model_path: null``).
FILELESS_BODIES = (*ANNY_BODIES, "toy")
#: ``data.source`` values (:class:`arteq.data.BodyScanDataModule` checks them but keeps no list).
DATA_SOURCES = ("synthetic", "amass")
_MISSING = object()


class ConfigError(ValueError):
    """An invalid configuration value. ``key``: dotted config key; the message is a single line."""

    def __init__(self, key: str, value: Any, allowed: str) -> None:
        shown = "(not set)" if value is _MISSING else repr(value) if isinstance(value, str) else value
        super().__init__(f"{key}={shown}: allowed: {allowed}")
        self.key, self.value, self.allowed = key, value, allowed


class ConfigPathError(ConfigError, FileNotFoundError):
    """A configured file or folder that does not exist (also a ``FileNotFoundError``)."""


def _get(cfg: DictConfig, key: str, default: Any = None) -> Any:
    try:
        value = OmegaConf.select(cfg, key, default=default, throw_on_missing=True)
    except MissingMandatoryValue:
        return _MISSING
    if isinstance(value, DictConfig | ListConfig):
        return OmegaConf.to_container(value, resolve=True)
    return value


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


def _int_at_least(cfg: DictConfig, key: str, low: int, allow_none: bool = False, hint: str = "") -> Any:
    v = _get(cfg, key)
    if v is None and allow_none:
        return None
    if not _is_int(v) or v < low:
        extra = " or null" if allow_none else ""
        raise ConfigError(key, v, f"an integer >= {low}{extra}{hint}")
    return v


def _one_of(cfg: DictConfig, key: str, options: Iterable[str], default: Any = None) -> Any:
    v = _get(cfg, key, default)
    options = tuple(options)
    if v not in options:
        raise ConfigError(key, v, " | ".join(options))
    return v


def _positive_float(cfg: DictConfig, key: str, hint: str = "") -> float:
    v = _get(cfg, key)
    ok = isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) and v > 0
    if not ok:
        raise ConfigError(key, v, f"a finite number > 0{hint}")
    return float(v)


def _existing_path(cfg: DictConfig, key: str, what: str, folder_ok: bool = False) -> None:
    v = _get(cfg, key)
    if v is None:
        return
    if v is _MISSING or str(v) in ("", "???"):
        raise ConfigError(key, _MISSING, what)
    p = Path(str(v)).expanduser()
    if not (p.is_file() or (folder_ok and p.is_dir())):
        raise ConfigPathError(key, str(v), f"{what} (no such {'file or folder' if folder_ok else 'file'})")


def world_size(cfg: DictConfig) -> int | None:
    """Processes a run will use (``trainer.devices * trainer.num_nodes``), or None if not known up front."""
    devices = _get(cfg, "trainer.devices", 1)
    nodes = _get(cfg, "trainer.num_nodes", 1) or 1
    if isinstance(devices, list):
        devices = len(devices)
    if isinstance(devices, str) and devices.isdigit():
        devices = int(devices)
    if not _is_int(devices) or devices < 1 or not _is_int(nodes):
        return None
    return devices * nodes


def validate_body_model(cfg: DictConfig) -> None:
    name = str(_one_of(cfg, "body_model.name", BODY_MODELS)).lower()
    path = _get(cfg, "body_model.model_path")
    fileless = name in FILELESS_BODIES
    if not fileless and (path is None or path is _MISSING):
        raise ConfigError(
            "body_model.model_path",
            _MISSING,
            f"the licensed {name.upper()} model file or folder (.pkl / .npz)",
        )
    _existing_path(
        cfg,
        "body_model.model_path",
        f"null (the cached {name} build)" if fileless else "an existing model file or folder",
        folder_ok=not fileless,
    )
    _int_at_least(cfg, "body_model.num_betas", 1)


AMASS_ROOT = "the AMASS folder (DFaust_67/ + MPI_Limits/ of SMPL+H G, or DFaust/ + PosePrior/ of SMPL-X G)"


def validate_amass(cfg: DictConfig) -> None:
    """``data.amass`` options, then the AMASS root itself (every sub-dataset found, every motion file with
    its keys): a bad download fails in one line before anything is built (:mod:`arteq.data.amass`)."""
    from arteq.data.amass import AmassConfigError, AmassError, AmassNotFoundError, check_amass_config

    root = str(_get(cfg, "data.amass_root"))
    try:
        check_amass_config(
            root,
            _get(cfg, "data.amass") or {},
            _get(cfg, "data.amass_ood_datasets", ["PosePrior"]),
            ood_stride=_get(cfg, "data.amass_ood_stride"),
        )
    except AmassConfigError as e:
        raise ConfigError(e.key, e.value, e.allowed) from None
    except AmassError as e:
        error = ConfigPathError if isinstance(e, AmassNotFoundError) else ConfigError
        raise error("data.amass_root", root, f"an AMASS root as in docs/data.md; {e}") from None


def validate_data(cfg: DictConfig, processes: int | None = None) -> None:
    source = _one_of(cfg, "data.source", DATA_SOURCES)
    if source == "amass":
        _existing_path(cfg, "data.amass_root", AMASS_ROOT, True)
        if _get(cfg, "data.amass_root") is None:
            raise ConfigError("data.amass_root", None, AMASS_ROOT)
        validate_amass(cfg)
    _int_at_least(cfg, "data.num_points", 1, hint=" (500..5000 in the paper's study; 5000 = paper)")
    noise = _get(cfg, "data.noise_std")
    if not (isinstance(noise, int | float) and math.isfinite(noise) and 0 <= noise < 0.05):
        raise ConfigError("data.noise_std", noise, "metres in [0, 0.05) (e.g. 0.001 = 1 mm)")
    _one_of(cfg, "data.augment", AUGMENTS)
    _one_of(cfg, "data.eval_augment", AUGMENTS)
    if _one_of(cfg, "data.shape_prior", SHAPE_PRIORS, "normal") == "allages":
        body = _get(cfg, "body_model.name")
        if body != "anny_allages":
            raise ConfigError(
                "data.shape_prior", "allages",
                f"normal with body_model={body}: allages draws the all-ages body's stored shapes "
                "(use body_model=anny_allages)",
            )  # fmt: skip
    mix = _get(cfg, "data.train_pose_mix")
    if mix is not None:
        ok = isinstance(mix, dict) and mix and all(k in TRAIN_MIX_SOURCES for k in mix)
        ok = ok and all(isinstance(w, int | float) and not isinstance(w, bool) for w in mix.values())
        ok = ok and all(math.isfinite(w) and w >= 0 for w in mix.values()) and sum(mix.values()) > 0
        if not ok:
            raise ConfigError(
                "data.train_pose_mix", mix,
                f"null, or weights >= 0 (not all 0) over {' | '.join(TRAIN_MIX_SOURCES)}, "
                "e.g. {id: 0.4, ood: 0.4, limb1: 0.1, limb2: 0.1}",
            )  # fmt: skip
    splits = _get(cfg, "data.test_splits")
    if splits is not None and (
        not isinstance(splits, list) or not splits or any(s not in TEST_SPLITS for s in splits)
    ):
        raise ConfigError("data.test_splits", splits, f"a non-empty list of {' | '.join(TEST_SPLITS)}")
    views = _get(cfg, "data.view_splits")
    if views is not None and (not isinstance(views, list) or any(view_split(v) is None for v in views)):
        raise ConfigError(
            "data.view_splits", views,
            f"a list of {' | '.join(VIEW_NAMES)} (or test_view_<view>), [] = none: the single-view test sets",
        )  # fmt: skip
    synthetic = source == "synthetic"
    sizes = {}
    for key in ("train_size", "val_size", "test_size"):
        sizes[key] = _int_at_least(cfg, f"data.{key}", 1, allow_none=not synthetic)
    batch = _int_at_least(cfg, "data.batch_size", 1)
    _int_at_least(cfg, "data.num_workers", 0)
    fps = _get(cfg, "data.fps_points")
    if not (fps is None or fps == "auto" or (_is_int(fps) and 0 <= fps <= _get(cfg, "data.num_points"))):
        raise ConfigError(
            "data.fps_points", fps, "null | auto | an integer in 0..data.num_points (FPS indices per cloud)"
        )
    eval_batch = _int_at_least(cfg, "data.eval_batch_size", 1, allow_none=True)
    procs = processes or 1
    if sizes["train_size"] is not None and batch > sizes["train_size"] // procs:
        share = sizes["train_size"] // procs
        where = f" ({procs} processes share data.train_size={sizes['train_size']})" if procs > 1 else ""
        raise ConfigError(
            "data.batch_size", batch, f"1..{max(share, 1)}: at most the training samples per process{where}"
        )
    eval_key, eb = (
        ("data.eval_batch_size", eval_batch) if eval_batch is not None else ("data.batch_size", batch)
    )
    for key in ("val_size", "test_size"):
        n = sizes[key]
        if n is not None and eb > n:
            raise ConfigError(eval_key, eb, f"1..{n}: at most data.{key}={n} (the fixed {key[:-5]} set)")


def _point_counts(n: int, strides: list[int]) -> list[int]:
    out = []
    for s in strides:
        n //= s
        out.append(n)
    return out


def validate_model(cfg: DictConfig) -> None:
    arch = _one_of(cfg, "model.net.arch", ARCHS, default=DEFAULT_ARCH)
    n = _get(cfg, "data.num_points")
    if arch == "arteq":
        pc = _get(cfg, "model.net.parent_conditioning")
        if not (pc is None or isinstance(pc, bool) or (isinstance(pc, str) and pc.lower() in PARENT_MODES)):
            allowed = f"{' | '.join(PARENT_MODES)} (or true = aligned, false = none)"
            raise ConfigError("model.net.parent_conditioning", pc, allowed)
        _one_of(cfg, "model.net.sides", SIDE_MODES, default="learned")
        if _get(cfg, "model.net.side_scale") is not None:
            _positive_float(cfg, "model.net.side_scale", " (the width of the left / right split, in metres)")
        bb = "model.net.backbone"
        channels = _get(cfg, f"{bb}.channels", [32, 32, 64, 64])
        strides = _get(cfg, f"{bb}.strides", [2, 1, 2, 1])
        if not isinstance(strides, list) or not all(_is_int(s) and s >= 1 for s in strides):
            raise ConfigError(f"{bb}.strides", strides, "a list of integers >= 1, one per backbone layer")
        for key in ("strides", "radii", "neighbours"):
            v = _get(cfg, f"{bb}.{key}")
            if v is not None and (not isinstance(v, list) or len(v) != len(channels)):
                raise ConfigError(f"{bb}.{key}", v, f"a list with one entry per layer ({len(channels)})")
        counts = _point_counts(n, strides)
        if min(counts) < 1:
            most = math.prod(strides)
            raise ConfigError(
                f"{bb}.strides",
                strides,
                f"strides whose product is at most data.num_points={n} (these leave {counts} points; "
                f"their product {most} needs data.num_points >= {most})",
            )
        fps = _get(cfg, "data.fps_points")
        need = next((c for c, s in zip(counts, strides) if s > 1), 0)
        if _is_int(fps) and 0 < fps < need:
            raise ConfigError(
                "data.fps_points", fps, f"null | auto | an integer >= {need} (what the backbone needs)"
            )
    else:
        fps = _get(cfg, "data.fps_points")
        if _is_int(fps) and fps > 0:
            raise ConfigError(
                "data.fps_points", fps, f"null | auto (only the ArtEq backbone uses it, not {arch})"
            )
        npoints = _get(cfg, "model.net.npoints", [])
        prev = n
        for i, m in enumerate(npoints):
            if not _is_int(m) or not 1 <= m <= prev:
                raise ConfigError(
                    "model.net.npoints", npoints, f"decreasing integers with npoints[{i}] in 1..{prev}"
                )
            prev = m
    validate_optimization(cfg)
    weights = _get(cfg, "model.loss_weights") or {}
    known = tuple(DEFAULT_WEIGHTS)
    for k, w in weights.items():
        if k not in known:
            raise ConfigError(f"model.loss_weights.{k}", w, f"a weight for one of {' | '.join(known)}")
        if not (isinstance(w, int | float) and math.isfinite(w) and w >= 0):
            raise ConfigError(f"model.loss_weights.{k}", w, "a finite number >= 0")


def _target_exists(key: str, target: str, what: str) -> None:
    from hydra.utils import get_object

    try:
        get_object(str(target))
    except Exception:  # noqa: BLE001 - Hydra raises ImportError or others for a bad path
        raise ConfigError(key, target, what) from None


def validate_optimization(cfg: DictConfig) -> None:
    """``model.optimizer`` / ``model.scheduler``: a Hydra partial whose ``_target_`` imports, or a name of the
    earlier form (:data:`arteq.training.optim.OPTIMIZERS` / :data:`~arteq.training.optim.SCHEDULERS`)."""
    try:
        opt = optim.optimizer_config(_get(cfg, "model.optimizer"))
        sched = optim.scheduler_config(_get(cfg, "model.scheduler"))
    except optim.OptimConfigError as e:
        raise ConfigError(e.key, e.value, e.allowed) from None
    _target_exists("model.optimizer._target_", opt["_target_"], "an importable optimizer (torch.optim.AdamW)")
    if sched is not None:
        what = "an importable scheduler (arteq.training.optim.warmup_cosine)"
        _target_exists("model.scheduler._target_", sched["_target_"], what)
    _positive_float(cfg, "model.optimizer.lr", " (e.g. 1e-4 for the paper, 3e-3 for the CPU default)")
    wd = _get(cfg, "model.optimizer.weight_decay", 0.0)
    if not (isinstance(wd, int | float) and math.isfinite(wd) and wd >= 0):
        raise ConfigError("model.optimizer.weight_decay", wd, "a finite number >= 0")


def validate_trainer(cfg: DictConfig) -> None:
    precision = _get(cfg, "trainer.precision", "32-true")
    if str(precision) not in PRECISIONS:
        raise ConfigError("trainer.precision", precision, " | ".join(PRECISIONS))
    devices = _get(cfg, "trainer.devices", 1)
    if not (devices == "auto" or world_size(cfg) is not None or devices == -1):
        raise ConfigError("trainer.devices", devices, "an integer >= 1, -1 (all), 'auto' or a list of ids")
    max_epochs = _get(cfg, "trainer.max_epochs")
    if max_epochs is not None and (not _is_int(max_epochs) or max_epochs < 1):
        raise ConfigError("trainer.max_epochs", max_epochs, "an integer >= 1")
    step_ckpt = _get(cfg, "callbacks.step_checkpoint.every_n_train_steps")
    if step_ckpt is not None and (not _is_int(step_ckpt) or step_ckpt < 0):
        raise ConfigError(
            "callbacks.step_checkpoint.every_n_train_steps",
            step_ckpt,
            "an integer >= 0 (0: no step checkpoints)",
        )
    for name, lg in (_get(cfg, "logger") or {}).items():
        if lg is not None and (not isinstance(lg, dict) or "_target_" not in lg):
            raise ConfigError(f"logger.{name}", lg, "a logger config with a _target_ (see conf/logger/)")


def validate_train_config(cfg: DictConfig) -> None:
    """All start-up checks of a ``conf/train.yaml`` composition; raises :class:`ConfigError`."""
    stage = _get(cfg, "stage")
    if stage not in (1, 2):
        raise ConfigError("stage", stage, "1 (ground-truth part pooling) | 2 (predicted parts)")
    if _get(cfg, "seed") is not None and not _is_int(_get(cfg, "seed")):
        raise ConfigError("seed", _get(cfg, "seed"), "an integer")
    validate_trainer(cfg)
    validate_body_model(cfg)
    validate_data(cfg, processes=world_size(cfg))
    validate_model(cfg)
    _existing_path(cfg, "ckpt_path", "null or a Lightning checkpoint file to resume")
    resume = _get(cfg, "resume")
    if resume not in (None, "auto") and not (isinstance(resume, str) and Path(resume).expanduser().is_dir()):
        raise ConfigError(
            "resume", resume, "null | auto (the newest run of this task) | an existing run folder"
        )
    if resume is not None and _get(cfg, "ckpt_path") is not None:
        raise ConfigError("resume", resume, "null when ckpt_path is given (use one or the other)")
    if stage == 2 and _get(cfg, "stage1.init"):
        _existing_path(cfg, "stage1.ckpt", "null or a stage-1 checkpoint file")
        _int_at_least(cfg, "stage1.epochs", 1)


def validate_eval_config(cfg: DictConfig) -> None:
    """Start-up checks of a ``conf/eval.yaml`` composition (the body model comes from the checkpoint;
    ``ckpt_path`` is checked by :func:`arteq.eval.evaluate`)."""
    validate_trainer(cfg)
    validate_data(cfg)


@contextmanager
def exit_on_config_error(prog: str) -> Iterator[None]:
    """For command-line entry points: a :class:`ConfigError` becomes one line on stderr and exit status 2."""
    try:
        yield
    except ConfigError as e:
        print(f"{prog}: config error: {e}", file=sys.stderr)
        raise SystemExit(2) from None
