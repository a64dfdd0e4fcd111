"""Exact fast forms of the backbone's hot operations (same results as the reference forms, less work).

- :func:`group_conv_fourier`: the group convolution ``out[g] = sum_k f[g h_k] @ W_k`` in the Fourier basis
  of the icosahedral group (A5: real irreps of dimensions 1, 3, 3, 4, 5). Per irrep it is one GEMM
  ``[P*d, d*C_in] @ [d*C_in, d*C_out]`` instead of a 13x gathered copy of the features.
- :class:`PermuteAxis`: a fixed permutation along one axis whose backward is the inverse permutation
  (a gather), not the scatter-add (``index_put`` with accumulation) of advanced indexing.
- :func:`gather_rows`: per-batch row gather through ``index_select`` on the flattened batch (backward
  ``index_add`` along dim 0).
- :func:`interpolate_csr`: inverse-distance 3-NN upsampling as a sparse CSR product (backward by the
  transposed CSR matrix; no atomics).

:func:`reference_ops` switches the backbone back to the reference forms (benchmarks and tests).

Fourier derivation (``rho`` real orthogonal irreps, ``fhat(rho) = sum_g f(g) rho(g)``): for the
right-translation convolution, ``outhat(rho) = sum_k fhat(rho) rho(h_k)^T W_k``, i.e. with coefficients
``A[i, l, c]`` (row ``i``, column ``l`` of ``fhat``)
``out[i, j, c'] = sum_{l, c} A[i, l, c] What[(l, c), (j, c')]`` and
``What[(l, c), (j, c')] = sum_k rho(h_k)[j, l] W_k[c, c']``. The orthonormal basis
``Q[g, (rho, i, j)] = sqrt(d / 60) rho(g)[i, j]`` turns features into these coefficients and back
(``A = Q^T f``, ``f = Q A``; Schur orthogonality makes ``Q`` orthogonal).
"""

from __future__ import annotations

import contextlib
import math
import warnings
from collections.abc import Iterator

import torch

from arteq.runtime import one_thread
from arteq.tensor_cache import tensor_cache

from .group import GROUP_SIZE, _tables

_PHI = (1.0 + math.sqrt(5.0)) / 2.0
# characters of A5 on the classes (identity, 72 deg, 144 deg, 120 deg, 180 deg)
_CHARACTERS = {
    "1": (1.0, 1.0, 1.0, 1.0, 1.0),
    "3": (3.0, _PHI, 1.0 - _PHI, 0.0, -1.0),
    "3'": (3.0, 1.0 - _PHI, _PHI, 0.0, -1.0),
    "4": (4.0, -1.0, -1.0, 1.0, 0.0),
    "5": (5.0, 0.0, 0.0, -1.0, 1.0),
}

_REFERENCE = False


def use_reference() -> bool:
    """True inside :func:`reference_ops` (the backbone then runs its reference implementation)."""
    return _REFERENCE


@contextlib.contextmanager
def reference_ops(enabled: bool = True) -> Iterator[None]:
    """Run the backbone with its reference (pre-speed-up) operations inside this block."""
    global _REFERENCE
    old, _REFERENCE = _REFERENCE, bool(enabled)
    try:
        yield
    finally:
        _REFERENCE = old


# --------------------------------------------------------------------------- Fourier basis
def _classes() -> torch.Tensor:
    """Conjugacy class index (0..4 in the order of ``_CHARACTERS``) of each element ``[60]``."""
    deg = torch.rad2deg(_tables()["angles"])
    targets = torch.tensor([0.0, 72.0, 144.0, 120.0, 180.0], dtype=torch.float64)
    cls = (deg[:, None] - targets[None]).abs().argmin(-1)
    if float((deg - targets[cls]).abs().max()) > 1e-6:
        raise RuntimeError("icosahedral group: unexpected rotation angle")
    return cls


def _canonical_basis(u: torch.Tensor) -> torch.Tensor:
    """An orthonormal basis ``[60, d]`` of the span of ``u`` that depends only on that subspace, not
    on the basis ``u`` an eigensolver returned: Gram-Schmidt of the orthogonal projector's columns,
    in order, keeping those clearly independent of the ones kept before."""
    d = u.shape[1]
    proj = u @ u.T
    out: list[torch.Tensor] = []
    for x in range(proj.shape[1]):
        v = proj[:, x].clone()
        for _ in range(2):  # twice: orthogonal to rounding
            for w in out:
                v = v - (w @ v) * w
        if float(v.norm()) > 0.5 * float(proj[x, x].clamp_min(0).sqrt()):
            out.append(v / v.norm())
            if len(out) == d:
                return torch.stack(out, 1)
    raise RuntimeError("icosahedral group: could not build a basis of an irreducible subspace")


@tensor_cache(maxsize=1)
def _irreps() -> tuple[tuple[int, torch.Tensor], ...]:
    """Real orthogonal irreps ``((d, rho [60, d, d]), ...)`` in float64, dimensions 1, 3, 3, 4, 5.

    The same tables in every process on a machine, whatever the thread count (one thread, and a basis
    fixed by its subspace): a float32 group convolution in another basis of the same irrep is the same
    linear map but rounds differently, and a run resumed in a new process must continue bit for bit."""
    with one_thread():  # LAPACK's eigenvectors depend on the thread count
        return _build_irreps()


