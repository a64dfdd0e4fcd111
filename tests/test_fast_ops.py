"""The backbone's fast operations agree with the reference forms (values and gradients) and keep
the group structure they rely on."""

from __future__ import annotations

import pytest
import torch

from arteq.equivariant import (
    EquivariantBackbone,
    cayley_table,
    group_conv,
    group_conv_fourier,
    group_conv_index,
    reference_ops,
)
from arteq.equivariant.fast_ops import (
    _build_irreps,
    _irreps,
    fourier_basis,
    gather_rows,
    interpolate_csr,
    permute_axis,
)
from arteq.geometry.pointops import gather, knn, three_nn_interpolate


def test_irreps_are_orthogonal_homomorphisms_and_basis_is_orthogonal():
    cayley = cayley_table()
    dims = []
    for d, rho in _irreps():
        dims.append(d)
        assert torch.allclose(rho[cayley], rho[:, None] @ rho[None, :], atol=1e-10)
        eye = torch.eye(d, dtype=torch.float64)
        assert torch.allclose(rho @ rho.transpose(-1, -2), eye.expand_as(rho), atol=1e-10)
        assert torch.allclose(rho[0], eye, atol=1e-12)
    assert sorted(dims) == [1, 3, 3, 4, 5]
    q, _, _ = fourier_basis()
    assert torch.allclose(q.T @ q, torch.eye(60, dtype=torch.float64), atol=1e-10)


def test_irreps_do_not_depend_on_the_thread_count():
    # LAPACK returns another basis of a degenerate eigenspace at another thread count; the group conv in
    # another basis of the same irrep rounds differently in float32, so a run resumed in a new process
    # diverged from the uninterrupted one (seen in CI). The basis must be fixed by its subspace alone.
    threads = torch.get_num_threads()
    try:
        builds = []
        for n in (1, 2, 3):
            torch.set_num_threads(n)
            builds.append(_build_irreps())
    finally:
        torch.set_num_threads(threads)
    for other in builds[1:]:
        for (d, a), (d2, b) in zip(builds[0], other):
            assert d == d2
            torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
    for (_, a), (_, b) in zip(builds[0], _irreps()):
        torch.testing.assert_close(a, b, rtol=0, atol=1e-12)


@pytest.mark.parametrize("dtype,tol", [(torch.float64, 1e-12), (torch.float32, 2e-5)])
def test_fourier_group_conv_matches_gather_form(dtype, tol):
    g = torch.Generator().manual_seed(0)
    x = torch.randn(2, 7, 60, 5, generator=g, dtype=dtype, requires_grad=True)
    w = torch.randn(13 * 5, 6, generator=g, dtype=dtype, requires_grad=True)
    ref = group_conv(x, group_conv_index(), w)
    out = group_conv_fourier(x, w)
    assert (out - ref).abs().max() <= tol * ref.abs().max()
    up = torch.randn_like(ref)
    g_ref = torch.autograd.grad(ref, (x, w), up)
    g_out = torch.autograd.grad(out, (x, w), up)
    for a, b in zip(g_ref, g_out):
        assert (a - b).abs().max() <= tol * a.abs().max()


def test_permute_axis_and_row_gather_match_indexing_with_gradients():
    g = torch.Generator().manual_seed(1)
    x = torch.randn(3, 4, 12, 2, generator=g, dtype=torch.float64, requires_grad=True)
    perm = torch.randperm(12, generator=g)
    a = permute_axis(x, perm, torch.argsort(perm), 2)
    b = x[:, :, perm]
    up = torch.randn_like(b)
    assert torch.equal(a, b)
    assert torch.equal(torch.autograd.grad(a, x, up)[0], torch.autograd.grad(b, x, up)[0])
    idx = torch.randint(0, 4, (3, 5, 6), generator=g)
    a, b = gather_rows(x, idx), gather(x, idx)
    up = torch.randn_like(b)
    assert torch.equal(a, b)
    assert torch.allclose(torch.autograd.grad(a, x, up)[0], torch.autograd.grad(b, x, up)[0], atol=1e-14)


