"""AMASS motion files as they are downloaded: a pose source of real mocap frames (22 body joints).

**Releases and layouts** (both read without renaming anything; docs/data.md shows the trees):

- SMPL+H G: ``<root>/DFaust_67/50002/50002_chicken_wings_poses.npz``,
  ``<root>/MPI_Limits/03099/op2_poses.npz`` (keys ``poses [N,156]``, ``trans [N,3]``, ``betas [16]``,
  ``gender``, ``mocap_framerate``, ``dmpls``...);
- SMPL-X G: ``<root>/DFaust/50002/[50002_]chicken_wings_stageii.npz``,
  ``<root>/PosePrior/03099/op2_stageii.npz`` (keys ``poses [N,165]``, ``root_orient``, ``pose_body``,
  ``pose_hand``, ``pose_jaw``, ``pose_eye``, ``trans``, ``betas``, ``num_betas``, ``gender``,
  ``surface_model_type``, ``mocap_frame_rate``...).

A sub-dataset is found under any of its release names (:data:`DATASET_ALIASES`: ``DFaust_67`` / ``DFaust``,
``MPI_Limits`` / ``PosePrior``...), also one level deeper as some archives unpack
(``<root>/DFaust_67/DFaust_67/50002/...``). Motion files are ``*_poses.npz`` and ``*_stageii.npz`` (and any
other ``.npz`` holding the keys); ``shape.npz`` and MoSh++'s ``*_stagei.npz`` (per-subject shape) are skipped.
A motion's name is its file name without the subject prefix (``50002_``) and the ``_poses`` / ``_stageii``
suffix; names are compared lower-case with runs of spaces, dashes and other punctuation as one ``_``
(``A1 - Stand`` of SMPL+H G = ``A1_-_Stand`` of SMPL-X G = ``a1_stand``).

**Reading** (:func:`read_amass_npz`): ``allow_pickle=False``, only the needed keys are read (pickled
extras such as ``markers_latent_vids`` are never loaded). Pose: ``poses[:, :66]`` (root + 21 body joints,
the same in both releases), else ``root_orient`` + ``pose_body``. Frame rate from ``mocap_framerate`` or
``mocap_frame_rate``. Gender as str or bytes (0-d or 1-element arrays). AMASS is z-up; with ``to_y_up`` the
root orientation and translation are rotated by ``Rx(-90 deg)`` into arteq's frame (y up).

**Frame rates.** Each sequence's own rate decides its stride toward a target rate: ``stride = max(1,
round(rate / target))``, halves up (``train_fps`` 60: every frame of a 60 fps sequence, every 2nd of a
120 fps one; ``eval_fps`` 12: every 5th / 10th).

**Split of the paper's protocol** (our choice; the paper's list is not published): the first sub-dataset of
``datasets`` (DFaust) is split by motion: ``test_motions`` -> ``test``, ``val_motions`` -> ``val`` (all
subjects), all other motions -> ``train``; val / test sequences are cropped to the middle 50% of their frames.
Further sub-datasets of ``datasets`` (CMU, BMLmovi...) add all their frames to ``train``. The OOD test set is
every sequence of the OOD sub-dataset (PosePrior), split ``all``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import zipfile
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

import numpy as np
import roma
import torch

from arteq.data.poses import PoseSource

log = logging.getLogger(__name__)

#: Folder names of the same sub-dataset in the SMPL+H G and SMPL-X G releases (and inside their archives).
DATASET_ALIASES: tuple[tuple[str, ...], ...] = (
    ("DFaust", "DFaust_67"),
    ("PosePrior", "MPI_Limits"),
    ("HDM05", "MPI_HDM05"),
    ("MoSh", "MPI_mosh"),
    ("SSM", "SSM_synced"),
    ("TCDHands", "TCD_handMocap"),
    ("Transitions", "Transitions_mocap"),
    ("EyesJapanDataset", "Eyes_Japan_Dataset"),
    ("BMLrub", "BioMotionLab_NTroje"),
)
#: Default motions held out of DFaust (every subject performs them).
DFAUST_TEST_MOTIONS = ("one_leg_jump", "punching", "chicken_wings")
DFAUST_VAL_MOTIONS = ("shake_shoulders",)
MOTION_SUFFIXES = ("_poses", "_stageii")
RATE_KEYS = ("mocap_framerate", "mocap_frame_rate")
EXPECTED_KEYS = (
    "poses [N, >=66] (or root_orient [N,3] + pose_body [N,63]), trans [N,3], "
    "mocap_framerate or mocap_frame_rate"
)
SPLITS = ("train", "val", "test", "all")
_MAX_LISTED = 12


class AmassError(ValueError):
    """An AMASS root, sub-dataset or file that cannot be used; the message is one line naming it."""


class AmassNotFoundError(AmassError, FileNotFoundError):
    """A missing AMASS folder, sub-dataset or file."""


class AmassConfigError(AmassError):
    """A bad ``data.amass*`` setting: ``key`` (dotted config key), ``value``, ``allowed``."""

    def __init__(self, key: str, value: Any, allowed: str) -> None:
        super().__init__(f"{key}={value!r}: allowed: {allowed}")
        self.key, self.value, self.allowed = key, value, allowed


def _listing(items: Iterable[Any]) -> str:
    items = sorted(str(i) for i in items)
    more = f" ... (+{len(items) - _MAX_LISTED} more)" if len(items) > _MAX_LISTED else ""
    return "[" + ", ".join(items[:_MAX_LISTED]) + "]" + more


# ---------------------------------------------------------------------------------------------- names
def motion_name(path: str | Path) -> str:
    """A motion file's sequence name: ``50002/50002_chicken_wings_poses.npz`` -> ``chicken_wings``,
    ``03099/op2_stageii.npz`` -> ``op2`` (subject prefix = the parent folder's name, then ``_``)."""
    path = Path(path)
    stem = path.name[: -len(".npz")] if path.name.lower().endswith(".npz") else path.stem
    for suffix in MOTION_SUFFIXES:
        if stem.endswith(suffix) and len(stem) > len(suffix):
            stem = stem[: -len(suffix)]
            break
    prefix = path.parent.name + "_"
    if stem.startswith(prefix) and len(stem) > len(prefix):
        stem = stem[len(prefix) :]
    return stem


def motion_key(name: str) -> str:
    """Name used to compare motions: lower case, each run of non-alphanumerics one ``_``, none at the ends."""
    return re.sub(r"[^0-9a-z]+", "_", name.lower()).strip("_")


def dataset_names(name: str) -> tuple[str, ...]:
    """The folder names a sub-dataset may have: ``name`` first, then its other release names."""
    for group in DATASET_ALIASES:
        if name.lower() in (g.lower() for g in group):
            return (name, *[g for g in group if g.lower() != name.lower()])
    return (name,)


def canonical_dataset(name: str) -> str:
    """One name per sub-dataset (the SMPL-X G one where they differ): ``DFaust_67`` -> ``DFaust``."""
    for group in DATASET_ALIASES:
        if name.lower() in (g.lower() for g in group):
            return group[0]
    return name


def unique_datasets(names: Iterable[str]) -> list[str]:
    """``names`` without repeats of one sub-dataset (``[DFaust_67, DFaust]`` is one), order kept."""
    out, seen = [], set()
    for n in names:
        c = canonical_dataset(str(n)).lower()
        if c not in seen:
            seen.add(c)
            out.append(str(n))
    return out


def is_motion_file(path: Path) -> bool:
    """``.npz`` files that hold a sequence: everything but ``shape.npz`` and MoSh++'s ``*_stagei.npz``."""
    name = path.name.lower()
    return name.endswith(".npz") and name != "shape.npz" and not name.endswith("_stagei.npz")


# ---------------------------------------------------------------------------------------------- folders
def find_dataset_dir(root: str | Path, name: str | Iterable[str]) -> Path:
    """The folder of sub-dataset ``name`` under ``root`` (any of its release names, also nested one level
    as ``<root>/DFaust_67/DFaust_67``); a list of names = alternatives, the first one found is used.

    Raises:
        AmassNotFoundError naming the root, the names expected and the folders found.
    """
    root = Path(root).expanduser()
    if not root.is_dir():
        raise AmassNotFoundError(f"AMASS root folder not found: {root} (set data.amass_root)")
    names: list[str] = []
    for n in [name] if isinstance(name, str) else list(name):
        names += [m for m in dataset_names(str(n)) if m not in names]
    found = {p.name.lower(): p for p in root.iterdir() if p.is_dir()}
    for n in names:
        if n.lower() in found:
            return found[n.lower()]
    raise AmassNotFoundError(
        f"AMASS root {root}: no folder of sub-dataset {canonical_dataset(names[0])} (expected one of "
        f"{names}); found folders {_listing(found[k].name for k in found)}"
    )


def motion_files(dataset_dir: Path) -> list[Path]:
    """Motion files under a sub-dataset folder (recursively), sorted by relative path.

    Raises:
        AmassNotFoundError when there is none (naming the folder and what it holds).
    """
    files = sorted((p for p in dataset_dir.rglob("*") if p.is_file() and is_motion_file(p)), key=str)
    if not files:
        others = [str(p.relative_to(dataset_dir)) for p in dataset_dir.rglob("*") if p.is_file()]
        raise AmassNotFoundError(
            f"AMASS sub-dataset {dataset_dir}: no motion files (expected <subject>/<sequence>_poses.npz of "
            f"the SMPL+H G release or <subject>/<sequence>_stageii.npz of the SMPL-X G release); found "
            f"{len(others)} other files {_listing(others)}"
        )
    return files


# ---------------------------------------------------------------------------------------------- files
def _open_npz(path: Path) -> np.lib.npyio.NpzFile:
    if not path.is_file():
        raise AmassNotFoundError(f"AMASS file not found: {path}")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, EOFError, ValueError, zipfile.BadZipFile) as e:  # not a zip / npy, or a pickle
        raise AmassError(f"{path}: cannot read as an .npz archive ({e})") from e
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise AmassError(f"{path}: is a single .npy array, not an .npz archive of an AMASS sequence")
    return z


