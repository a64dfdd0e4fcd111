"""EPN-style separable SE(3) point convolution (SPConv) over the icosahedral group, channels last.

Feature layout everywhere: ``[B, N, A, C]`` (batch, points, 60 group elements, channels).

One :class:`SeparableConvBlock` is: spatial conv -> instance norm -> LeakyReLU(0.01) -> group conv ->
instance norm -> LeakyReLU(0.01), plus a 1x1 (linear) residual branch from the input features at the
output centres.

- Spatial conv: for centre ``c``, element ``a`` and kernel point ``j``, neighbour ``n`` (ball query,
  masked) gets weight ``max(0, 1 - |(x_n - x_c) - R_a k_j|^2 / sigma)``; the weighted sum over
  neighbours of ``f_in[n, a]`` is mapped by a learned ``W_j [C_in, C_out]`` shared over group elements
  and summed over ``j``: one contraction ``[.., A, J*C_in] @ [J*C_in, C_out]``.
- Neighbour normalisation (``normalize``): with ``True`` the sum is divided by the number of neighbours
  found in the ball (the mean over found neighbours), so the response is driven by local shape, not by
  how many points the ball happens to hold; the authors' CUDA ball query gets the same in effect by
  filling its ``k`` slots cyclically with the neighbours it found (their sum is ``k`` times this mean
  when ``k`` is a multiple of the count, close to it otherwise). ``False`` (what networks built before
  this option used, and the constructor default, so their checkpoints load unchanged) keeps the plain
  masked sum, whose scale follows the Poisson count of points in the ball and the non-uniform density:
  that is why those networks needed balls much larger than a body part (see docs/backbone.md).
- Closed kernels (``ico13``/``ico33``): ``R_a k_j = k_{pi[a, j]}``, so the ``[.., A, J, K]`` weight
  tensor is a re-indexing of one ``[.., J, K]`` tensor (60x smaller); same result, see
  ``use_fast_path``.
- Group conv: ``out[g] = sum_k f[cayley[g, H[k]]] @ W_k`` over the 13-element neighbourhood ``H``.
- Instance norm: per sample and channel, over points and group elements, no affine. Convolution
  biases are omitted (a per-channel constant is removed by the following norm anyway).

Speed (same results, see :mod:`arteq.equivariant.fast_ops`): the group conv runs in the group's Fourier
basis, the closed-kernel re-index is a permutation whose backward gathers, neighbour features are
gathered as rows, and a block whose input is the constant 1 (the first layer) sums kernel weights
instead of gathering features. ``fast_ops.reference_ops()`` restores the reference forms.
"""

from __future__ import annotations

import logging
import math

import torch
import torch.nn.functional as F
from torch import nn
from torch.utils.checkpoint import checkpoint as _checkpoint

from arteq.geometry.pointops import ball_query, gather

from .fast_ops import gather_rows, group_conv_fourier, permute_axis, use_reference
from .group import GROUP_SIZE, group_conv_index, kernel_permutation, rotated_kernel_points

log = logging.getLogger(__name__)

#: Default budget (elements) of the largest per-chunk intermediate.
DEFAULT_CHUNK_ELEMS = 1 << 24


def instance_norm(x: torch.Tensor, eps: float = 1e-5) -> torch.Tensor:
    """Normalise x [B, N, A, C] per sample and channel over points and group elements (no affine).

    Statistics in at least float32 (also under autocast: bf16 sums over 10^5 elements lose digits).
    Two passes (the mean, then the mean square about it), each reduced over the points first with the
    contiguous ``A * C`` row kept: on CPU about 3x faster forward and 1.7x forward and backward than
    ``torch.var_mean`` over the strided dims (1, 2) (benchmarks/README.md), the same to float rounding.
    """
    with torch.autocast(x.device.type, enabled=False):
        xf = x.float() if x.dtype in (torch.float16, torch.bfloat16) else x
        b, n, a, c = xf.shape
        mean = xf.reshape(b, n, a * c).mean(1).reshape(b, a, c).mean(1).reshape(b, 1, 1, c)
        d = xf - mean
        rows = d.reshape(b, n, a * c)
        var = torch.linalg.vecdot(rows, rows, dim=1).reshape(b, a, c).mean(1).reshape(b, 1, 1, c) / n
        return d * torch.rsqrt(var + eps)