def test_csr_interpolation_matches_three_nn():
    g = torch.Generator().manual_seed(2)
    q = torch.rand(2, 40, 3, generator=g, dtype=torch.float64)
    r = torch.rand(2, 15, 3, generator=g, dtype=torch.float64)
    f = torch.randn(2, 15, 60, 3, generator=g, dtype=torch.float64, requires_grad=True)
    d, idx = knn(q, r, 3)
    w = 1.0 / (d + 1e-8)
    out = interpolate_csr(idx, w / w.sum(-1, keepdim=True), f)
    ref = three_nn_interpolate(q, r, f)
    assert torch.allclose(out, ref, atol=1e-13)
    up = torch.randn_like(ref)
    assert torch.allclose(torch.autograd.grad(out, f, up)[0], torch.autograd.grad(ref, f, up)[0], atol=1e-13)


@pytest.mark.parametrize("kernel", ["ico13", "paper24"])
def test_backbone_fast_equals_reference_in_float64(kernel):
    """Outputs and parameter gradients of the whole backbone: fast path vs the pre-speed-up code."""
    torch.manual_seed(0)
    m = EquivariantBackbone(
        channels=[4, 4, 6, 6], neighbours=[12, 8, 12, 8], radii=[0.3, 0.4, 0.55, 0.55], kernel=kernel
    ).double()
    x = torch.rand(2, 120, 3, dtype=torch.float64) * torch.tensor([0.6, 0.3, 1.7], dtype=torch.float64)
    results = []
    for ref in (True, False):
        m.zero_grad()
        with reference_ops(ref):
            y = m(x)
        (y.square().mean() + y[..., :2].sum()).backward()
        results.append((y.detach(), [p.grad.clone() for p in m.parameters()]))
    (y_ref, g_ref), (y_fast, g_fast) = results
    assert (y_ref - y_fast).abs().max() <= 1e-12 * y_ref.abs().max()
    for a, b in zip(g_ref, g_fast):
        assert (a - b).abs().max() <= 1e-11 * max(a.abs().max(), 1e-30)


def test_caches_built_in_inference_mode_still_train():
    """Constant tables first built under inference_mode (a validation loop, arteq-fit) must not break a
    later training step in the same process."""
    from arteq.body import skeleton
    from arteq.equivariant import fast_ops, group

    cached = [group._tables, group._unit_kernel, group._kernel_perm, fast_ops._irreps,
              fast_ops._fourier_tables, skeleton._parent_index]  # fmt: skip
    for fn in cached:
        fn.cache_clear()
    fast_ops._DEVICE_CACHE.clear()
    x = torch.randn(1, 2, 60, 3)
    w = torch.randn(13 * 3, 4)
    rots = torch.eye(3).expand(1, 22, 3, 3)
    with torch.inference_mode():
        fast_ops.group_conv_fourier(x, w)
        skeleton.global_to_local(rots)
    w.requires_grad_(True)
    fast_ops.group_conv_fourier(x, w).sum().backward()
    assert w.grad is not None and torch.isfinite(w.grad).all()
    r = rots.clone().requires_grad_(True)
    skeleton.global_to_local(r).sum().backward()
    assert r.grad is not None


def test_instance_norm_agrees_with_var_mean_in_values_and_gradients():
    from arteq.equivariant import instance_norm

    torch.manual_seed(0)
    x = (torch.randn(3, 17, 60, 5, dtype=torch.float64) * 2 + 3).requires_grad_(True)
    g = torch.randn_like(x)
    var, mean = torch.var_mean(x, dim=(1, 2), keepdim=True, unbiased=False)
    ref = (x - mean) * torch.rsqrt(var + 1e-5)
    (gr,) = torch.autograd.grad((ref * g).sum(), x)
    out = instance_norm(x)
    (go,) = torch.autograd.grad((out * g).sum(), x)
    torch.testing.assert_close(out, ref, rtol=0, atol=1e-12)
    torch.testing.assert_close(go, gr, rtol=0, atol=1e-12)
    # per sample and channel: zero mean, unit variance over points and group elements
    torch.testing.assert_close(out.mean((1, 2)), torch.zeros(3, 5, dtype=torch.float64), rtol=0, atol=1e-12)
    # half-precision input: statistics and result in float32, as close to the float64 result as float32 allows
    low = instance_norm(x.detach().to(torch.bfloat16))
    assert low.dtype == torch.float32
    exact = instance_norm(x.detach().to(torch.bfloat16).double())
    torch.testing.assert_close(low.double(), exact, atol=1e-5, rtol=0)
