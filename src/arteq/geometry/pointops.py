"""Batched point-cloud operations in plain PyTorch: FPS, kNN, ball query, gather, 3-NN interpolation.

All neighbour *indices* are computed in float64 under ``no_grad`` whatever the input dtype: in float32,
rounding differs between a cloud and its rotated copy, which changes FPS orders and kNN sets and
breaks exact equivariance (measured: FPS diverged after ~800 of 2500 steps at N = 5000). Distance
work is chunked over queries so that B = 8, N = 5000 stays within a few hundred MB.

Device-agnostic; on CPU, :func:`knn` uses ``scipy.spatial.cKDTree`` when ``backend="auto"`` (faster,
see ``benchmarks/bench_pointops.py``); the pure-torch path is the reference and the fallback.
"""

from __future__ import annotations

import numpy as np
import torch

#: Largest [B, chunk, N] float64 distance block formed at once (elements).
_CHUNK_ELEMS = 1 << 23


def _check_cloud(name: str, x: torch.Tensor, fn: str) -> None:
    if not isinstance(x, torch.Tensor):
        raise TypeError(f"{fn}: {name} must be a torch.Tensor, got {type(x).__name__}")
    if x.dim() != 3 or x.shape[-1] != 3:
        raise ValueError(f"{fn}: {name} must have shape [B, N, 3], got {tuple(x.shape)}")
    if x.shape[1] == 0:
        raise ValueError(f"{fn}: {name} is empty (0 points)")
    if not x.is_floating_point():
        raise TypeError(f"{fn}: {name} must be floating point, got {x.dtype}")
    # a host-device sync on accelerators: there the model checks its input once at its boundary
    # (EquivariantBackbone.forward) instead of in every neighbour query
    if x.device.type == "cpu" and not bool(torch.isfinite(x).all()):
        raise ValueError(f"{fn}: {name} contains NaN or inf")