def _build_irreps() -> tuple[tuple[int, torch.Tensor], ...]:
    t = _tables()
    cayley = t["cayley"]
    # left regular representation: L(g) e_y = e_{g y}
    left = torch.zeros(GROUP_SIZE, GROUP_SIZE, GROUP_SIZE, dtype=torch.float64)
    left[torch.arange(GROUP_SIZE)[:, None], cayley, torch.arange(GROUP_SIZE)[None, :]] = 1.0
    # right regular representation (commutes with L): R(h) e_y = e_{y h^-1}
    inv = t["inverse"]
    right = torch.zeros_like(left)
    right[torch.arange(GROUP_SIZE)[:, None], cayley[:, inv].T, torch.arange(GROUP_SIZE)[None, :]] = 1.0
    gen = torch.Generator().manual_seed(0)
    coeff = torch.randn(GROUP_SIZE, generator=gen, dtype=torch.float64)
    sym = torch.einsum("h,hxy->xy", coeff, right)
    sym = sym + sym.T  # symmetric, commutes with every L(g)
    cls = _classes()
    out = []
    for chars in _CHARACTERS.values():
        d = int(round(chars[0]))
        chi = torch.tensor(chars, dtype=torch.float64)[cls]  # [60]
        proj = (d / GROUP_SIZE) * torch.einsum("g,gxy->xy", chi, left)  # isotypic projector
        evals, evecs = torch.linalg.eigh(proj)
        basis = evecs[:, evals > 0.5]  # [60, d*d]
        if basis.shape[1] != d * d:
            raise RuntimeError(
                f"icosahedral group: isotypic component of dim {basis.shape[1]}, expected {d * d}"
            )
        ev, vec = torch.linalg.eigh(basis.T @ sym @ basis)
        # one eigenvalue of multiplicity d = one minimal left-invariant subspace
        u = _canonical_basis(basis @ vec[:, :d])
        if float((ev[:d] - ev[0]).abs().max()) > 1e-8 * max(1.0, float(ev.abs().max())):
            raise RuntimeError("icosahedral group: degenerate split of an isotypic component")
        rho = torch.einsum("xi,gxy,yj->gij", u, left, u)  # [60, d, d]
        if float((rho[cayley] - rho[:, None] @ rho[None, :]).abs().max()) > 1e-9:
            raise RuntimeError("icosahedral group: constructed irrep is not a homomorphism")
        out.append((d, rho))
    return tuple(out)


@tensor_cache(maxsize=1)
def _fourier_tables() -> tuple[torch.Tensor, tuple[int, ...], tuple[torch.Tensor, ...]]:
    """``Q [60, 60]`` (float64, orthogonal), irrep dims, and ``rho(H) [13, d, d]`` per irrep."""
    nbr = _tables()["neighbourhood"]
    cols, dims, rho_h = [], [], []
    for d, rho in _irreps():
        cols.append(math.sqrt(d / GROUP_SIZE) * rho.reshape(GROUP_SIZE, d * d))
        dims.append(d)
        rho_h.append(rho[nbr])
    q = torch.cat(cols, 1)
    if float((q.T @ q - torch.eye(GROUP_SIZE, dtype=torch.float64)).abs().max()) > 1e-10:
        raise RuntimeError("icosahedral group: Fourier basis is not orthogonal")
    return q, tuple(dims), tuple(rho_h)


_DEVICE_CACHE: dict[tuple[torch.dtype, torch.device], tuple[torch.Tensor, tuple[torch.Tensor, ...]]] = {}


def fourier_basis(
    dtype: torch.dtype = torch.float64, device: torch.device | str | None = None
) -> tuple[torch.Tensor, tuple[int, ...], tuple[torch.Tensor, ...]]:
    """``(Q [60, 60], dims, rho(H) per irrep [13, d, d])`` cast to ``dtype`` / ``device`` (cached)."""
    q, dims, rho_h = _fourier_tables()
    key = (dtype, torch.device(device) if device is not None else torch.device("cpu"))
    if key not in _DEVICE_CACHE:
        _DEVICE_CACHE[key] = _on_device(q, rho_h, dtype, key[1])
    qq, rr = _DEVICE_CACHE[key]
    return qq, dims, rr


def _on_device(q, rho_h, dtype, device):
    with torch.inference_mode(False):  # cached: never an inference tensor (see arteq.tensor_cache)
        return (
            q.to(dtype=dtype, device=device),
            tuple(r.to(dtype=dtype, device=device) for r in rho_h),
        )


