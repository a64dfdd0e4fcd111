"""Body-scan samples: pose source -> body model -> noisy non-uniform point cloud with part labels.

Every sample is drawn independently and deterministically from ``(seed, split, index)``: four
generators (pose, shape, augmentation, surface) are seeded from a hash of those, so changing e.g.
the augmentation leaves the pose, shape and point pattern of a sample unchanged.

Translation convention: the body is posed in a "scan frame" (``transl`` from the source, or 0), points
are sampled there, then the cloud is centred by subtracting its centroid ``center``. The sample's
``transl`` is ``scan_transl - center``, so ``body(betas, pose, transl)`` gives the ground-truth mesh in the
centred frame; a result goes back to the scan frame by adding ``center``.

Sample keys (float32 unless stated): ``points [N,3]`` (centred), ``labels [N]`` int64 (0..21),
``pose [22,3,3]`` local rotation matrices (root includes the global orientation), ``global_rotmats
[22,3,3]``, ``betas [nb]``, ``transl [3]``, ``center [3]``. With a shape prior that records what body a
draw is (``shapes`` with a ``draw`` method: :class:`arteq.data.shapes.StoredShapePrior`), also the
:data:`META_KEYS` ``shape_index``, ``age_years``, ``build_extreme`` (0-d; see :mod:`arteq.data.shapes`).
"""

from __future__ import annotations

import hashlib
import math

import roma
import torch
from torch.utils.data import Dataset, Sampler

from arteq.body.lbs import skin
from arteq.body.skeleton import PARENTS
from arteq.data.holes import OVERSAMPLE, HoleConfig, carve_holes
from arteq.data.poses import PoseSource
from arteq.data.shapes import SHAPE_META_KEYS, no_shape_meta
from arteq.geometry.rotations import euler_to_rotmat, random_rotmat
from arteq.geometry.sampling import interpolate_labels, sample_surface, smooth_density_field
from arteq.runtime import one_thread

AUGMENTS = ("none", "so3", "z")
SAMPLE_KEYS = ("points", "labels", "pose", "global_rotmats", "betas", "transl", "center")
#: Optional per-sample keys: what body a sample is, present when its dataset's shape prior records it.
META_KEYS = SHAPE_META_KEYS


def seeded_generator(*parts: object) -> torch.Generator:
    """A CPU generator seeded from a stable hash of ``parts`` (not Python's salted ``hash``)."""
    digest = hashlib.blake2b(repr(parts).encode(), digest_size=8).digest()
    return torch.Generator().manual_seed(int.from_bytes(digest, "little") & ((1 << 63) - 1))


def augmentation_rotation(kind: str, generator: torch.Generator) -> torch.Tensor:
    """Rotation ``[3, 3]`` float64 for ``augment``: identity, Haar-uniform (so3) or about y (z: vertical)."""
    if kind == "none":
        return torch.eye(3, dtype=torch.float64)
    if kind == "so3":
        return random_rotmat(1, generator)[0]
    if kind == "z":
        yaw = torch.rand((), generator=generator, dtype=torch.float64) * 360.0
        return euler_to_rotmat(torch.stack([yaw.new_zeros(()), yaw, yaw.new_zeros(())]))
    raise ValueError(f"augment must be one of {AUGMENTS}, got {kind!r}")