def _missing_keys(keys: set[str]) -> list[str]:
    missing = []
    if "poses" not in keys and not {"root_orient", "pose_body"} <= keys:
        missing.append("poses (or root_orient + pose_body)")
    if "trans" not in keys:
        missing.append("trans")
    if not keys & set(RATE_KEYS):
        missing.append("mocap_framerate or mocap_frame_rate")
    return missing


def check_motion_file(path: str | Path) -> None:
    """Check that a file is an AMASS motion file (its key list only, no arrays read)."""
    path = Path(path)
    with _open_npz(path) as z:
        keys = set(z.files)
    missing = _missing_keys(keys)
    if missing:
        raise AmassError(
            f"{path}: not an AMASS motion file, missing {', '.join(missing)} (expected {EXPECTED_KEYS}; "
            f"found keys {sorted(keys)})"
        )


def _text(z: np.lib.npyio.NpzFile, key: str) -> str | None:
    """A text scalar stored as str or bytes, 0-d or 1-element; None if absent or pickled (not loaded)."""
    if key not in z.files:
        return None
    try:
        a = np.asarray(z[key])
    except ValueError:  # an object array: would need unpickling
        return None
    if a.size != 1 or a.dtype.kind not in "US":
        return None
    v = a.reshape(()).item()
    return (v.decode("latin1") if isinstance(v, bytes) else str(v)).strip()


