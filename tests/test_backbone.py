"""Exact equivariance and behaviour of the separable layers and the equivariant backbone."""

from __future__ import annotations

import pytest
import torch

from arteq.equivariant import (
    EquivariantBackbone,
    SeparableConvBlock,
    element_orders,
    group_rotations,
    inverse_table,
    rotate_group_features,
    spatial_aggregate,
    spatial_aggregate_closed,
)
from arteq.equivariant.group import kernel_permutation, kernel_points, rotated_kernel_points

SMALL = dict(channels=(4, 4, 6, 6), radii=(0.35, 0.45, 0.6, 0.6), neighbours=(12, 8, 12, 8))
N = 120


def _elements() -> list[int]:
    """Fixed random pick of two order-3 and two order-5 elements (180-degree ones hide a wrong convention)."""
    orders = element_orders()
    g = torch.Generator().manual_seed(7)
    o3 = torch.nonzero(orders == 3)[:, 0]
    o5 = torch.nonzero(orders == 5)[:, 0]
    pick = lambda v: v[torch.randperm(v.numel(), generator=g)[:2]].tolist()  # noqa: E731
    return pick(o3) + pick(o5)


def _cloud(dtype, b=2, n=N, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(b, n, 3, generator=g, dtype=torch.float64) - 0.5).to(dtype)


def _model(kernel, dtype, **kw):
    torch.manual_seed(0)
    return EquivariantBackbone(kernel=kernel, **{**SMALL, **kw}).to(dtype).eval()


def _rel(a, b):
    return float((a - b).detach().abs().max() / b.detach().abs().max())


@pytest.mark.parametrize("kernel", ["paper24", "ico13"])
@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-4), (torch.float64, 1e-11)])
def test_rotation_equivariance_exact(kernel, dtype, tol):
    m = _model(kernel, dtype)
    x = _cloud(dtype)
    r = group_rotations(dtype)
    with torch.no_grad():
        out = m(x)
        assert out.shape == (2, N, 60, m.out_channels)
        for j in _elements():
            rot = m(x @ r[j].T)
            assert _rel(rot, rotate_group_features(out, j)) < tol
            assert _rel(rot.mean(2), out.mean(2)) < tol  # group-mean feature invariant
            assert _rel(rot, out) > 1e-2  # and the features really do move


def test_wrong_convention_is_detected():
    m = _model("ico13", torch.float64)
    x = _cloud(torch.float64)
    r = group_rotations(torch.float64)
    j = _elements()[0]  # order 3: the inverse permutation differs
    with torch.no_grad():
        out, rot = m(x), m(x @ r[j].T)
    wrong = rotate_group_features(out, int(inverse_table()[j]))  # the opposite convention
    assert _rel(rot, wrong) > 1e-3


@pytest.mark.parametrize("kernel", ["paper24", "ico13"])
def test_translation_invariance_and_point_order(kernel):
    m = _model(kernel, torch.float32)
    x = _cloud(torch.float32)
    with torch.no_grad():
        out = m(x)
        assert _rel(m(x + torch.tensor([0.3, -1.2, 2.0])), out) < 1e-4
        perm = torch.randperm(N, generator=torch.Generator().manual_seed(1))
        assert _rel(m(x[:, perm]), out[:, perm]) < 1e-5


