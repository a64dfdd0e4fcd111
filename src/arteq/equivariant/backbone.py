"""The EPN-style SE(3)-equivariant backbone of ArtEq: separable layers, FPS strides, 3-NN propagation."""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from arteq.geometry.pointops import fps_from_centroid, knn, three_nn_interpolate

from .fast_ops import interpolate_csr, use_reference
from .layers import DEFAULT_CHUNK_ELEMS, SeparableConvBlock


class EquivariantBackbone(nn.Module):
    """Point-wise features over the 60-element icosahedral group, equivariant to rotations in the group.

    ``forward(points [B, N, 3], fps_idx [B, >=M1] long | None) -> feats [B, N, 60, C_out]`` (channels
    last, group axis = dim 2), ``C_out = out_channels = channels[-1]``.

    Layers: ``len(channels)`` separable blocks (:class:`SeparableConvBlock`); block ``i`` has
    ``channels[i]`` outputs, ball radius ``radii[i]``, ``neighbours[i]`` neighbours, Gaussian-like
    kernel width ``sigmas[i]`` (default ``radii[i]**2 / 2``) and stride ``strides[i]`` (the number of
    points is divided by it, keeping a prefix of one farthest-point-sampling order). The input feature
    is a constant 1 per point and group element. The last layer's features are interpolated back to
    every input point from the 3 nearest centres (inverse squared distance). Defaults are the paper's
    setting: 5000 -> 2500 -> 2500 -> 1250 -> 1250 points, channels 32, 32, 64, 64.
    ``normalize``: neighbour sums divided by the neighbour count (see :mod:`arteq.equivariant.layers`);
    the constructor default ``False`` is what checkpoints made before the option hold, the project's
    part-local config (``conf/model/arteq_local.yaml``) sets ``True``.

    FPS: ``fps_idx`` gives the sample order of the first strided layer; it needs at least ``fps_size(N)``
    columns (extra columns are ignored: FPS is prefix-consistent). If omitted, it is computed here in
    float64, starting from the point nearest the centroid so that the result does not depend on pose,
    position or point order. Data workers compute the same indices with
    :func:`arteq.geometry.pointops.fps_from_centroid` (what ``compute_fps`` runs) on the CPU, in parallel
    with training (``data.fps_points``, see :class:`arteq.data.FpsCollate`): on a GPU the FPS loop is
    thousands of sequential kernel launches.
    A given ``fps_idx`` is checked for shape and dtype; its range only when it is on the CPU (reading
    its min / max on an accelerator would be a host-device sync; the data path's indices are valid by
    construction and move to the device after that check).

    Equivariance convention (relied upon by the heads): if the input is rotated by group element ``j``
    (``points @ R_j.T``), then ``out_rot[:, :, a] == out[:, :, cayley[inverse[j], a]]``: the feature at
    element ``b`` moves to element ``cayley[j, b]`` (see
    :func:`arteq.equivariant.group.rotate_group_features`). Hence for per-element weights ``w_a`` read
    off the features, ``sum_a w'_a R_a == R_j sum_b w_b R_b``. Translating the input leaves the output
    unchanged; permuting the input points permutes the output rows the same way (given consistent FPS).
    Exact up to rounding (float32 ~1e-5 relative, float64 ~1e-13).

    Memory: each layer's largest intermediates are computed in chunks of about ``chunk_elems``
    elements; ``checkpoint=True`` recomputes them in the backward pass instead of storing them.
    """

    def __init__(
        self,
        channels: Sequence[int] = (32, 32, 64, 64),
        strides: Sequence[int] = (2, 1, 2, 1),
        radii: Sequence[float] = (0.08, 0.113, 0.16, 0.16),
        neighbours: Sequence[int] = (64, 32, 64, 32),
        sigmas: Sequence[float] | None = None,
        kernel: str = "paper24",
        kernel_radius_ratio: float = 0.7,
        checkpoint: bool = False,
        use_fast_path: bool = True,
        chunk_elems: int = DEFAULT_CHUNK_ELEMS,
        normalize: bool = False,
    ) -> None:
        super().__init__()
        n = len(channels)
        if n == 0:
            raise ValueError("EquivariantBackbone: channels must not be empty")
        lists = {"strides": strides, "radii": radii, "neighbours": neighbours}
        if sigmas is not None:
            lists["sigmas"] = sigmas
        for name, v in lists.items():
            if len(v) != n:
                raise ValueError(f"EquivariantBackbone: {name} has {len(v)} entries, channels has {n}")
        if any(int(s) < 1 for s in strides):
            raise ValueError(f"EquivariantBackbone: strides must be >= 1, got {list(strides)}")
        self.channels = tuple(int(c) for c in channels)
        self.strides = tuple(int(s) for s in strides)
        self.kernel = kernel
        self.normalize = bool(normalize)
        self.out_channels = self.channels[-1]
        c_in = 1
        blocks = []
        for i in range(n):
            blocks.append(
                SeparableConvBlock(
                    c_in,
                    self.channels[i],
                    radius=float(radii[i]),
                    n_neighbours=int(neighbours[i]),
                    sigma=None if sigmas is None else float(sigmas[i]),
                    kernel=kernel,
                    kernel_radius_ratio=kernel_radius_ratio,
                    use_fast_path=use_fast_path,
                    checkpoint=checkpoint,
                    chunk_elems=chunk_elems,
                    normalize=normalize,
                )
            )
            c_in = self.channels[i]
        self.blocks = nn.ModuleList(blocks)

    def point_counts(self, n_points: int) -> list[int]:
        """Number of points after each block for an input of ``n_points``."""
        return point_counts(self.strides, n_points)

    def fps_size(self, n_points: int) -> int:
        """Columns of ``fps_idx`` needed for ``n_points`` input points (0 if no block is strided)."""
        return fps_size(self.strides, n_points)

    def compute_fps(self, points: torch.Tensor) -> torch.Tensor:
        """FPS order ``[B, fps_size(N)]`` from the point nearest the centroid (float64, no grad)."""
        return fps_from_centroid(points, self.fps_size(points.shape[1]))

    def forward(self, points: torch.Tensor, fps_idx: torch.Tensor | None = None) -> torch.Tensor:
        if not isinstance(points, torch.Tensor) or points.dim() != 3 or points.shape[-1] != 3:
            shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
            raise ValueError(f"EquivariantBackbone: points must have shape [B, N, 3], got {shape}")
        b, n, _ = points.shape
        counts = self.point_counts(n)
        if n == 0 or min(counts) < 1:
            raise ValueError(
                f"EquivariantBackbone: {n} points is too few for strides {self.strides} "
                "(need >= 1 point after each block)"
            )
        if not bool(torch.isfinite(points).all()):
            raise ValueError("EquivariantBackbone: points contain NaN or inf")
        dtype = self.blocks[0].spatial_weight.dtype
        points = points.to(dtype)
        need = self.fps_size(n)
        if fps_idx is None:
            fps_idx = self.compute_fps(points)
        elif need > 0:
            if fps_idx.dim() != 2 or fps_idx.shape[0] != b or fps_idx.shape[1] < need:
                raise ValueError(
                    f"EquivariantBackbone: fps_idx must be [B={b}, >={need}] for N={n}, "
                    f"got {tuple(fps_idx.shape)}"
                )
            if fps_idx.dtype != torch.long:
                raise ValueError(
                    f"EquivariantBackbone: fps_idx must be long indices (int64), got {fps_idx.dtype}"
                )
            fps_idx = fps_idx[:, :need]
            # range check on the CPU only (on an accelerator min / max would be a host-device sync)
            if fps_idx.device.type == "cpu" and (int(fps_idx.min()) < 0 or int(fps_idx.max()) >= n):
                raise ValueError(
                    f"EquivariantBackbone: fps_idx must be long indices in [0, {n}), got values in "
                    f"[{int(fps_idx.min())}, {int(fps_idx.max())}]"
                )
            fps_idx = fps_idx.to(points.device)
        xyz = points
        feats = None  # the constant input 1 (see SeparableConvBlock.forward)
        downsampled = False
        for block, stride, m in zip(self.blocks, self.strides, counts):
            centres = None
            if stride > 1:
                # first strided block: FPS indices into the input; later ones: prefix of the FPS-ordered set
                centres = (
                    fps_idx[:, :m] if not downsampled else torch.arange(m, device=xyz.device).expand(b, m)
                )
                downsampled = True
            xyz, feats = block(xyz, feats, centres)
        if xyz.shape[1] == n and not downsampled:
            return feats
        if use_reference():
            return three_nn_interpolate(points, xyz, feats)
        return upsample_3nn(points, xyz, feats)


def point_counts(strides: Sequence[int], n_points: int) -> list[int]:
    """Number of points after each block of a backbone with ``strides`` for ``n_points`` input points."""
    counts, m = [], int(n_points)
    for s in strides:
        m = m // int(s)
        counts.append(m)
    return counts


def fps_size(strides: Sequence[int], n_points: int) -> int:
    """FPS indices a backbone with ``strides`` needs for ``n_points`` input points: the point count after
    its first strided block (0 if no block is strided)."""
    counts = point_counts(strides, n_points)
    return next((c for c, s in zip(counts, strides) if int(s) > 1), 0)


def upsample_3nn(
    query: torch.Tensor, ref: torch.Tensor, feats: torch.Tensor, eps: float = 1e-8
) -> torch.Tensor:
    """:func:`arteq.geometry.pointops.three_nn_interpolate` (same weights, float64 geometry) as a CSR
    product: [B, M, 3], [B, N, 3], [B, N, *F] -> [B, M, *F]."""
    d, idx = knn(query, ref, min(3, ref.shape[1]))
    w = 1.0 / (d + eps)
    w = w / w.sum(-1, keepdim=True)
    return interpolate_csr(idx, w.to(feats.dtype), feats)
