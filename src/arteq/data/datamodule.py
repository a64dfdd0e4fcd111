"""``BodyScanDataModule``: train / val / test_id / test_ood loaders of synthetic body scans.

- ``train``: drawn on the fly, fresh every epoch (indices ``epoch * train_size + i``), ID source.
- ``val``, ``test_id``: fixed ID sets with their own random streams (disjoint seed spaces; with AMASS,
  held-out motions). ``test_ood``: fixed OOD set (synthetic extremes, or AMASS MPI_Limits), always with a
  random root orientation.
- Fixed sets are generated once and cached under ``arteq.paths.cache_dir("datasets")``, keyed by a hash of
  everything that defines them (source, body, sizes, sampling, seed), written atomically with
  ``torch.save`` of plain tensors and read with ``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch.utils.data import DataLoader, Dataset

from arteq.data.dataset import AUGMENTS, SAMPLE_KEYS, BodyScanDataset, EpochSampler, TensorDictDataset
from arteq.data.poses import PoseSource, SyntheticIDPoses, SyntheticOODPoses
from arteq.paths import cache_dir

log = logging.getLogger(__name__)
CACHE_VERSION = 1
EVAL_SPLITS = ("val", "test_id", "test_ood")


def build_body(body_model: Any) -> torch.nn.Module:
    """A body model from a module (returned as is) or a config mapping for ``arteq.body.load_body_model``.

    ``{"name": "toy"}`` gives the procedural :class:`arteq.data.toy_body.ToyBody` (fast tests).
    """
    if isinstance(body_model, torch.nn.Module):
        return body_model
    cfg = dict(body_model or {"name": "anny22"})
    cfg.pop("_target_", None)
    if cfg.get("name") == "toy":
        from arteq.data.toy_body import ToyBody

        return ToyBody(num_betas=int(cfg.get("num_betas", 2)))
    from arteq.body import load_body_model

    return load_body_model(**cfg)


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


def _plain(x: Any) -> Any:
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(x, DictConfig | ListConfig):
            return OmegaConf.to_container(x, resolve=True)
    except ImportError:
        pass
    return x


class BodyScanDataModule(L.LightningDataModule):
    """Lightning data module of synthetic scans (see module docstring and docs/data.md).

    Args:
        source: ``synthetic`` (ID motions + OOD extremes) or ``amass`` (DFaust_67 + MPI_Limits).
        body_model: config mapping for :func:`arteq.body.load_body_model` (``_target_`` ignored;
            ``name: toy`` for the procedural test body) or a body ``nn.Module``.
        amass_root: AMASS root folder (``source=amass``).
        amass: extra keyword arguments of :class:`arteq.data.amass.AmassPoses` for the ID splits
            (``datasets``, ``test_motions``, ``val_motions``, ``eval_stride``, ``train_stride``);
            ``amass_ood_datasets`` names the OOD folder candidates; ``amass_ood_stride`` its stride.
        use_data_betas: with AMASS, use the files' betas (only correct with an SMPL body; ``null`` = auto:
            true iff the body's name starts with ``smpl``); otherwise betas ~ N(0, beta_scale^2 I).
        num_points, noise_std, density_contrast, density_wavelength: cloud sampling.
        augment: train rotation augmentation ``none | so3 | z``; ``eval_augment`` for val / test_id;
            test_ood always gets ``so3``.
        train_size: samples per epoch (``null`` with AMASS: number of training frames).
        val_size, test_size: fixed set sizes (``null`` with AMASS: all frames of the split).
        batch_size, eval_batch_size, num_workers: loaders.
        seed: base seed of every random stream.
        cache: cache the fixed sets on disk; ``cache_root`` overrides the folder.
    """

    def __init__(
        self,
        source: str = "synthetic",
        body_model: Any = None,
        amass_root: str | None = None,
        amass: Mapping[str, Any] | None = None,
        amass_ood_datasets: list[str] | tuple[str, ...] = ("MPI_Limits", "PosePrior"),
        amass_ood_stride: int = 5,
        use_data_betas: bool | None = None,
        num_points: int = 5000,
        noise_std: float = 0.001,
        density_contrast: float = 0.75,
        density_wavelength: float = 0.6,
        beta_scale: float = 1.0,
        augment: str = "none",
        eval_augment: str = "none",
        train_size: int | None = 2000,
        val_size: int | None = 64,
        test_size: int | None = 256,
        batch_size: int = 4,
        eval_batch_size: int | None = None,
        num_workers: int = 0,
        seed: int = 0,
        cache: bool = True,
        cache_root: str | None = None,
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
        self.source = source
        self.body_model_cfg = _plain(body_model)
        self.amass_root = amass_root
        self.amass_kwargs = dict(_plain(amass) or {})
        self.amass_ood_datasets = list(amass_ood_datasets)
        self.amass_ood_stride = amass_ood_stride
        self.use_data_betas = use_data_betas
        self.sampling = {
            "num_points": int(num_points),
            "noise_std": float(noise_std),
            "density_contrast": float(density_contrast),
            "density_wavelength": float(density_wavelength),
            "beta_scale": float(beta_scale),
        }
        self.augment, self.eval_augment = augment, eval_augment
        self.sizes = {"train": train_size, "val": val_size, "test_id": test_size, "test_ood": test_size}
        self.batch_size = batch_size
        self.eval_batch_size = eval_batch_size or batch_size
        self.num_workers = num_workers
        self.seed = seed
        self.cache = cache
        self.cache_root = Path(cache_root).expanduser() if cache_root else None
        self._body: torch.nn.Module | None = None
        self.datasets: dict[str, Dataset] = {}
        self.generated: list[str] = []  # fixed sets generated (not loaded from cache) by this instance

    # ------------------------------------------------------------------ body and sources
    @property
    def body(self) -> torch.nn.Module:
        """The body model (built on first access; the LightningModule can reuse it)."""
        if self._body is None:
            self._body = build_body(self.body_model_cfg).eval()
        return self._body

    def _sources(self, split: str) -> PoseSource:
        if self.source == "synthetic":
            return SyntheticOODPoses() if split == "test_ood" else SyntheticIDPoses()
        from arteq.data.amass import AmassPoses

        use_betas = self.use_data_betas
        if use_betas is None:
            use_betas = str(getattr(self.body, "name", "")).lower().startswith("smpl")
        if split == "test_ood":
            return AmassPoses(
                self.amass_root,
                datasets=self.amass_ood_datasets,
                split="all",
                all_stride=self.amass_ood_stride,
                use_betas=use_betas,
            )
        amass_split = {"train": "train", "val": "val", "test_id": "test"}[split]
        return AmassPoses(self.amass_root, split=amass_split, use_betas=use_betas, **self.amass_kwargs)

    def make_dataset(self, split: str) -> BodyScanDataset:
        """The on-the-fly dataset of a split (for the fixed splits: the generator of the cached set)."""
        src = self._sources(split)
        size = self.sizes[split]
        if size is None:
            if src.num_poses is None:
                raise ValueError(f"data size of split {split!r} must be set for an infinite pose source")
            size = src.num_poses
        augment = {"train": self.augment, "test_ood": "so3"}.get(split, self.eval_augment)
        return BodyScanDataset(
            src, self.body, split, int(size), seed=self.seed, augment=augment, **self.sampling
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
        return {k: torch.cat([p[k] for p in parts]) for k in SAMPLE_KEYS}

    def fixed_set(self, split: str) -> TensorDictDataset:
        """Load the cached fixed set of ``split`` (``val``, ``test_id``, ``test_ood``) or generate it."""
        if split not in EVAL_SPLITS:
            raise ValueError(f"fixed splits are {EVAL_SPLITS}, got {split!r}")
        ds = self.make_dataset(split)
        if not self.cache:
            self.generated.append(split)
            return TensorDictDataset(self._generate(ds))
        path = self.cache_path(split, ds)
        if path.is_file():
            try:
                return TensorDictDataset(torch.load(path, map_location="cpu", weights_only=True))
            except Exception as e:  # a corrupt or foreign file: regenerate rather than fail
                log.warning("cached set %s unreadable (%s); regenerating", path, e)
        tensors = self._generate(ds)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        torch.save(tensors, tmp)
        os.replace(tmp, path)
        self.generated.append(split)
        log.info("cached %s set (%d scans) at %s", split, ds.size, path)
        return TensorDictDataset(tensors)

    # ------------------------------------------------------------------ Lightning hooks
    def setup(self, stage: str | None = None) -> None:
        want = {
            "fit": ("train", "val"),
            "validate": ("val",),
            "test": ("test_id", "test_ood"),
            "predict": ("test_id", "test_ood"),
        }.get(stage or "", ("train", "val", "test_id", "test_ood"))
        for split in want:
            if split in self.datasets:
                continue
            self.datasets[split] = self.make_dataset(split) if split == "train" else self.fixed_set(split)

    def _loader(self, ds: Dataset, batch_size: int, sampler=None) -> DataLoader:
        return DataLoader(
            ds,
            batch_size=batch_size,
            sampler=sampler,
            shuffle=False,
            num_workers=self.num_workers,
            pin_memory=torch.cuda.is_available(),
            persistent_workers=self.num_workers > 0,
        )

    def _get(self, split: str) -> Dataset:
        if split not in self.datasets:
            self.setup({"train": "fit", "val": "validate"}.get(split, "test"))
        return self.datasets[split]

    def train_dataloader(self) -> DataLoader:
        ds = self._get("train")
        return self._loader(ds, self.batch_size, EpochSampler(len(ds), seed=self.seed))

    def val_dataloader(self) -> DataLoader:
        return self._loader(self._get("val"), self.eval_batch_size)

    def test_dataloader(self) -> list[DataLoader]:
        """``[test_id, test_ood]`` (the order of ``arteq.training.module.TEST_SPLITS``)."""
        return [self._loader(self._get(s), self.eval_batch_size) for s in ("test_id", "test_ood")]