def _number(z: np.lib.npyio.NpzFile, key: str, path: Path) -> float:
    try:
        a = np.asarray(z[key])
        value = float(a.reshape(())) if a.size == 1 else float("nan")
    except (ValueError, TypeError):
        value = float("nan")
    if not (np.isfinite(value) and value > 0):
        raise AmassError(f"{path}: '{key}' must be one positive number (frames per second), got {z[key]!r}")
    return value


def read_amass_npz(path: str | Path) -> dict[str, Any]:
    """Read one AMASS motion file of either release.

    Returns:
        ``poses [N,22,3]`` float32 axis-angle (root + 21 body joints), ``trans [N,3]`` float32, ``betas [nb]``
        float32 or None, ``fps`` float, ``gender`` str (``unknown`` if absent), ``surface_model`` str
        (``smplh`` / ``smplx`` / ``smpl`` from ``surface_model_type`` or the pose width; ``unknown``).
    Raises:
        AmassError / AmassNotFoundError naming the file, what was expected and what was found.
    """
    path = Path(path)
    check_motion_file(path)
    with _open_npz(path) as z:
        keys = set(z.files)
        if "poses" in keys:
            poses = np.asarray(z["poses"], dtype=np.float64)
            if poses.ndim != 2 or poses.shape[1] < 66:
                raise AmassError(
                    f"{path}: 'poses' must be [N, 72|156|165] (>= 66 columns), got {list(poses.shape)}"
                )
            width = poses.shape[1]
            poses = poses[:, :66]
        else:
            root, body = (np.asarray(z[k], dtype=np.float64) for k in ("root_orient", "pose_body"))
            if root.ndim != 2 or root.shape[1] != 3 or body.shape != (root.shape[0], 63):
                raise AmassError(
                    f"{path}: 'root_orient' / 'pose_body' must be [N, 3] / [N, 63], got "
                    f"{list(root.shape)} / {list(body.shape)}"
                )
            poses, width = np.concatenate([root, body], axis=1), None
        trans = np.asarray(z["trans"], dtype=np.float64)
        betas = np.asarray(z["betas"], dtype=np.float64).reshape(-1) if "betas" in keys else None
        fps = _number(z, next(k for k in RATE_KEYS if k in keys), path)
        gender = (_text(z, "gender") or "unknown").lower()
        model = _text(z, "surface_model_type")
    if model is None:
        model = {72: "smpl", 156: "smplh", 165: "smplx"}.get(width, "unknown")
    if trans.shape != (poses.shape[0], 3):
        raise AmassError(f"{path}: 'trans' must be [N, 3] with N={poses.shape[0]}, got {list(trans.shape)}")
    finite = np.isfinite(poses).all() and np.isfinite(trans).all()
    if not finite or (betas is not None and not np.isfinite(betas).all()):
        raise AmassError(f"{path}: NaN or Inf in poses / trans / betas")
    return {
        "poses": poses.reshape(-1, 22, 3).astype(np.float32),
        "trans": trans.astype(np.float32),
        "betas": None if betas is None or betas.size == 0 else betas.astype(np.float32),
        "fps": fps,
        "gender": gender,
        "surface_model": model.lower(),
    }