class BodyScanDataset(Dataset):
    """Synthetic scans of a body model posed by a :class:`PoseSource`.

    Args:
        source: pose source.
        body: body model (``BodyModel`` or anything with its call signature and buffers ``faces``,
            ``lbs_weights``, attribute ``num_betas``).
        split: split name, part of the random-stream key.
        size: ``len(dataset)``; any index >= 0 is valid (training uses ``epoch * size + i``).
        seed: base seed.
        num_points: points per cloud.
        noise_std: Gaussian noise, metres.
        augment: ``none`` | ``so3`` | ``z`` (rotation of the whole body about the pelvis).
        density_contrast, density_wavelength: non-uniform density field (see
            :mod:`arteq.geometry.sampling`); contrast 0 = uniform.
        beta_scale: betas ~ N(0, beta_scale^2 I) when the source gives none.
        shapes: draw the betas from this prior instead when the source gives none (an object with
            ``sample(num_betas, generator)``, e.g. :class:`arteq.data.shapes.StoredShapePrior`; None: the
            normal prior). If it also has ``draw(num_betas, generator) -> (betas, meta)``, every sample
            carries ``meta`` (:data:`META_KEYS`; for betas from the source: unknown, ``shape_index`` -1).
        holes: holes in the full-surface clouds (:class:`arteq.data.holes.HoleConfig`; None: none).
    """

    def __init__(
        self,
        source: PoseSource,
        body: torch.nn.Module,
        split: str,
        size: int,
        seed: int = 0,
        num_points: int = 5000,
        noise_std: float = 0.001,
        augment: str = "none",
        density_contrast: float = 0.75,
        density_wavelength: float = 0.6,
        beta_scale: float = 1.0,
        shapes: object | None = None,
        holes: HoleConfig | None = None,
        hand_curl: float = 0.0,
    ) -> None:
        if augment not in AUGMENTS:
            raise ValueError(f"augment must be one of {AUGMENTS}, got {augment!r}")
        if not isinstance(num_points, int) or num_points < 1:
            raise ValueError(f"num_points must be a positive int, got {num_points!r}")
        if not (math.isfinite(noise_std) and 0 <= noise_std < 0.05):
            raise ValueError(f"noise_std is in metres and must be in [0, 0.05), got {noise_std}")
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        self.source, self.body, self.split, self.size, self.seed = source, body, split, size, seed
        self.num_points, self.noise_std, self.augment = num_points, noise_std, augment
        self.density_contrast, self.density_wavelength = density_contrast, density_wavelength
        self.beta_scale = beta_scale
        self.shapes = shapes
        self.holes = holes if holes is not None and holes.prob > 0 else None
        if not 0.0 <= float(hand_curl) <= 1.0:
            raise ValueError(f"hand_curl is a probability in [0, 1], got {hand_curl}")
        #: share of samples whose hands are curled (each hand uniform in [0, 1]; :mod:`arteq.body.hands`)
        self.hand_curl = float(hand_curl)
        self._hands = None
        if self.hand_curl > 0:
            from arteq.body.hands import hands_for

            self._hands = hands_for(body)
            if self._hands is None:
                raise ValueError(
                    "hand_curl needs a body built from Anny (its finger bones); "
                    f"{getattr(body, 'name', 'body')!r} has none"
                )

    def __len__(self) -> int:
        return self.size

    @property
    def records_shapes(self) -> bool:
        """Whether samples carry :data:`META_KEYS` (the shape prior records what body a draw is)."""
        return self.shapes is not None and callable(getattr(self.shapes, "draw", None))

    def _betas(self, src_betas: torch.Tensor | None, generator: torch.Generator) -> torch.Tensor:
        return self._shape(src_betas, generator)[0]

    def _shape(
        self, src_betas: torch.Tensor | None, generator: torch.Generator
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor] | None]:
        """``(betas [nb] float64, meta)``: meta per :data:`META_KEYS` when :attr:`records_shapes`, else None.
        The same random numbers whichever is asked for."""
        nb = int(self.body.num_betas)
        if src_betas is None and self.shapes is not None:
            if self.records_shapes:
                return self.shapes.draw(nb, generator)
            return self.shapes.sample(nb, generator), None
        meta = no_shape_meta() if self.records_shapes else None
        return self._source_betas(src_betas, generator), meta

    def _source_betas(self, src_betas: torch.Tensor | None, generator: torch.Generator) -> torch.Tensor:
        nb = int(self.body.num_betas)
        if src_betas is None:
            return torch.randn(nb, generator=generator, dtype=torch.float64) * self.beta_scale
        out = torch.zeros(nb, dtype=torch.float64)
        k = min(nb, src_betas.shape[0])
        out[:k] = src_betas[:k]
        return out

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        # Per-sample tensors are small: one intra-op thread is much faster than several competing
        # ones (20x on a busy 2-core machine). DataLoader workers already run with one thread.
        with one_thread(), torch.no_grad():
            return self._make(index)

    def source_sample(self, index: int) -> dict:
        """The pose source's raw sample behind ``self[index]`` (before rotation augmentation)."""
        return self.source.sample(index, seeded_generator(self.seed, self.split, int(index), "pose"))

    def _make(self, index: int) -> dict[str, torch.Tensor]:
        index = int(index)
        if index < 0:
            raise IndexError(f"index must be >= 0, got {index}")
        key = (self.seed, self.split, index)
        src = self.source_sample(index)
        pose = src["pose"]
        if pose.shape != (22, 3) or not torch.isfinite(pose).all():
            raise ValueError(
                f"{type(self.source).__name__} gave a bad pose at index {index}: {tuple(pose.shape)}"
            )
        rot = roma.rotvec_to_rotmat(pose.double())
        rot[0] = augmentation_rotation(self.augment, seeded_generator(*key, "aug")) @ rot[0]
        betas, meta = self._shape(src.get("betas"), seeded_generator(*key, "shape"))
        scan_transl = src.get("transl")
        scan_transl = torch.zeros(3, dtype=torch.float64) if scan_transl is None else scan_transl.double()

        dtype = self.body.lbs_weights.dtype
        curl = self._curl(key)
        if curl is None:
            out = self.body(
                betas=betas[None].to(dtype), pose=rot[None].to(dtype), transl=scan_transl[None].to(dtype)
            )
            verts, grot, pelvis = out.vertices[0], out.global_rotmats[0], out.joints[0, 0]
        else:  # the same body with its fingers curled before the skinning (the pose and shape as drawn)
            rest, rest_joints = self.body.shape(betas[None].to(dtype))
            hands = self._hands(rest, curl.to(dtype))
            weights, transl = self.body.lbs_weights, scan_transl[None].to(dtype)
            verts, joints, grots = skin(
                hands, rest_joints, rot[None].to(dtype), weights, PARENTS, None, transl
            )
            verts, grot, pelvis = verts[0], grots[0], joints[0, 0]
        points, labels = self._surface_points(verts, self.body.faces, grot, pelvis, key)
        center = points.mean(0)
        sample = {
            "points": (points - center).float(),
            "labels": labels.long(),
            "pose": rot.float(),
            "global_rotmats": grot.float(),
            "betas": betas.float(),
            "transl": (scan_transl - center.double()).float(),
            "center": center.float(),
        }
        if meta is not None:
            sample.update({k: meta[k] for k in META_KEYS})
        return sample

    def _curl(self, key: tuple) -> torch.Tensor | None:
        """``[1, 2]`` the sample's hands' curl (:attr:`hand_curl` of the samples, its own random stream), or
        None for flat hands."""
        if self.hand_curl <= 0:
            return None
        u = torch.rand(3, generator=seeded_generator(*key, "hands"), dtype=torch.float64)
        return u[None, 1:] if u[0] < self.hand_curl else None

    def _surface_points(
        self, verts: torch.Tensor, faces: torch.Tensor, grot: torch.Tensor, pelvis: torch.Tensor, key: tuple
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``(points [N, 3], labels [N])`` of the posed mesh ``verts`` (``grot``: the parts' world rotations,
        ``pelvis``: the root joint, ``key``: the sample's stream key): the full-surface sampler. Subclasses
        draw other kinds of clouds (:class:`arteq.data.single_view.SingleViewDataset`)."""
        g = seeded_generator(*key, "surface")
        # density field anchored to the body's root frame: rotating the body does not move it
        centroids = (verts[faces].mean(1) - pelvis) @ grot[0]
        density = smooth_density_field(centroids, g, self.density_contrast, self.density_wavelength)
        gh = None if self.holes is None else seeded_generator(*key, "holes")  # a stream of its own: a cloud
        # without holes is drawn as before the option existed
        if gh is None or float(torch.rand((), generator=gh, dtype=torch.float64)) >= self.holes.prob:
            points, face_idx, bary = sample_surface(verts, faces, self.num_points, g, density, self.noise_std)
            return points, interpolate_labels(self.body.lbs_weights, faces, face_idx, bary)
        n = math.ceil(self.num_points * OVERSAMPLE)
        points, face_idx, bary = sample_surface(verts, faces, n, g, density, self.noise_std)
        kept, _ = carve_holes(points, self.num_points, self.holes, gh)
        return points[kept], interpolate_labels(self.body.lbs_weights, faces, face_idx[kept], bary[kept])


class TensorDictDataset(Dataset):
    """A fixed set of samples stored as a dict of stacked tensors (all with the same first dim)."""

    def __init__(self, tensors: dict[str, torch.Tensor]) -> None:
        missing = [k for k in SAMPLE_KEYS if k not in tensors]
        if missing:
            raise ValueError(f"cached set is missing keys {missing}")
        n = {v.shape[0] for v in tensors.values()}
        if len(n) != 1:
            raise ValueError(f"cached tensors disagree on the sample count: {n}")
        self.tensors = tensors
        self.size = n.pop()

    def __len__(self) -> int:
        return self.size

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        return {k: v[index] for k, v in self.tensors.items()}


class EpochSampler(Sampler[int]):
    """Training indices ``epoch * size + perm_epoch(i)``: fresh samples every epoch, sharded over ranks.

    Each epoch draws one permutation of ``range(size)`` seeded by ``(seed, epoch)``; process ``rank`` of
    ``world_size`` takes every ``world_size``-th entry of it from ``rank`` (``size // world_size`` per rank,
    the remainder is dropped so that every rank runs the same number of steps). Since a sample is drawn
    from ``(seed, split, index)``, the ranks see disjoint samples, every epoch different ones, and the
    stream is deterministic (independent of workers, and the union over ranks is the 1-process epoch).

    Epoch bookkeeping: an iteration uses ``self.epoch`` and then advances it (so a plain loop over the
    loader gets a new epoch each time); ``set_epoch`` pins the next iteration's epoch (Lightning calls
    it every epoch) and ``resume(epoch, skip)`` additionally skips the first ``skip`` indices of that
    epoch's shard once (mid-epoch resume: the skipped samples are never generated).

    ``epoch_offset`` shifts the stream: epoch ``e`` draws what epoch ``e + epoch_offset`` of an unshifted
    sampler would (a run that starts from another run's weights can train on clouds that run never drew;
    the epoch counters, and so resuming, are unaffected).
    """

    def __init__(
        self,
        size: int,
        seed: int = 0,
        shuffle: bool = True,
        rank: int = 0,
        world_size: int = 1,
        epoch_offset: int = 0,
    ):
        if not 0 <= rank < world_size:
            raise ValueError(f"EpochSampler: rank must be in [0, {world_size}), got {rank}")
        if int(epoch_offset) < 0:
            raise ValueError(f"EpochSampler: epoch_offset must be >= 0, got {epoch_offset}")
        self.epoch_offset = int(epoch_offset)
        self.size, self.seed, self.shuffle = size, seed, shuffle
        self.rank, self.world_size = int(rank), int(world_size)
        self.per_rank = size // self.world_size
        if self.per_rank < 1:
            raise ValueError(f"EpochSampler: {size} samples cannot be shared by {world_size} processes")
        self.epoch = 0
        self.skip = 0
        self.active_epoch: int | None = None  # epoch of the iteration in progress (or last started)

    def set_epoch(self, epoch: int) -> None:
        self.epoch = int(epoch)

    def resume(self, epoch: int, skip: int) -> None:
        """The next iteration is epoch ``epoch`` without its first ``skip`` indices (of this rank's shard)."""
        if not 0 <= skip <= self.per_rank:
            raise ValueError(f"EpochSampler.resume: skip must be in [0, {self.per_rank}], got {skip}")
        self.epoch, self.skip = int(epoch), int(skip)

    def __len__(self) -> int:
        return self.per_rank

    def epoch_indices(self, epoch: int) -> list[int]:
        """This rank's full index list of ``epoch`` (what an iteration of that epoch yields)."""
        epoch = epoch + self.epoch_offset
        if self.shuffle:
            order = torch.randperm(self.size, generator=seeded_generator(self.seed, "epoch", epoch))
        else:
            order = torch.arange(self.size)
        mine = order[self.rank :: self.world_size][: self.per_rank]
        return [epoch * self.size + int(i) for i in mine]

    def __iter__(self):
        e, skip = self.epoch, self.skip
        self.epoch, self.skip = e + 1, 0
        self.active_epoch = e
        yield from self.epoch_indices(e)[skip:]


class ShardSampler(Sampler[int]):
    """Indices ``rank, rank + world_size, ...`` of a fixed set: each sample on exactly one rank, no padding
    and no duplicates (unlike ``DistributedSampler``), so metrics summed over ranks equal 1-process ones."""

    def __init__(self, size: int, rank: int = 0, world_size: int = 1) -> None:
        if not 0 <= rank < world_size:
            raise ValueError(f"ShardSampler: rank must be in [0, {world_size}), got {rank}")
        self.size, self.rank, self.world_size = size, rank, world_size

    def __len__(self) -> int:
        return len(range(self.rank, self.size, self.world_size))

    def __iter__(self):
        return iter(range(self.rank, self.size, self.world_size))
