"""``BodyScanDataModule``: train / val / test loaders of synthetic body scans.

- ``train``: drawn on the fly, fresh every epoch (indices ``epoch * train_size + i``), ID source.
- ``val``, ``test_id``: fixed ID sets with their own random streams (disjoint seed spaces; with AMASS,
  held-out motions). ``test_ood``: fixed OOD set (synthetic extremes, or AMASS MPI_Limits), always with a
  random root orientation. The graded OOD sets (synthetic with either source, any root orientation):
  ``test_ood_limb1`` / ``test_ood_limb2`` (an everyday pose with one / two limbs from the OOD sampler) and
  ``test_ood_contact`` (OOD poses without self-contact, PosePrior-like); ``test_splits`` chooses which
  test sets run (default all, in the order of :data:`arteq.results.TEST_SPLITS`).
- Single-view depth scans (:mod:`arteq.data.single_view`): ``single_view.prob`` of the training clouds
  are what one depth camera at a random position sees (default 0: full surfaces only); ``view_splits``
  (default none) names cached single-view test sets, ``test_view_front`` / ``_side`` / ``_back`` /
  ``_top``: the same ``test_size`` bodies as drawn for ID testing (their own stream ``test_view``, rotated
  as ``eval_augment``), each seen from that side; loaders from :meth:`BodyScanDataModule.view_dataloaders`,
  and run by the test loop after the ``test_splits`` (:meth:`BodyScanDataModule.test_dataloader`).
- Fixed sets are generated once and cached under ``arteq.paths.cache_dir("datasets")``, keyed by a hash of
  everything that defines them (source, body, sizes, sampling, seed). A cache file holds plain tensors
  plus their SHA-256 and sample count (read with ``torch.load(weights_only=True)``); a file that is
  truncated, corrupted or foreign is detected, removed and regenerated with a warning, never used.
  Files are written to a temporary name and renamed (atomic), under a lock file, so concurrent runs
  creating the same set cannot corrupt it (the second one waits, then loads what the first wrote).
- Distributed runs (``trainer=ddp``): Lightning's distributed sampler is off (``use_distributed_sampler:
  false``); the training stream is sharded by :class:`EpochSampler` (disjoint samples per rank), the
  fixed sets by :class:`ShardSampler` (no padding, no duplicates). Caches are created by local rank 0 in
  ``prepare_data`` while the other ranks wait.
- FPS in the workers (``fps_points``): each batch also carries ``fps_idx [B, fps_points]``, the
  backbone's farthest-point-sampling order of its clouds, computed by :class:`FpsCollate` in the loader
  workers (in parallel with training) from the float32 points the network receives, with the backbone's
  own function (:func:`arteq.geometry.pointops.fps_from_centroid`): the network uses them instead of its
  sequential FPS loop (thousands of tiny kernels per step on a GPU) and its outputs are bit-identical.
  Training stream and fixed sets alike (computed after loading: the cache format is unchanged).
- Resume: the position in the training stream (epoch and batches done) is saved in checkpoints through
  ``state_dict`` and restored by ``load_state_dict``; a run resumed mid-epoch continues with exactly the
  samples an uninterrupted run would have seen next.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset, default_collate

from arteq.body.factory import create_body
from arteq.config import to_plain
from arteq.data.dataset import (
    AUGMENTS,
    META_KEYS,
    SAMPLE_KEYS,
    BodyScanDataset,
    EpochSampler,
    ShardSampler,
    TensorDictDataset,
)
from arteq.data.holes import HoleConfig
from arteq.data.poses import (
    ATHLETIC_LIMITS_DEG,
    ContactRejectedPoses,
    LimbOODPoses,
    MixedPoses,
    PoseSource,
    SyntheticIDPoses,
    SyntheticOODPoses,
)
from arteq.data.shapes import make_shape_prior
from arteq.data.single_view import VIEW_SPLITS, SingleViewConfig, SingleViewDataset
from arteq.geometry.pointops import fps_from_centroid
from arteq.paths import cache_dir
from arteq.results import TEST_SPLITS, VIEW_NAMES, view_split
from arteq.runtime import one_thread

log = logging.getLogger(__name__)
CACHE_VERSION = 2
CACHE_FORMAT = "arteq-fixed-set"
EVAL_SPLITS = ("val", *TEST_SPLITS)
#: Test sets drawn from the synthetic samplers whatever ``source`` is (the graded OOD scale).
GRADED_SPLITS = ("test_ood_limb1", "test_ood_limb2", "test_ood_contact")
#: Their size when ``test_size`` is null (AMASS: every frame of the real test sets).
GRADED_DEFAULT_SIZE = 128
#: Sources a training pose mixture (``train_pose_mix``) may draw from: ``id`` = the configured training
#: poses (synthetic everyday motions, widened by ``wide_poses``, or the AMASS training frames), the others
#: the synthetic samplers of the OOD test sets (their own random streams: the test sets stay held out).
#: ``athletic`` is the OOD sampler with a trained athlete's joint range (poses.ATHLETIC_LIMITS_DEG; training
#: only, no test set draws from it); ``athletic_spine`` the same with the spine bending as one chain in half
#: of the draws (``SyntheticOODPoses(spine_chain_prob=0.5)``: back bends, pikes, side bends).
TRAIN_MIX_SOURCES = ("id", "ood", "limb1", "limb2", "contact", "athletic", "athletic_spine")


class CorruptCacheError(RuntimeError):
    """A cached fixed set failed its checks (unreadable, truncated, wrong checksum or contents)."""


def stored_keys(tensors: Mapping[str, Any]) -> tuple[str, ...]:
    """The keys a fixed set stores: ``SAMPLE_KEYS``, then the ``META_KEYS`` it has (sets drawn with a shape
    prior that records what body a sample is; the other sets store exactly what they always did)."""
    return (*SAMPLE_KEYS, *(k for k in META_KEYS if k in tensors))


def tensors_digest(tensors: Mapping[str, torch.Tensor]) -> str:
    """SHA-256 over the sample tensors (key, dtype, shape and bytes, in :func:`stored_keys` order)."""
    h = hashlib.sha256()
    for k in stored_keys(tensors):
        t = tensors[k].detach().cpu().contiguous()
        h.update(f"{k}|{t.dtype}|{tuple(t.shape)}|".encode())
        h.update(t.numpy().tobytes())
    return h.hexdigest()


def write_cache(path: Path, tensors: Mapping[str, torch.Tensor], split: str) -> None:
    """Write a fixed set with its checksum: temporary file in the same folder, then atomic rename."""
    payload = {
        "format": CACHE_FORMAT,
        "version": CACHE_VERSION,
        "split": split,
        "count": int(tensors["points"].shape[0]),
        "sha256": tensors_digest(tensors),
        "tensors": {k: tensors[k].contiguous() for k in stored_keys(tensors)},
    }
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{os.urandom(4).hex()}.tmp")
    try:
        torch.save(payload, tmp)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def read_cache(path: Path, split: str | None = None) -> dict[str, torch.Tensor]:
    """Load and verify a cache file written by :func:`write_cache`; raises :class:`CorruptCacheError`."""
    size = path.stat().st_size
    if size == 0:
        raise CorruptCacheError("empty file")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # truncated zip, bad pickle, foreign file...
        raise CorruptCacheError(f"unreadable ({type(e).__name__}: {str(e).splitlines()[0][:120]})") from e
    if not isinstance(payload, dict) or payload.get("format") != CACHE_FORMAT:
        raise CorruptCacheError("not an arteq fixed-set file")
    if payload.get("version") != CACHE_VERSION:
        raise CorruptCacheError(f"format version {payload.get('version')}, expected {CACHE_VERSION}")
    if split is not None and payload.get("split") != split:
        raise CorruptCacheError(f"holds split {payload.get('split')!r}, expected {split!r}")
    tensors = payload.get("tensors")
    if not isinstance(tensors, dict) or any(k not in tensors for k in SAMPLE_KEYS):
        raise CorruptCacheError("missing sample tensors")
    keys = stored_keys(tensors)
    counts = {int(tensors[k].shape[0]) for k in keys}
    if counts != {payload.get("count")}:
        raise CorruptCacheError(f"sample count {sorted(counts)} != recorded {payload.get('count')}")
    if tensors_digest(tensors) != payload.get("sha256"):
        raise CorruptCacheError("checksum mismatch (contents changed after writing)")
    return {k: tensors[k] for k in keys}


def body_fingerprint(body: torch.nn.Module) -> str:
    """Hash of a body model's identity: its faces and its rest mesh at betas = 0."""
    h = hashlib.sha256()
    h.update(str(getattr(body, "name", type(body).__name__)).encode())
    h.update(str(int(body.num_betas)).encode())
    h.update(body.faces.cpu().numpy().tobytes())
    with torch.no_grad():
        pose = torch.eye(3).expand(1, 22, 3, 3).to(body.lbs_weights)
        v = body(betas=torch.zeros(1, int(body.num_betas)).to(body.lbs_weights), pose=pose).vertices
    h.update(torch.round(v.double().cpu() * 1e4).long().numpy().tobytes())
    return h.hexdigest()