def frame_stride(fps: float, target_fps: float | None) -> int:
    """Stride that brings a ``fps`` sequence closest to ``target_fps`` (None: every frame)."""
    if target_fps is None:
        return 1
    return max(1, int(np.floor(fps / float(target_fps) + 0.5)))  # nearest, halves up


def betas_match_body(surface_model: str, body_name: str) -> bool:
    """Whether a file's betas live in the body's shape space: SMPL+H G betas (SMPL+H, SMPL) for an SMPL or
    SMPL+H body; SMPL-X G betas (SMPL-X) for an SMPL-X body only. Never for anny22 or another body."""
    body = body_name.lower().replace("-", "")
    if not body.startswith("smpl"):
        return False
    if surface_model == "smplx" or body.startswith("smplx"):
        return surface_model == "smplx" and body.startswith("smplx")
    return surface_model in ("smpl", "smplh", "unknown")


def check_amass_root(
    root: str | Path,
    datasets: Iterable[str] = ("DFaust",),
    ood_datasets: Iterable[str] = ("PosePrior",),
) -> dict[str, Path]:
    """Check an AMASS root before anything is built: every sub-dataset found and every motion file with the
    keys (its key list only). Returns ``{sub-dataset: folder}``; raises :class:`AmassError` (one line)."""
    datasets, ood = unique_datasets(datasets), unique_datasets(ood_datasets)
    if not datasets:
        raise AmassError("data.amass.datasets is empty: name at least the ID sub-dataset (DFaust)")
    _check_disjoint(datasets, ood)
    out = {}
    for name in [*datasets, *ood]:
        d = find_dataset_dir(root, name)
        for f in motion_files(d):
            check_motion_file(f)
        out[canonical_dataset(name)] = d
    return out