def spatial_aggregate(
    rel: torch.Tensor, mask: torch.Tensor, nb_feats: torch.Tensor, rot_kernels: torch.Tensor, sigma: float
) -> torch.Tensor:
    """General spatial aggregation with rotated kernels.

    rel: [B, M, K, 3] neighbour offsets ``x_n - x_c``; mask: [B, M, K] bool; nb_feats: [B, M, K, A, C];
    rot_kernels: [A, J, 3] (``R_a k_j``). Returns [B, M, A, J, C]:
    ``sum_n max(0, 1 - |rel_n - R_a k_j|^2 / sigma) * mask_n * nb_feats[n, a]``.
    """
    # 1 - |r - q|^2 / s = (1 - |r|^2 / s) - |q|^2 / s + (2 / s) r.q, formed once in the [B,M,A,J,K] layout
    a = 1.0 - rel.square().sum(-1) / sigma  # [B, M, K]
    q = rot_kernels.square().sum(-1) / sigma  # [A, J]
    w = torch.einsum("bmkx,ajx->bmajk", rel, rot_kernels * (2.0 / sigma))
    w = F.relu(w + a[:, :, None, None, :] - q[None, None, :, :, None]) * mask[:, :, None, None, :].to(
        rel.dtype
    )
    return torch.matmul(w, nb_feats.permute(0, 1, 3, 2, 4))  # [B,M,A,J,K] @ [B,M,A,K,C]


def spatial_aggregate_closed(
    rel: torch.Tensor,
    mask: torch.Tensor,
    nb_feats: torch.Tensor,
    kernels: torch.Tensor,
    perm: torch.Tensor,
    sigma: float,
) -> torch.Tensor:
    """Same result as :func:`spatial_aggregate` for a kernel set closed under the group.

    kernels: [J, 3]; perm: [A, J] long with ``R_a k_j = k_{perm[a, j]}``; other shapes as there.
    Forms a [B, M, J, K] weight tensor instead of [B, M, A, J, K].
    """
    b, m, k, a, c = nb_feats.shape
    j = kernels.shape[0]
    d2 = (rel[:, :, None, :, :] - kernels[None, None, :, None, :]).square().sum(-1)  # B M J K
    w = F.relu(1.0 - d2 / sigma) * mask[:, :, None, :].to(rel.dtype)
    g = torch.matmul(w, nb_feats.reshape(b, m, k, a * c)).reshape(b, m, j * a, c)  # [B,M,(J A),C]
    flat = perm * a + torch.arange(a, device=perm.device)[:, None]  # [A, J]: (pi[a,j], a)
    if use_reference():
        return g[:, :, flat.reshape(-1)].reshape(b, m, a, j, c)
    flat = flat.reshape(-1)
    return permute_axis(g, flat, torch.argsort(flat), 2).reshape(b, m, a, j, c)


def kernel_weight_sums(
    rel: torch.Tensor, mask: torch.Tensor, kernels: torch.Tensor, sigma: float, perm: torch.Tensor | None
) -> torch.Tensor:
    """``sum_n max(0, 1 - |rel_n - R_a k_j|^2 / sigma) * mask_n`` ``[B, M, A, J]``: the spatial aggregate of
    a constant feature 1 (the first layer's input). ``kernels``: ``[J, 3]`` with ``perm`` (closed set) or
    the rotated set ``[A, J, 3]`` with ``perm=None``."""
    mk = mask.to(rel.dtype)
    if perm is not None:
        d2 = (rel[:, :, None, :, :] - kernels[None, None, :, None, :]).square().sum(-1)  # B M J K
        s = (F.relu(1.0 - d2 / sigma) * mk[:, :, None, :]).sum(-1)  # [B, M, J]
        return s[:, :, perm]  # [B, M, A, J]
    a = 1.0 - rel.square().sum(-1) / sigma
    q = kernels.square().sum(-1) / sigma
    w = torch.einsum("bmkx,ajx->bmajk", rel, kernels * (2.0 / sigma))
    return (F.relu(w + a[:, :, None, None, :] - q[None, None, :, :, None]) * mk[:, :, None, None, :]).sum(-1)