def group_conv_fourier(x: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """Group convolution over the 13-element neighbourhood, exact, in the Fourier basis.

    x: ``[B, N, 60, C_in]``; weight: ``[13 * C_in, C_out]`` (rows ordered (k, c) like the reference
    :func:`arteq.equivariant.layers.group_conv`) -> ``[B, N, 60, C_out]``. Every output mixes all 60
    group elements, so in half precision its rounding is not equivariant: under autocast the layers use
    the gather form, which only permutes (see SeparableConvBlock.forward).
    """
    b, n, a, c_in = x.shape
    c_out = weight.shape[1]
    q, dims, rho_h = fourier_basis(x.dtype, x.device)
    w = weight.reshape(rho_h[0].shape[0], c_in, c_out)  # [13, C_in, C_out]
    p = b * n
    # coefficients: [P, 60, C] with the 60 axis = (irrep, i, l)
    coef = torch.matmul(q.T, x.reshape(p, a, c_in))
    outs = []
    off = 0
    for d, rh in zip(dims, rho_h):
        blk = coef[:, off : off + d * d].reshape(p * d, d * c_in)  # rows (P, i), cols (l, c)
        what = torch.einsum("kjl,kcd->lcjd", rh, w).reshape(d * c_in, d * c_out)
        outs.append((blk @ what).reshape(p, d * d, c_out))  # cols (j, c') -> [P, (i, j), C_out]
        off += d * d
    out = torch.cat(outs, 1)  # [P, 60, C_out]
    return torch.matmul(q, out).reshape(b, n, a, c_out)


# --------------------------------------------------------------------------- permutation / gathers
class _PermuteAxis(torch.autograd.Function):
    @staticmethod
    def forward(ctx, x: torch.Tensor, perm: torch.Tensor, inv: torch.Tensor, dim: int) -> torch.Tensor:
        ctx.save_for_backward(inv)
        ctx.dim = dim
        return x.index_select(dim, perm)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (inv,) = ctx.saved_tensors
        return grad.index_select(ctx.dim, inv), None, None, None


def permute_axis(x: torch.Tensor, perm: torch.Tensor, inv: torch.Tensor, dim: int) -> torch.Tensor:
    """``x.index_select(dim, perm)`` for a permutation ``perm`` with inverse ``inv``; backward gathers."""
    return _PermuteAxis.apply(x, perm, inv, dim)


def gather_rows(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """Per-batch row gather: x ``[B, N, *F]``, idx ``[B, *I]`` long -> ``[B, *I, *F]``.

    Same values as :func:`arteq.geometry.pointops.gather`, through ``index_select`` on ``[B * N, F]``
    rows (contiguous rows; backward is a row-wise ``index_add``).
    """
    b, n = x.shape[:2]
    feat = x.shape[2:]
    flat = (idx.reshape(b, -1) + torch.arange(b, device=idx.device)[:, None] * n).reshape(-1)
    out = x.reshape(b * n, -1).index_select(0, flat)
    return out.reshape(*idx.shape, *feat)


# --------------------------------------------------------------------------- sparse 3-NN upsampling
class _SparseMM(torch.autograd.Function):
    @staticmethod
    def forward(ctx, s: torch.Tensor, st: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(st)
        return torch.sparse.mm(s, x)

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        (st,) = ctx.saved_tensors
        return None, None, torch.sparse.mm(st, grad.contiguous())


def interpolate_csr(idx: torch.Tensor, w: torch.Tensor, feats: torch.Tensor) -> torch.Tensor:
    """``out[b, m] = sum_i w[b, m, i] * feats[b, idx[b, m, i]]`` as one CSR product.

    idx: ``[B, M, k]`` long; w: ``[B, M, k]`` (feats' dtype); feats: ``[B, N, *F]`` -> ``[B, M, *F]``.
    Gradient flows to ``feats`` only (the weights are geometry, computed without gradient).
    """
    b, m, k = idx.shape
    n = feats.shape[1]
    feat = feats.shape[2:]
    dev = idx.device
    cols = (idx + torch.arange(b, device=dev)[:, None, None] * n).reshape(-1)
    # sparse kernels have no half-precision forms on CPU: bfloat16 / float16 features (autocast) are
    # summed in float32 (autocast off: it would cast the product back down) and returned in their own
    # dtype; float32 / float64 are left as they are
    work = torch.promote_types(feats.dtype, torch.float32)
    vals = w.reshape(-1).to(work)
    rows = torch.arange(b * m, device=dev).repeat_interleave(k)
    order = torch.argsort(cols, stable=True)  # the transpose: rows of S^T = source points
    crow_t = torch.zeros(b * n + 1, dtype=torch.long, device=dev)
    crow_t[1:] = torch.cumsum(torch.bincount(cols, minlength=b * n), 0)
    with warnings.catch_warnings(), torch.autocast(dev.type, enabled=False):
        warnings.simplefilter("ignore", UserWarning)  # "sparse CSR support is in beta": these ops are stable
        s = torch.sparse_csr_tensor(
            torch.arange(0, b * m * k + 1, k, device=dev), cols, vals, (b * m, b * n), check_invariants=False
        )
        st = torch.sparse_csr_tensor(crow_t, rows[order], vals[order], (b * n, b * m), check_invariants=False)
        out = _SparseMM.apply(s, st, feats.reshape(b * n, -1).to(work))
    return out.to(feats.dtype).reshape(b, m, *feat)