def _check_disjoint(datasets: Iterable[str], ood_datasets: Iterable[str]) -> None:
    ood = {canonical_dataset(d).lower() for d in ood_datasets}
    both = sorted({canonical_dataset(d) for d in datasets if canonical_dataset(d).lower() in ood})
    if both:
        raise AmassConfigError(
            "data.amass.datasets",
            list(datasets),
            f"sub-datasets other than the OOD test set (data.amass_ood_datasets): {both} would be both "
            "training data and the OOD test set",
        )


_Y_UP = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64)  # Rx(-90)


class AmassPoses(PoseSource):
    """Frames of AMASS sub-datasets as a finite pose source.

    Args:
        root: AMASS root folder (holding e.g. ``DFaust_67/`` and ``MPI_Limits/``, or ``DFaust/`` and
            ``PosePrior/``).
        datasets: sub-datasets, each by either release's name. Splits ``train`` / ``val`` / ``test``: the
            first is split by motion, the others add all their frames to ``train``. Split ``all``: every
            sequence of every one (a list of one sub-dataset's names, as ``[MPI_Limits, PosePrior]``, is
            one sub-dataset).
        split: ``train`` | ``val`` | ``test`` (by motion) | ``all``.
        test_motions, val_motions: motion names held out for test / val (compared by :func:`motion_key`).
        train_fps, eval_fps, all_fps: target frame rates (Hz; None = every frame) of train, val / test
            (middle 50% of each sequence) and ``all``; each file's own rate gives its stride.
        use_betas: return the files' betas: True always, False never, None (auto) when they live in the
            shape space of the body named ``body_name`` (:func:`betas_match_body`); frames without betas
            get ``None`` and the dataset samples betas from the body's shape space.
        to_y_up: rotate AMASS's z-up world into arteq's y-up frame.
    """

    def __init__(
        self,
        root: str | Path,
        datasets: Iterable[str] = ("DFaust",),
        split: str = "train",
        test_motions: Iterable[str] = DFAUST_TEST_MOTIONS,
        val_motions: Iterable[str] = DFAUST_VAL_MOTIONS,
        train_fps: float | None = 60.0,
        eval_fps: float | None = 12.0,
        all_fps: float | None = 24.0,
        use_betas: bool | None = False,
        body_name: str = "",
        to_y_up: bool = True,
    ) -> None:
        if split not in SPLITS:
            raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
        for key, v in (("train_fps", train_fps), ("eval_fps", eval_fps), ("all_fps", all_fps)):
            if v is not None and not (isinstance(v, int | float) and not isinstance(v, bool) and v > 0):
                raise ValueError(f"AmassPoses: {key} must be a frame rate > 0 (Hz) or None, got {v!r}")
        self.root = Path(root).expanduser()
        names = unique_datasets(datasets)
        if not names:
            raise ValueError("AmassPoses: datasets is empty")
        self.dirs = [find_dataset_dir(self.root, n) for n in names]
        test_m = {motion_key(m) for m in test_motions}
        val_m = {motion_key(m) for m in val_motions}
        if test_m & val_m:
            raise ValueError(f"AmassPoses: motions {sorted(test_m & val_m)} are both test and val motions")
        stride_fps = {"train": train_fps, "val": eval_fps, "test": eval_fps, "all": all_fps}[split]
        poses, trans, betas, has_betas = [], [], [], []
        self.files: list[Path] = []
        self.motions: dict[str, int] = {}  # motion key -> frames kept
        self.frames: list[tuple[int, int]] = []
        self.surface_models: set[str] = set()
        seen_motions: set[str] = set()
        for i, d in enumerate(self.dirs):
            by_motion = split != "all" and i == 0  # the first sub-dataset is the one split by motion
            if split in ("val", "test") and not by_motion:
                break
            for f in motion_files(d):
                key = motion_key(motion_name(f))
                kind = "train"
                if by_motion:
                    seen_motions.add(key)
                    kind = "test" if key in test_m else "val" if key in val_m else "train"
                if split != "all" and kind != split:
                    continue
                data = read_amass_npz(f)
                n = data["poses"].shape[0]
                stride = frame_stride(data["fps"], stride_fps)
                idx = np.arange(n // 4, n - n // 4) if split in ("val", "test") else np.arange(n)
                idx = idx[::stride]
                if len(idx) == 0:
                    continue
                use = self._use_betas(use_betas, data, body_name)
                self.files.append(f)
                self.surface_models.add(data["surface_model"])
                self.motions[key] = self.motions.get(key, 0) + len(idx)
                poses.append(data["poses"][idx])
                trans.append(data["trans"][idx])
                b = data["betas"] if data["betas"] is not None else np.zeros(0, np.float32)
                betas.append(b)
                has_betas.append(use and b.size > 0)
                self.frames += [(len(self.files) - 1, int(j)) for j in idx]
        absent = sorted((test_m | val_m) - seen_motions)
        if absent and split in ("val", "test"):
            log.warning("AMASS %s: held-out motions %s not found", self.dirs[0], absent)
        if not poses:
            wanted = {"test": test_m, "val": val_m}.get(split)
            what = f"no motion of {sorted(wanted)}" if wanted else "no frames"
            raise AmassError(
                f"AMASS split {split!r} of {self.dirs[0]} is empty: {what} (expected files such as "
                f"<subject>/<subject>_<motion>_poses.npz or <subject>/<motion>_stageii.npz); motions found: "
                f"{_listing(seen_motions) if seen_motions else '[]'}"
            )
        counts = [len(p) for p in poses]
        nb = max(b.size for b in betas)
        betas_rows = np.zeros((sum(counts), max(nb, 1)), np.float32)
        mask = np.zeros(sum(counts), bool)
        start = 0
        for b, c, h in zip(betas, counts, has_betas, strict=True):
            betas_rows[start : start + c, : b.size] = b
            mask[start : start + c] = h
            start += c
        self.poses = torch.from_numpy(np.concatenate(poses)).double()
        self.trans = torch.from_numpy(np.concatenate(trans)).double()
        self.betas = torch.from_numpy(betas_rows).double()
        self.has_betas = torch.from_numpy(mask)
        if to_y_up:
            root_rot = _Y_UP @ roma.rotvec_to_rotmat(self.poses[:, 0])
            self.poses[:, 0] = roma.rotmat_to_rotvec(root_rot)
            self.trans = self.trans @ _Y_UP.T
        self.split, self.use_betas, self.to_y_up = split, use_betas, to_y_up
        self._args = {
            "datasets": [d.name for d in self.dirs],
            "split": split,
            "test_motions": sorted(test_m),
            "val_motions": sorted(val_m),
            "fps": stride_fps,
            "body_name": body_name if use_betas is None else None,
            "betas_frames": int(mask.sum()),
        }
        self.num_poses = self.poses.shape[0]

    @staticmethod
    def _use_betas(use_betas: bool | None, data: dict, body_name: str) -> bool:
        if use_betas is None:
            return betas_match_body(data["surface_model"], body_name)
        return bool(use_betas)

    def fingerprint(self) -> dict:
        h = hashlib.sha256()
        for f in self.files:
            st = f.stat()
            h.update(f"{f.relative_to(self.root)}:{st.st_size}:{int(st.st_mtime)};".encode())
        return {
            "class": "AmassPoses",
            "dir": str(self.root.resolve()),
            "files": h.hexdigest(),
            "use_betas": self.use_betas,
            "to_y_up": self.to_y_up,
            "args": json.loads(json.dumps(self._args)),
        }

    def sample(self, index: int, generator: torch.Generator) -> dict:
        i = index % self.num_poses
        return {
            "pose": self.poses[i].clone(),
            "betas": self.betas[i].clone() if bool(self.has_betas[i]) else None,
            "transl": self.trans[i].clone(),
        }


#: Keys of ``data.amass`` (the AMASS settings of :class:`arteq.data.BodyScanDataModule`) and defaults.
AMASS_DEFAULTS: dict[str, Any] = {
    "datasets": ["DFaust"],
    "test_motions": list(DFAUST_TEST_MOTIONS),
    "val_motions": list(DFAUST_VAL_MOTIONS),
    "train_fps": 60.0,
    "eval_fps": 12.0,
    "ood_fps": 24.0,
}
AMASS_OPTIONS = tuple(AMASS_DEFAULTS)
#: Former keys and what replaced them.
RENAMED_OPTIONS = {
    "eval_stride": "eval_fps (target frame rate; each file's rate gives its stride)",
    "train_stride": "train_fps (target frame rate; each file's rate gives its stride)",
    "all_stride": "ood_fps",
}


def check_amass_options(
    options: Mapping[str, Any], ood_datasets: Iterable[str], ood_stride: Any = None
) -> dict[str, Any]:
    """``data.amass`` options (:data:`AMASS_OPTIONS`) checked, with their defaults filled in.

    Raises:
        AmassConfigError naming the key, the value and what is allowed.
    """
    opts = dict(options)
    for k, v in opts.items():
        if k in RENAMED_OPTIONS:
            raise AmassConfigError(f"data.amass.{k}", v, f"(renamed) data.amass.{RENAMED_OPTIONS[k]}")
        if k not in AMASS_OPTIONS:
            raise AmassConfigError(f"data.amass.{k}", v, f"a key among {' | '.join(AMASS_OPTIONS)}")
    if ood_stride is not None:
        raise AmassConfigError("data.amass_ood_stride", ood_stride, "(renamed) data.amass.ood_fps (Hz)")
    for k in ("train_fps", "eval_fps", "ood_fps"):
        v = opts.get(k)
        if v is not None and not (isinstance(v, int | float) and not isinstance(v, bool) and v > 0):
            raise AmassConfigError(
                f"data.amass.{k}", v, "a target frame rate in Hz > 0, or null (every frame)"
            )
    opts = {**AMASS_DEFAULTS, **opts}
    lists = {f"data.amass.{k}": opts[k] for k in ("datasets", "test_motions", "val_motions")}
    lists["data.amass_ood_datasets"] = ood_datasets
    for k, v in lists.items():
        if not isinstance(v, list | tuple) or not all(isinstance(x, str) and x for x in v):
            raise AmassConfigError(k, v, "a list of names, e.g. [DFaust, CMU]")
    if not opts["datasets"] or not list(ood_datasets):
        key = "data.amass.datasets" if not opts["datasets"] else "data.amass_ood_datasets"
        raise AmassConfigError(
            key, [], "at least one sub-dataset, e.g. [DFaust] (training) / [PosePrior] (OOD)"
        )
    _check_disjoint(opts["datasets"], ood_datasets)
    return opts


def check_amass_config(
    root: str | Path, options: Mapping[str, Any], ood_datasets: Iterable[str], ood_stride: Any = None
) -> dict[str, Path]:
    """:func:`check_amass_options`, then :func:`check_amass_root` on the sub-datasets they name."""
    opts = check_amass_options(options, list(ood_datasets), ood_stride)
    return check_amass_root(root, opts["datasets"], ood_datasets)


def amass_source(
    root: str | Path,
    split: str,
    options: Mapping[str, Any] | None = None,
    ood_datasets: Iterable[str] = ("PosePrior",),
    use_betas: bool | None = None,
    body_name: str = "",
) -> AmassPoses:
    """The pose source of a datamodule split (``train`` | ``val`` | ``test_id`` | ``test_ood``) from the
    ``data.amass`` options (:data:`AMASS_OPTIONS`) and ``data.amass_ood_datasets``."""
    ood_datasets = list(ood_datasets)
    opts = check_amass_options(options or {}, ood_datasets)
    ood_fps = opts.pop("ood_fps")
    common = {"use_betas": use_betas, "body_name": body_name}
    if split == "test_ood":
        return AmassPoses(root, datasets=ood_datasets, split="all", all_fps=ood_fps, **common)
    amass_split = {"train": "train", "val": "val", "test_id": "test"}[split]
    return AmassPoses(root, split=amass_split, **common, **opts)