def _sqdist(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Exact-ish squared distances ``[B, M, N]`` in float64 (difference form, not the dot trick)."""
    return (a[:, :, None, :] - b[:, None, :, :]).square().sum(-1)


@torch.no_grad()
def farthest_point_sample(xyz: torch.Tensor, m: int, start: int | torch.Tensor = 0) -> torch.Tensor:
    """Farthest point sampling.

    xyz: [B, N, 3]; m: number of samples (1 <= m <= N); start: first index, an int or a long tensor [B].
    Returns idx [B, m] long (``idx[:, 0] == start``). Computed in float64. The order is prefix-consistent:
    the first ``m' < m`` indices are the FPS of ``m'`` points from the same start, and FPS run on the
    sampled subset from the same start reproduces that prefix.
    """
    _check_cloud("xyz", xyz, "farthest_point_sample")
    b, n, _ = xyz.shape
    if not 1 <= m <= n:
        raise ValueError(f"farthest_point_sample: m must be in [1, N={n}], got {m}")
    x = xyz.detach().to(torch.float64)
    if isinstance(start, torch.Tensor):
        cur = start.to(device=xyz.device, dtype=torch.long).reshape(b)
    else:
        if not 0 <= start < n:
            raise ValueError(f"farthest_point_sample: start must be in [0, N={n}), got {start}")
        cur = torch.full((b,), int(start), dtype=torch.long, device=xyz.device)
    if xyz.device.type == "cpu":
        # numpy loop over the samples, vectorised across the batch: no per-step dispatch overhead (torch's
        # small ops slow down badly on a busy CPU; see benchmarks/README.md); per cloud the same float64
        # arithmetic and first-index argmax as the torch loop, so the same order
        # (coordinates as [3, B, N]: d = ((dx^2 + dy^2) + dz^2), the same rounding as summing over xyz)
        xt, cn = np.ascontiguousarray(x.numpy().transpose(2, 0, 1)), cur.numpy().copy()
        out = np.empty((b, m), dtype=np.int64)
        rows = np.arange(b)
        mind = np.full((b, n), np.inf)
        d, t = np.empty((b, n)), np.empty((b, n))
        for i in range(m):
            out[:, i] = cn
            np.subtract(xt[0], xt[0, rows, cn][:, None], out=d)
            np.multiply(d, d, out=d)
            for ax in (1, 2):
                np.subtract(xt[ax], xt[ax, rows, cn][:, None], out=t)
                np.multiply(t, t, out=t)
                np.add(d, t, out=d)
            np.minimum(mind, d, out=mind)
            cn = mind.argmax(-1)
        return torch.from_numpy(out)
    return _fps_torch(x, cur, m)


def _fps_torch(x: torch.Tensor, cur: torch.Tensor, m: int) -> torch.Tensor:
    """Torch FPS loop (any device). x: [B, N, 3] float64; cur: [B] start indices -> [B, m]."""
    b, n, _ = x.shape
    idx = torch.empty(b, m, dtype=torch.long, device=x.device)
    mind = torch.full((b, n), float("inf"), dtype=torch.float64, device=x.device)
    ar = torch.arange(b, device=x.device)
    for i in range(m):
        idx[:, i] = cur
        d = (x - x[ar, cur][:, None, :]).square().sum(-1)
        mind = torch.minimum(mind, d)
        cur = mind.argmax(-1)
    return idx


@torch.no_grad()
def centroid_nearest_index(xyz: torch.Tensor) -> torch.Tensor:
    """Index ``[B]`` of the point nearest each cloud's centroid (FPS start free of pose, position, order)."""
    _check_cloud("xyz", xyz, "centroid_nearest_index")
    x = xyz.detach().to(torch.float64)
    return (x - x.mean(1, keepdim=True)).square().sum(-1).argmin(-1)


def fps_from_centroid(xyz: torch.Tensor, m: int) -> torch.Tensor:
    """FPS order ``[B, m]`` starting from the point nearest each cloud's centroid: the backbone's FPS
    (:meth:`arteq.equivariant.EquivariantBackbone.compute_fps`), also run by data workers on the float32
    batch the network receives (same function, same float64 arithmetic, hence the same indices).
    ``m = 0`` gives an empty ``[B, 0]``."""
    if m == 0:
        return torch.zeros(xyz.shape[0], 0, dtype=torch.long, device=xyz.device)
    return farthest_point_sample(xyz, m, start=centroid_nearest_index(xyz))


def _knn_torch(q: torch.Tensor, r: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    b, m, _ = q.shape
    n = r.shape[1]
    chunk = max(1, _CHUNK_ELEMS // max(1, b * n))
    ds, ids = [], []
    for s in range(0, m, chunk):
        d = _sqdist(q[:, s : s + chunk], r)
        dv, iv = d.topk(k, dim=-1, largest=False, sorted=True)
        ds.append(dv)
        ids.append(iv)
    return torch.cat(ds, 1), torch.cat(ids, 1)


def _knn_scipy(q: torch.Tensor, r: torch.Tensor, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    from scipy.spatial import cKDTree

    qn, rn = q.numpy(), r.numpy()
    idx = torch.empty(q.shape[0], q.shape[1], k, dtype=torch.long)
    for i in range(q.shape[0]):
        _, ii = cKDTree(rn[i]).query(qn[i], k=k)
        idx[i] = torch.from_numpy(ii.reshape(q.shape[1], k))
    # distances recomputed in the same float64 difference form as the torch path
    d = (gather(r, idx) - q[:, :, None, :]).square().sum(-1)
    # cKDTree orders by (rounded) distance; re-sort so ties/rounding agree with the torch path
    d, o = d.sort(dim=-1, stable=True)
    return d, idx.gather(-1, o)


@torch.no_grad()
def knn(
    query: torch.Tensor, ref: torch.Tensor, k: int, backend: str = "auto"
) -> tuple[torch.Tensor, torch.Tensor]:
    """k nearest neighbours of each query point among the reference points.

    query: [B, M, 3]; ref: [B, N, 3]; 1 <= k <= N. Returns ``(dist2 [B, M, k] float64, idx [B, M, k] long)``
    sorted by increasing distance. ``backend``: ``"torch"`` (chunked brute force, the reference),
    ``"scipy"`` (cKDTree, CPU only) or ``"auto"`` (scipy on CPU, torch elsewhere).
    """
    _check_cloud("query", query, "knn")
    _check_cloud("ref", ref, "knn")
    if query.shape[0] != ref.shape[0]:
        raise ValueError(f"knn: batch sizes differ: query {query.shape[0]}, ref {ref.shape[0]}")
    n = ref.shape[1]
    if not 1 <= k <= n:
        raise ValueError(f"knn: k must be in [1, N={n}], got {k}")
    if backend not in ("auto", "torch", "scipy"):
        raise ValueError(f"knn: backend must be 'auto', 'torch' or 'scipy', got {backend!r}")
    q, r = query.detach().to(torch.float64), ref.detach().to(torch.float64)
    on_cpu = q.device.type == "cpu"
    if backend == "scipy" and not on_cpu:
        raise ValueError("knn: backend='scipy' needs CPU tensors")
    if backend == "scipy" or (backend == "auto" and on_cpu):
        return _knn_scipy(q, r, k)
    return _knn_torch(q, r, k)


@torch.no_grad()
def ball_query(
    query: torch.Tensor, ref: torch.Tensor, radius: float, k: int, backend: str = "auto"
) -> tuple[torch.Tensor, torch.Tensor]:
    """Up to ``k`` neighbours within ``radius`` of each query point.

    query: [B, M, 3]; ref: [B, N, 3]. Returns ``(idx [B, M, k] long, mask [B, M, k] bool)``.
    Selection rule: the ``k`` *nearest* reference points, sorted by distance, of which those farther
    than ``radius`` are invalid (``mask`` False). Padding rule: invalid slots hold the index of the
    nearest neighbour (slot 0), so gathers stay in range; consumers must apply ``mask``. If no point is
    within ``radius``, slot 0 is still the nearest point and its mask is False. Taking the nearest
    (rather than the first found in memory order, as CUDA ball queries do) makes the result
    independent of point order. If ``k > N``, ``k`` is clamped to ``N`` and the rest padded.
    """
    if not radius > 0:
        raise ValueError(f"ball_query: radius must be > 0, got {radius}")
    if k < 1:
        raise ValueError(f"ball_query: k must be >= 1, got {k}")
    _check_cloud("ref", ref, "ball_query")
    kk = min(k, ref.shape[1])
    d, idx = knn(query, ref, kk, backend=backend)
    mask = d <= radius * radius
    idx = torch.where(mask, idx, idx[..., :1])
    if kk < k:
        pad = k - kk
        idx = torch.cat([idx, idx[..., :1].expand(*idx.shape[:-1], pad)], -1)
        mask = torch.cat([mask, mask.new_zeros(*mask.shape[:-1], pad)], -1)
    return idx, mask


def gather(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Gather rows per batch: x [B, N, *F], idx [B, *I] long -> [B, *I, *F] (differentiable in x)."""
    if x.dim() < 2 or idx.dim() < 1 or x.shape[0] != idx.shape[0]:
        raise ValueError(
            f"gather: need x [B, N, ...] and idx [B, ...], got {tuple(x.shape)} and {tuple(idx.shape)}"
        )
    b, n = x.shape[:2]
    feat = x.shape[2:]
    flat = idx.reshape(b, -1)
    out = x.gather(1, flat.reshape(b, -1, *([1] * len(feat))).expand(b, flat.shape[1], *feat))
    return out.reshape(*idx.shape, *feat)


def three_nn_interpolate(
    query: torch.Tensor, ref: torch.Tensor, feats: torch.Tensor, eps: float = 1e-8, backend: str = "auto"
) -> torch.Tensor:
    """Inverse-squared-distance interpolation from the 3 nearest reference points (PointNet++ style).

    query: [B, M, 3]; ref: [B, N, 3]; feats: [B, N, *F]. Returns [B, M, *F] in ``feats.dtype``.
    Weights ``w_i = 1 / (d_i^2 + eps)`` normalised to sum 1, computed in float64 (no gradient through
    the coordinates). Uses ``min(3, N)`` neighbours. A query that coincides with a reference point gets
    (almost exactly) that point's feature.
    """
    _check_cloud("query", query, "three_nn_interpolate")
    _check_cloud("ref", ref, "three_nn_interpolate")
    if feats.dim() < 2 or feats.shape[:2] != ref.shape[:2]:
        raise ValueError(
            f"three_nn_interpolate: feats must be [B, N, ...] matching ref {tuple(ref.shape[:2])}, "
            f"got {tuple(feats.shape)}"
        )
    d, idx = knn(query, ref, min(3, ref.shape[1]), backend=backend)
    w = 1.0 / (d + eps)
    w = (w / w.sum(-1, keepdim=True)).to(feats.dtype)
    w = w.reshape(*w.shape, *([1] * (feats.dim() - 2)))
    out = gather(feats, idx[..., 0]) * w[:, :, 0]
    for i in range(1, idx.shape[-1]):  # one neighbour at a time: never forms [B, M, 3, *F]
        out = out + gather(feats, idx[..., i]) * w[:, :, i]
    return out