def test_precomputed_fps_matches_internal():
    m = _model("ico13", torch.float32)
    x = _cloud(torch.float32)
    fps = m.compute_fps(x)
    assert fps.shape == (2, m.fps_size(N)) == (2, N // 2)
    with torch.no_grad():
        assert torch.equal(m(x, fps_idx=fps), m(x))
        longer = torch.cat([fps, fps[:, :3]], 1)  # extra columns ignored
        assert torch.equal(m(x, fps_idx=longer), m(x))
        other = m(x, fps_idx=torch.arange(N // 2).expand(2, -1))  # a different sampling changes features
    assert _rel(other, m(x)) > 1e-3
    with pytest.raises(ValueError, match="fps_idx must be"):
        m(x, fps_idx=fps[:, :10])
    with pytest.raises(ValueError, match="fps_idx must be long"):
        m(x, fps_idx=fps + N)


def test_ico13_fast_path_matches_general_path():
    fast = _model("ico13", torch.float64)
    slow = _model("ico13", torch.float64, use_fast_path=False)
    slow.load_state_dict(fast.state_dict())
    assert fast.blocks[0].fast and not slow.blocks[0].fast
    x = _cloud(torch.float64)
    a, b = fast(x), slow(x)
    assert float((a - b).detach().abs().max()) < 1e-12
    ga = torch.autograd.grad(a.square().sum(), fast.blocks[1].spatial_weight)[0]
    gb = torch.autograd.grad(b.square().sum(), slow.blocks[1].spatial_weight)[0]
    assert torch.allclose(ga, gb, atol=1e-10, rtol=1e-10)


def test_closed_aggregate_matches_general_aggregate():
    g = torch.Generator().manual_seed(4)
    rel = torch.randn(2, 5, 7, 3, generator=g, dtype=torch.float64) * 0.3
    mask = torch.rand(2, 5, 7, generator=g) > 0.3
    nb = torch.randn(2, 5, 7, 60, 3, generator=g, dtype=torch.float64)
    for kind in ("ico13", "ico33"):
        k = kernel_points(kind, 0.35, torch.float64)
        general = spatial_aggregate(rel, mask, nb, rotated_kernel_points(kind, 0.35, torch.float64), 0.1)
        closed = spatial_aggregate_closed(rel, mask, nb, k, kernel_permutation(kind), 0.1)
        assert general.abs().max() > 0.1
        assert torch.allclose(general, closed, atol=1e-13)
    # masked neighbours contribute nothing
    nb2 = nb.clone()
    nb2[~mask] = 1e6
    k = rotated_kernel_points("paper24", 0.35, torch.float64)
    assert torch.allclose(spatial_aggregate(rel, mask, nb2, k, 0.1), spatial_aggregate(rel, mask, nb, k, 0.1))


def test_checkpoint_and_chunking_match_plain_gradients():
    x = _cloud(torch.float32)
    plain = _model("paper24", torch.float32).train()
    other = _model("paper24", torch.float32, checkpoint=True, chunk_elems=300_000).train()
    other.load_state_dict(plain.state_dict())
    a, b = plain(x), other(x)
    assert torch.allclose(a, b, atol=1e-5)
    a.square().mean().backward()
    b.square().mean().backward()
    for (name, p), q in zip(plain.named_parameters(), other.parameters()):
        assert p.grad is not None and torch.isfinite(p.grad).all(), name
        assert torch.allclose(p.grad, q.grad, atol=1e-5, rtol=1e-4), name


def test_parameter_count_paper_width():
    m24 = EquivariantBackbone()
    m13 = EquivariantBackbone(kernel="ico13")

    # per block: J*Cin*Cout (spatial) + 13*Cout^2 (group) + Cin*Cout + Cout (shortcut)
    def count(j):
        dims = [(1, 32), (32, 32), (32, 64), (64, 64)]
        return sum(j * ci * co + 13 * co * co + ci * co + co for ci, co in dims)

    assert sum(p.numel() for p in m24.parameters()) == count(24) == 313_312
    assert sum(p.numel() for p in m13.parameters()) == count(13)
    assert m24.out_channels == 64
    assert m24.point_counts(5000) == [2500, 2500, 1250, 1250]


def test_no_stride_and_block_shapes():
    m = EquivariantBackbone(channels=(3, 5), strides=(1, 1), radii=(0.4, 0.4), neighbours=(8, 8))
    x = _cloud(torch.float32, n=50)
    assert m(x).shape == (2, 50, 60, 5)
    blk = SeparableConvBlock(2, 3, radius=0.4, n_neighbours=8)
    xyz, f = blk(x, torch.randn(2, 50, 60, 2), torch.arange(10).expand(2, 10))
    assert xyz.shape == (2, 10, 3) and f.shape == (2, 10, 60, 3)
    with pytest.raises(ValueError, match="feats must be"):
        blk(x, torch.randn(2, 50, 60, 3))


def test_bad_input():
    m = _model("ico13", torch.float32)
    with pytest.raises(ValueError, match=r"points must have shape \[B, N, 3\]"):
        m(torch.rand(10, 3))
    with pytest.raises(ValueError, match="NaN"):
        x = _cloud(torch.float32)
        x[0, 3, 1] = float("nan")
        m(x)
    with pytest.raises(ValueError, match="too few"):
        m(torch.rand(1, 3, 3))
    with pytest.raises(ValueError, match="radii has 2 entries"):
        EquivariantBackbone(channels=(4, 4, 4), strides=(1, 1, 1), radii=(0.1, 0.1), neighbours=(4, 4, 4))


@pytest.mark.slow
@pytest.mark.parametrize("kernel", ["paper24", "ico13"])
def test_all_sixty_elements(kernel):
    m = _model(kernel, torch.float32)
    x = _cloud(torch.float32)
    r = group_rotations(torch.float32)
    with torch.no_grad():
        out = m(x)
        errs = [_rel(m(x @ r[j].T), rotate_group_features(out, j)) for j in range(60)]
    assert max(errs) < 1e-4, max(errs)


@pytest.mark.slow
@pytest.mark.parametrize("kernel", ["paper24", "ico13"])
def test_measure_continuous_rotation_drift(kernel):
    """MEASURES (does not assert a bound on) the drift of the group-mean feature for Haar-random rotations."""
    import roma

    m = _model(kernel, torch.float64)
    x = _cloud(torch.float64, b=1, n=400)
    torch.manual_seed(3)
    with torch.no_grad():
        ref = m(x).mean(2)
        drift = []
        for q in roma.random_rotmat(8, dtype=torch.float64):
            inv = m(x @ q.T).mean(2)
            drift.append(float((inv - ref).norm() / ref.norm()))
    print(
        f"\n[{kernel}] group-mean feature drift under random SO(3) rotations: "
        f"mean {sum(drift) / len(drift):.3f}, max {max(drift):.3f}"
    )
    assert all(d == d for d in drift)  # finite numbers were produced