def group_conv(x: torch.Tensor, index: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """x [B, N, A, C_in]; index [A, H] long; weight [H * C_in, C_out] -> [B, N, A, C_out].

    Reference (gather) form; :func:`arteq.equivariant.fast_ops.group_conv_fourier` is the same map for
    the default neighbourhood.
    """
    b, n, a, c = x.shape
    h = index.shape[1]
    return x[:, :, index.reshape(-1)].reshape(b, n, a, h * c) @ weight


class SeparableConvBlock(nn.Module):
    """One separable SE(3) layer with residual branch (see module docstring).

    forward(xyz [B, N, 3], feats [B, N, A, C_in], centres [B, M] long or None) ->
    (new_xyz [B, M, 3], new_feats [B, M, A, C_out]); ``centres`` indexes the output points in ``xyz``
    (``None``: every point is a centre).
    """

    def __init__(
        self,
        c_in: int,
        c_out: int,
        radius: float,
        n_neighbours: int,
        sigma: float | None = None,
        kernel: str = "paper24",
        kernel_radius_ratio: float = 0.7,
        use_fast_path: bool = True,
        checkpoint: bool = False,
        chunk_elems: int = DEFAULT_CHUNK_ELEMS,
        normalize: bool = False,
    ) -> None:
        super().__init__()
        if c_in < 1 or c_out < 1:
            raise ValueError(f"SeparableConvBlock: channels must be >= 1, got c_in={c_in}, c_out={c_out}")
        if not radius > 0 or n_neighbours < 1:
            raise ValueError(
                f"SeparableConvBlock: need radius > 0 and n_neighbours >= 1, got {radius}, {n_neighbours}"
            )
        self.c_in, self.c_out = c_in, c_out
        self.radius, self.n_neighbours = float(radius), int(n_neighbours)
        self.sigma = float(sigma) if sigma is not None else self.radius**2 / 2.0
        if not self.sigma > 0:
            raise ValueError(f"SeparableConvBlock: sigma must be > 0, got {self.sigma}")
        self.kernel = kernel
        self.normalize = bool(normalize)
        self.checkpoint = checkpoint
        self.chunk_elems = int(chunk_elems)
        kr = kernel_radius_ratio * self.radius
        rk = rotated_kernel_points(kernel, kr, torch.float64)
        # float64 source of truth (cast on use) so that float64 runs are exact to rounding
        self.register_buffer("rot_kernels", rk)  # [A, J, 3]
        self.register_buffer("kernels", rk[0].clone())  # [J, 3] (element 0 is the identity)
        perm = kernel_permutation(kernel)
        self.fast = bool(use_fast_path and perm is not None)
        self.register_buffer("kernel_perm", perm if perm is not None else torch.zeros(0, dtype=torch.long))
        self.register_buffer("gconv_index", group_conv_index())
        j, h = rk.shape[1], self.gconv_index.shape[1]
        self.n_kernel = j
        self.spatial_weight = nn.Parameter(torch.empty(j * c_in, c_out))
        self.group_weight = nn.Parameter(torch.empty(h * c_out, c_out))
        self.shortcut = nn.Linear(c_in, c_out)
        for p, fan in ((self.spatial_weight, j * c_in), (self.group_weight, h * c_out)):
            nn.init.uniform_(p, -1.0 / math.sqrt(fan), 1.0 / math.sqrt(fan))

    def _load_from_state_dict(self, state_dict, prefix, local_metadata, strict, missing, unexpected, errors):
        # Kernel points are persistent buffers (older checkpoints hold them), but they follow from this
        # block's kernel set and radius: weights saved by a network with other radii would otherwise bring
        # their kernel points along while sigma follows this block's radius. Keep this block's own.
        for name in ("rot_kernels", "kernels"):
            key = prefix + name
            if key in state_dict:
                saved, own = state_dict[key], getattr(self, name)
                if saved.shape != own.shape or not torch.allclose(saved.to(own.dtype), own, atol=1e-6):
                    log.warning(
                        "%s: the loaded kernel points (norm %.4f) belong to another ball radius; "
                        "keeping this block's own (radius %.4g m, norm %.4f)",
                        key, float(saved.norm()), self.radius, float(own.norm()),
                    )  # fmt: skip
                state_dict[key] = own.detach().clone()
        super()._load_from_state_dict(state_dict, prefix, local_metadata, strict, missing, unexpected, errors)

    def extra_repr(self) -> str:
        return (
            f"c_in={self.c_in}, c_out={self.c_out}, radius={self.radius}, k={self.n_neighbours}, "
            f"sigma={self.sigma:g}, kernel={self.kernel} (J={self.n_kernel}), fast={self.fast}, "
            f"normalize={self.normalize}"
        )

    def _spatial_chunk(self, xyz, feats, new_xyz, idx, mask):
        rel = gather(xyz, idx) - new_xyz[:, :, None, :]  # [B, m, K, 3]
        if self.normalize:  # mean over the neighbours found: the mask rescaled by 1 / count (>= 1)
            mask = mask.to(rel.dtype)
            mask = mask / mask.sum(-1, keepdim=True).clamp_min(1.0)
        if feats is None:  # constant input 1: the neighbour sum of features is the sum of kernel weights
            if self.fast:
                s = kernel_weight_sums(rel, mask, self.kernels.to(rel.dtype), self.sigma, self.kernel_perm)
            else:
                s = kernel_weight_sums(rel, mask, self.rot_kernels.to(rel.dtype), self.sigma, None)
            w = self.spatial_weight.reshape(self.n_kernel, self.c_in, self.c_out).sum(1)
            return s.to(w.dtype) @ w
        nb = gather(feats, idx) if use_reference() else gather_rows(feats, idx)  # [B, m, K, A, C]
        if self.fast:
            kern = self.kernels.to(rel.dtype)
            g = spatial_aggregate_closed(rel, mask, nb, kern, self.kernel_perm, self.sigma)
        else:
            g = spatial_aggregate(rel, mask, nb, self.rot_kernels.to(rel.dtype), self.sigma)
        b, m, a = g.shape[:3]
        return g.reshape(b, m, a, -1) @ self.spatial_weight

    def _run(self, fn, *args):
        if self.checkpoint and torch.is_grad_enabled():
            return _checkpoint(fn, *args, use_reentrant=False)
        return fn(*args)

    def forward(
        self, xyz: torch.Tensor, feats: torch.Tensor | None, centres: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """``feats=None`` stands for the constant input 1 (``[B, N, 60, C_in]`` of ones), computed without
        materialising or gathering it."""
        b, n, _ = xyz.shape
        if feats is not None and feats.shape != (b, n, GROUP_SIZE, self.c_in):
            raise ValueError(
                f"SeparableConvBlock: feats must be [B={b}, N={n}, 60, C_in={self.c_in}], "
                f"got {tuple(feats.shape)}"
            )
        dtype = self.spatial_weight.dtype
        if feats is None and use_reference():
            feats = xyz.new_ones(b, n, GROUP_SIZE, self.c_in, dtype=dtype)
        new_xyz = xyz if centres is None else gather(xyz, centres)
        m = new_xyz.shape[1]
        idx, mask = ball_query(new_xyz, xyz, self.radius, self.n_neighbours)
        k = idx.shape[-1]
        per_centre = b * k * GROUP_SIZE * max(self.c_in, 1 if self.fast else self.n_kernel)
        step = max(1, self.chunk_elems // per_centre)
        out = torch.cat(
            [
                self._run(
                    self._spatial_chunk,
                    xyz,
                    feats,
                    new_xyz[:, s : s + step],
                    idx[:, s : s + step],
                    mask[:, s : s + step],
                )
                for s in range(0, m, step)
            ],
            1,
        )
        out = F.leaky_relu(instance_norm(out), 0.01)
        # Gather form under autocast: it only permutes group elements, so bfloat16 / float16 rounding commutes
        # with the group action (the Fourier form mixes all 60, and its rounding measurably breaks
        # equivariance).
        if use_reference() or torch.is_autocast_enabled(out.device.type):
            gidx = self.gconv_index
            step = max(1, self.chunk_elems // (b * GROUP_SIZE * gidx.shape[1] * self.c_out))
            out = torch.cat(
                [
                    self._run(group_conv, out[:, s : s + step], gidx, self.group_weight)
                    for s in range(0, m, step)
                ],
                1,
            )
        else:
            out = self._run(group_conv_fourier, out, self.group_weight)
        out = F.leaky_relu(instance_norm(out), 0.01)
        if feats is None:  # shortcut of the constant 1: a per-channel constant
            res = (self.shortcut.weight.sum(1) + self.shortcut.bias).to(out.dtype)
            return new_xyz, out + res
        res = feats if centres is None else gather(feats, centres)
        return new_xyz, out + self.shortcut(res)