class FpsCollate:
    """Collate function: the default collation plus ``fps_idx [B, m]`` long, the FPS order of the batch's
    clouds as the ArtEq backbone computes it (:func:`arteq.geometry.pointops.fps_from_centroid`: start at
    the point nearest the centroid, float64 distances; on the CPU the batch-vectorised numpy loop). It runs
    where the collation runs: in the loader workers when ``num_workers > 0``. Picklable (workers)."""

    def __init__(self, m: int) -> None:
        if not isinstance(m, int) or m < 1:
            raise ValueError(f"FpsCollate: m must be an int >= 1, got {m!r}")
        self.m = m

    def __call__(self, items: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
        batch = default_collate(items)
        points = batch["points"]
        if self.m > points.shape[1]:
            raise ValueError(f"data.fps_points={self.m} is more than the {points.shape[1]} points per cloud")
        with one_thread():  # as in BodyScanDataset: small ops, one thread (main process)
            batch["fps_idx"] = fps_from_centroid(points, self.m)
        return batch

    def __repr__(self) -> str:
        return f"FpsCollate(m={self.m})"


def resolve_fps_points(fps_points: int | str | None, net: Mapping[str, Any] | None, num_points: int) -> int:
    """``data.fps_points`` as a number of FPS indices per cloud for the network config ``net``
    (``model.net``): ``null`` / 0 -> 0 (off); ``auto`` -> what the ArtEq backbone needs for ``num_points``
    points (the count after its first strided block, e.g. 2500 of 5000 with strides 2, 1, 2, 1), 0 for
    another architecture or without a network config; an int -> itself, checked against the backbone
    (at least what it needs; more is allowed, the extra columns are ignored)."""
    if fps_points is None or fps_points == 0:
        return 0
    net = dict(to_plain(net) or {})
    arteq = net.get("arch", "arteq") == "arteq"
    need = None
    if net and arteq:
        from arteq.equivariant.backbone import fps_size

        need = fps_size((net.get("backbone") or {}).get("strides", (2, 1, 2, 1)), num_points)
    if fps_points == "auto":
        return need or 0
    if isinstance(fps_points, bool) or not isinstance(fps_points, int) or fps_points < 0:
        raise ValueError(f"data.fps_points must be null, auto or an int >= 0, got {fps_points!r}")
    if net and not arteq:
        raise ValueError(
            f"data.fps_points={fps_points}: only the ArtEq backbone uses precomputed FPS indices "
            f"(model.net.arch={net.get('arch')!r}); use null or auto"
        )
    if need is not None and fps_points < need:
        raise ValueError(
            f"data.fps_points={fps_points} is fewer than the {need} FPS indices the backbone needs for "
            f"{num_points} points (use auto)"
        )
    return fps_points


class BodyScanDataModule(L.LightningDataModule):
    """Lightning data module of synthetic scans (see module docstring and docs/data.md).

    Args:
        source: ``synthetic`` (ID motions + OOD extremes) or ``amass`` (DFaust_67 + MPI_Limits).
        body_model: a body ``nn.Module`` (used as is: build it once and pass it to share it), or a
            config mapping for :func:`arteq.body.create_body` (``_target_`` ignored; ``name: toy`` for
            the procedural test body).
        amass_root: AMASS root folder (``source=amass``).
        amass: extra keyword arguments of :class:`arteq.data.amass.AmassPoses` for the ID splits
            (see ``conf/data/amass.yaml`` and docs/data.md); ``amass_ood_datasets`` names the OOD
            sub-dataset's folder candidates.
        use_data_betas: with AMASS, use the files' betas (only correct with an SMPL body; ``null`` = auto:
            true iff the body's name starts with ``smpl``); otherwise betas ~ N(0, beta_scale^2 I).
        shape_prior: where betas come from when the poses bring none: ``normal`` (N(0, beta_scale^2 I))
            or ``allages`` (the all-ages body's stored shape samples, children to elderly and extreme
            builds, perturbed with their age band's covariance: :mod:`arteq.data.shapes`; needs
            ``body_model=anny_allages``); every split.
        num_points, noise_std, density_contrast, density_wavelength: cloud sampling.
        augment: train rotation augmentation ``none | so3 | z`` (``z``: about the vertical axis, which is
            y in the body frame); ``eval_augment`` for val / test_id; every OOD set always gets ``so3``.
        wide_poses: probability that a synthetic training pose is widened at the collars, shoulders,
            elbows, wrists, neck and head (:data:`arteq.data.poses.WIDE_ID_RANGES_DEG`); val / test_id keep
            the narrow everyday motions.
        train_pose_mix: ``null`` (train on the ID poses) or weights over :data:`TRAIN_MIX_SOURCES`, e.g.
            ``{id: 0.4, ood: 0.4, limb1: 0.1, limb2: 0.1}``: each training pose comes from one of them
            (:class:`arteq.data.poses.MixedPoses`), for a model meant for any pose (the scan-fitting model).
            Validation and the test sets are unchanged.
        test_splits: the test sets to run, a subset of :data:`arteq.results.TEST_SPLITS` (default all).
        train_size: samples per epoch (``null`` with AMASS: number of training frames).
        train_epoch_offset: the training stream starts at this epoch (``>= 0``): a run that continues from
            another run's weights trains on clouds that run never drew (:class:`EpochSampler`); the fixed
            sets do not depend on it.
        val_size, test_size: fixed set sizes (``null`` with AMASS: all frames of the split; the graded OOD
            sets, synthetic and infinite, then have :data:`GRADED_DEFAULT_SIZE` clouds).
        batch_size, eval_batch_size, num_workers: loaders.
        seed: base seed of every random stream.
        cache: cache the fixed sets on disk; ``cache_root`` overrides the folder.
        fps_points: FPS indices per cloud computed in the loader workers and carried as the batch key
            ``fps_idx`` (see module docstring): ``null`` / 0 = off, an int, or ``auto`` = as many as the
            network's backbone needs. ``auto`` is resolved by :func:`arteq.training.build.build_datamodule`
            (which knows ``model.net``; see :func:`resolve_fps_points`), or from ``net`` when given; a
            datamodule built with neither takes ``auto`` as off.
        net: the network config (``model.net``) that ``fps_points: auto`` is resolved against.
        single_view: the camera and sensor of single-view scans (:class:`arteq.data.single_view.
            SingleViewConfig` fields; ``prob``: share of training clouds that are single-view scans).
        view_splits: cached single-view test sets to build and test on, after ``test_splits``
            (:data:`arteq.results.VIEW_SPLITS`, named so or by view: ``front`` = ``test_view_front``).
        holes: holes in the full-surface training clouds (:class:`arteq.data.holes.HoleConfig` fields;
            ``prob``: share of those clouds with holes); the fixed sets have none.
        hand_curl: share of the training clouds whose hands are curled (each hand's curl uniform in [0, 1],
            Anny's finger bones: :mod:`arteq.body.hands`; bodies built from Anny); the fixed sets' hands are
            flat.
    """

    def __init__(
        self,
        source: str = "synthetic",
        body_model: Any = None,
        amass_root: str | None = None,
        amass: Mapping[str, Any] | None = None,
        amass_ood_datasets: list[str] | tuple[str, ...] = ("MPI_Limits", "PosePrior"),
        use_data_betas: bool | None = None,
        num_points: int = 5000,
        noise_std: float = 0.001,
        density_contrast: float = 0.75,
        density_wavelength: float = 0.6,
        beta_scale: float = 1.0,
        shape_prior: str = "normal",
        augment: str = "none",
        eval_augment: str = "none",
        wide_poses: float = 0.0,
        train_pose_mix: Mapping[str, float] | None = None,
        test_splits: list[str] | tuple[str, ...] | None = None,
        train_size: int | None = 2000,
        train_epoch_offset: int = 0,
        val_size: int | None = 64,
        test_size: int | None = 256,
        batch_size: int = 4,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        seed: int = 0,
        cache: bool = True,
        cache_root: str | None = None,
        fps_points: int | str | None = None,
        net: Mapping[str, Any] | None = None,
        single_view: Mapping[str, Any] | None = None,
        view_splits: list[str] | tuple[str, ...] | None = None,
        holes: Mapping[str, Any] | None = None,
        hand_curl: float = 0.0,
    ) -> None:
        super().__init__()
        if source not in ("synthetic", "amass"):
            raise ValueError(f"data.source must be 'synthetic' or 'amass', got {source!r}")
        for name, a in (("augment", augment), ("eval_augment", eval_augment)):
            if a not in AUGMENTS:
                raise ValueError(f"data.{name} must be one of {AUGMENTS}, got {a!r}")
        if source == "amass" and not amass_root:
            raise ValueError("data.amass_root must name the AMASS folder when data.source=amass")
        if not 1 <= num_points:
            raise ValueError(f"data.num_points must be >= 1, got {num_points}")
        if not 0 <= noise_std < 0.05:
            raise ValueError(f"data.noise_std is in metres and must be in [0, 0.05), got {noise_std}")
        test_splits = tuple(TEST_SPLITS if test_splits is None else to_plain(test_splits))
        unknown = [t for t in test_splits if t not in TEST_SPLITS]
        if unknown or not test_splits:
            raise ValueError(
                f"data.test_splits must be a non-empty subset of {list(TEST_SPLITS)}, got {test_splits}"
            )
        self.test_splits = tuple(t for t in TEST_SPLITS if t in test_splits)
        view_splits = tuple(to_plain(view_splits) or ())
        if any(view_split(v) is None for v in view_splits):
            raise ValueError(
                f"data.view_splits must be a subset of {list(VIEW_NAMES)} (or their split names "
                f"{list(VIEW_SPLITS)}), got {list(view_splits)}"
            )
        named = {view_split(v) for v in view_splits}
        self.view_splits = tuple(v for v in VIEW_SPLITS if v in named)
        self.single_view = SingleViewConfig.from_mapping(to_plain(single_view))
        self.holes = HoleConfig.from_mapping(to_plain(holes))
        if not 0.0 <= float(hand_curl) <= 1.0:
            raise ValueError(f"data.hand_curl is a probability in [0, 1], got {hand_curl}")
        self.hand_curl = float(hand_curl)
        if not 0.0 <= float(wide_poses) <= 1.0:
            raise ValueError(f"data.wide_poses is a probability in [0, 1], got {wide_poses}")
        self.wide_poses = float(wide_poses)
        self.train_pose_mix = self._check_pose_mix(to_plain(train_pose_mix))
        self.fps_points = resolve_fps_points(fps_points, net, int(num_points))
        if self.fps_points > num_points:
            raise ValueError(f"data.fps_points={self.fps_points} is more than data.num_points={num_points}")
        self.source = source
        self.body_model_cfg = to_plain(body_model)
        self.amass_root = amass_root
        self.amass_kwargs = dict(to_plain(amass) or {})
        self.amass_ood_datasets = list(amass_ood_datasets)
        self.use_data_betas = use_data_betas
        self.sampling = {
            "num_points": int(num_points),
            "noise_std": float(noise_std),
            "density_contrast": float(density_contrast),
            "density_wavelength": float(density_wavelength),
            "beta_scale": float(beta_scale),
        }
        # data.shape_prior: rides with the sampling arguments of every dataset, and into the fixed sets'
        # cache keys as its fingerprint (str); the default adds nothing, so caches and streams stay as before
        self.shape_prior = shape_prior
        prior = make_shape_prior(shape_prior, self.body_model_cfg)
        if prior is not None:
            self.sampling["shapes"] = prior
        self.augment, self.eval_augment = augment, eval_augment
        tests = {t: test_size for t in (*TEST_SPLITS, *VIEW_SPLITS)}
        self.sizes = {"train": train_size, "val": val_size} | tests
        self.batch_size = batch_size
        self.eval_batch_size = eval_batch_size or batch_size
        self.num_workers = num_workers
        self.seed = seed
        if int(train_epoch_offset) < 0:
            raise ValueError(f"data.train_epoch_offset must be >= 0, got {train_epoch_offset}")
        self.train_epoch_offset = int(train_epoch_offset)
        self.cache = cache
        self.cache_root = Path(cache_root).expanduser() if cache_root else None
        self._body: torch.nn.Module | None = None
        self.datasets: dict[str, Dataset] = {}
        self.generated: list[str] = []  # fixed sets generated (not loaded from cache) by this instance
        self.train_sampler: EpochSampler | None = None
        self._resume_state: dict[str, int] | None = None
        # a rank may get no sample of a tiny fixed set (size < processes): that is fine here
        self.allow_zero_length_dataloader_with_multiple_devices = True

    # ------------------------------------------------------------------ body and sources
    @property
    def body(self) -> torch.nn.Module:
        """The body model (built on first access; the LightningModule can reuse it)."""
        if self._body is None:
            self._body = create_body(self.body_model_cfg).eval()
        return self._body

    @staticmethod
    def _check_pose_mix(mix: Any) -> dict[str, float] | None:
        if mix is None:
            return None
        if not isinstance(mix, Mapping) or not mix:
            raise ValueError(f"data.train_pose_mix must be null or a mapping of weights, got {mix!r}")
        unknown = [k for k in mix if k not in TRAIN_MIX_SOURCES]
        if unknown:
            raise ValueError(
                f"data.train_pose_mix: unknown sources {unknown}; known: {list(TRAIN_MIX_SOURCES)}"
            )
        try:
            weights = {str(k): float(v) for k, v in mix.items()}
        except (TypeError, ValueError):
            raise ValueError(f"data.train_pose_mix: weights must be numbers, got {dict(mix)}") from None
        if any(not (w >= 0 and math.isfinite(w)) for w in weights.values()) or sum(weights.values()) <= 0:
            raise ValueError(
                f"data.train_pose_mix: weights must be finite, >= 0 and not all 0, got {weights}"
            )
        return weights

    def _sources(self, split: str) -> PoseSource:
        if split == "train" and self.train_pose_mix is not None:
            named = {
                "id": lambda: self._base_source("train"),
                "ood": SyntheticOODPoses,
                "limb1": lambda: LimbOODPoses(1),
                "limb2": lambda: LimbOODPoses(2),
                "contact": lambda: ContactRejectedPoses(self.body),
                "athletic": lambda: SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG),
                "athletic_spine": lambda: SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG, spine_chain_prob=0.5),
            }
            mix = {k: w for k, w in self.train_pose_mix.items() if w > 0}
            return MixedPoses({k: named[k]() for k in mix}, mix)
        return self._base_source(split)

    def _base_source(self, split: str) -> PoseSource:
        if split == "test_ood_limb1" or split == "test_ood_limb2":
            return LimbOODPoses(int(split[-1]))
        if split == "test_ood_contact":
            return ContactRejectedPoses(self.body)
        if self.source == "synthetic":
            if split == "test_ood":
                return SyntheticOODPoses()
            return SyntheticIDPoses(wide_prob=self.wide_poses if split == "train" else 0.0)
        from arteq.data.amass import amass_source

        # data.amass options, the OOD sub-dataset; betas from the files only where they fit the body
        return amass_source(
            self.amass_root,
            split,
            self.amass_kwargs,
            ood_datasets=self.amass_ood_datasets,
            use_betas=self.use_data_betas,
            body_name=str(getattr(self.body, "name", "")),
        )

    def make_dataset(self, split: str) -> BodyScanDataset:
        """The on-the-fly dataset of a split (for the fixed splits: the generator of the cached set)."""
        src = self._sources("test_id" if split in VIEW_SPLITS else split)
        size = self.sizes[split]
        if size is None and split in GRADED_SPLITS:
            size = GRADED_DEFAULT_SIZE
        if size is None:
            if src.num_poses is None:
                raise ValueError(f"data size of split {split!r} must be set for an infinite pose source")
            size = src.num_poses
        augment = (
            self.augment if split == "train" else "so3" if split.startswith("test_ood") else self.eval_augment
        )
        if split in VIEW_SPLITS:  # one stream for the bodies of every view, the camera's own per view
            config = SingleViewConfig.from_mapping(self.single_view.to_dict() | {"prob": 1.0})
            return SingleViewDataset(
                src, self.body, "test_view", int(size), seed=self.seed, augment=augment, config=config,
                view=split[len("test_view_") :], **self.sampling,
            )  # fmt: skip
        holes = self.holes if split == "train" else None  # the fixed sets stay complete surfaces
        curl = (
            {"hand_curl": self.hand_curl} if split == "train" and self.hand_curl > 0 else {}
        )  # flat there too
        if split == "train" and self.single_view.prob > 0:
            return SingleViewDataset(
                src, self.body, split, int(size), seed=self.seed, augment=augment, config=self.single_view,
                view="any", holes=holes, **curl, **self.sampling,
            )  # fmt: skip
        return BodyScanDataset(
            src,
            self.body,
            split,
            int(size),
            seed=self.seed,
            augment=augment,
            holes=holes,
            **curl,
            **self.sampling,
        )

    # ------------------------------------------------------------------ fixed sets
    def _cache_key(self, ds: BodyScanDataset) -> str:
        spec = {
            "version": CACHE_VERSION,
            "split": ds.split,
            "size": ds.size,
            "seed": ds.seed,
            "augment": ds.augment,
            "sampling": self.sampling,
            "source": ds.source.fingerprint(),
            "body": body_fingerprint(self.body),
        }
        if isinstance(ds, SingleViewDataset):  # only these keys change: the other sets keep their files
            spec["single_view"] = ds.view_spec()
        if getattr(ds, "records_shapes", False):  # only the sets storing what body a sample is (allages)
            spec["shape_meta"] = ds.shapes.meta_spec()
        return hashlib.sha256(json.dumps(spec, sort_keys=True, default=str).encode()).hexdigest()[:20]

    def cache_path(self, split: str, ds: BodyScanDataset | None = None) -> Path:
        ds = ds or self.make_dataset(split)
        root = self.cache_root or cache_dir("datasets")
        root.mkdir(parents=True, exist_ok=True)
        return root / f"{split}-{self._cache_key(ds)}.pt"

    def _generate(self, ds: BodyScanDataset) -> dict[str, torch.Tensor]:
        loader = DataLoader(ds, batch_size=16, num_workers=self.num_workers, shuffle=False)
        parts: list[dict[str, torch.Tensor]] = []
        try:
            from tqdm.auto import tqdm

            it = tqdm(loader, desc=f"generating {ds.split} ({ds.size} scans)", leave=False)
        except ImportError:
            it = loader
        for batch in it:
            parts.append(batch)
        return {k: torch.cat([p[k] for p in parts]) for k in stored_keys(parts[0])}

    def _load_checked(self, path: Path, split: str, remove_bad: bool) -> dict[str, torch.Tensor] | None:
        if not path.is_file():
            return None
        try:
            return read_cache(path, split)
        except CorruptCacheError as e:
            if not remove_bad:
                return None
            log.warning("cached %s set %s is corrupt (%s): removed, regenerating", split, path, e)
            path.unlink(missing_ok=True)
            return None

    def fixed_set(self, split: str) -> TensorDictDataset:
        """Load the cached fixed set of ``split`` (``val``, ``test_id``, ``test_ood``) or generate it."""
        if split not in EVAL_SPLITS and split not in VIEW_SPLITS:
            raise ValueError(f"fixed splits are {EVAL_SPLITS + VIEW_SPLITS}, got {split!r}")
        ds = self.make_dataset(split)
        if not self.cache:
            self.generated.append(split)
            return TensorDictDataset(self._generate(ds))
        path = self.cache_path(split, ds)
        tensors = self._load_checked(path, split, remove_bad=False)  # fast path: no lock
        if tensors is None:
            from filelock import FileLock

            # One creator at a time; a waiting run loads what the first one wrote. Bad files are
            # removed only under the lock (never a file another run has just replaced).
            with FileLock(str(path) + ".lock"):
                tensors = self._load_checked(path, split, remove_bad=True)
                if tensors is None:
                    tensors = self._generate(ds)
                    write_cache(path, tensors, split)
                    self.generated.append(split)
                    log.info("cached %s set (%d scans) at %s", split, ds.size, path)
        return TensorDictDataset(tensors)

    # ------------------------------------------------------------------ Lightning hooks
    def _fixed_splits_for(self, stage: str | None) -> tuple[str, ...]:
        return {
            "fit": ("val",),
            "validate": ("val",),
            "test": self.test_loader_splits,
            "predict": self.test_splits,
        }.get(stage or "", EVAL_SPLITS)

    def prepare_data(self) -> None:
        """Create the cache files the coming stage needs (Lightning runs this on local rank 0 only, the
        other ranks wait; their ``setup`` then loads the files)."""
        if not self.cache:
            return
        fn = self.trainer.state.fn if self.trainer is not None else None
        stage = fn.value if fn is not None else None
        for split in self._fixed_splits_for(stage):
            if split not in self.datasets:
                self.datasets[split] = self.fixed_set(split)

    def setup(self, stage: str | None = None) -> None:
        want = ("train", "val") if stage == "fit" else self._fixed_splits_for(stage)
        if stage is None:
            want = ("train", "val", *self.test_loader_splits)
        for split in want:
            if split in self.datasets:
                continue
            self.datasets[split] = self.make_dataset(split) if split == "train" else self.fixed_set(split)

    def _rank_world(self) -> tuple[int, int]:
        trainer = self.trainer
        if trainer is None:
            return 0, 1
        return int(trainer.global_rank), int(trainer.world_size)

    def _loader(self, ds: Dataset, batch_size: int, sampler=None) -> DataLoader:
        return DataLoader(
            ds,
            batch_size=batch_size,
            sampler=sampler,
            shuffle=False,
            num_workers=self.num_workers,
            pin_memory=torch.cuda.is_available(),
            persistent_workers=self.num_workers > 0,
            collate_fn=FpsCollate(self.fps_points) if self.fps_points else None,
        )

    def _get(self, split: str) -> Dataset:
        if split not in self.datasets:
            self.setup({"train": "fit", "val": "validate"}.get(split, "test"))
        return self.datasets[split]

    def _eval_loader(self, split: str) -> DataLoader:
        ds = self._get(split)
        rank, world = self._rank_world()
        sampler = ShardSampler(len(ds), rank, world) if world > 1 else None
        return self._loader(ds, self.eval_batch_size, sampler)

    def train_dataloader(self) -> DataLoader:
        ds = self._get("train")
        rank, world = self._rank_world()
        sampler = EpochSampler(
            len(ds), seed=self.seed, rank=rank, world_size=world, epoch_offset=self.train_epoch_offset
        )
        if self._resume_state is not None:
            st = self._resume_state
            if (st.get("world_size"), st.get("batch_size")) != (world, self.batch_size):
                log.warning(
                    "resuming with %d process(es) x batch %d, the checkpoint was saved with %s x %s: the "
                    "training stream restarts at the beginning of epoch %d",
                    world, self.batch_size, st.get("world_size"), st.get("batch_size"), st["epoch"],
                )  # fmt: skip
                sampler.resume(st["epoch"], 0)
            elif st["batches_done"] >= st["batches_in_epoch"]:  # saved at the end of an epoch
                sampler.resume(st["epoch"] + 1, 0)
            else:
                sampler.resume(st["epoch"], min(st["batches_done"] * self.batch_size, sampler.per_rank))
            self._resume_state = None
        self.train_sampler = sampler
        return self._loader(ds, self.batch_size, sampler)

    def view_dataloaders(self) -> dict[str, DataLoader]:
        """``{split: loader}`` of the cached single-view test sets of ``view_splits`` (built on first use)."""
        for split in self.view_splits:
            if split not in self.datasets:
                self.datasets[split] = self.fixed_set(split)
        return {s: self._eval_loader(s) for s in self.view_splits}

    def val_dataloader(self) -> DataLoader:
        return self._eval_loader("val")

    @property
    def test_loader_splits(self) -> tuple[str, ...]:
        """Names of :meth:`test_dataloader`'s loaders, in order: ``test_splits``, then ``view_splits``."""
        return (*self.test_splits, *self.view_splits)

    def test_dataloader(self) -> list[DataLoader]:
        """One loader per test set of ``test_loader_splits``: those of ``test_splits`` (in the order of
        ``arteq.results.TEST_SPLITS``), then the view sets of ``view_splits`` (``VIEW_SPLITS`` order)."""
        return [self._eval_loader(s) for s in self.test_loader_splits]

    # ------------------------------------------------------------------ resume
    def state_dict(self) -> dict[str, Any]:
        """Position in the training stream, saved in every checkpoint (see module docstring)."""
        trainer = self.trainer
        s = self.train_sampler
        if trainer is None or s is None or s.active_epoch is None:
            return {}
        done = int(trainer.fit_loop.epoch_loop.batch_progress.current.ready)
        return {
            "epoch": int(s.active_epoch),
            "batches_done": done,
            "batches_in_epoch": int(trainer.num_training_batches),
            "batch_size": int(self.batch_size),
            "world_size": int(s.world_size),
        }

    def load_state_dict(self, state_dict: dict[str, Any]) -> None:
        self._resume_state = dict(state_dict) if state_dict else None
