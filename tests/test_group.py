"""The icosahedral group tables, neighbourhoods and kernel points."""

from __future__ import annotations

import math

import pytest
import torch

from arteq.equivariant import group as G


def test_rotations_orthonormal_det_one_identity_first():
    r = G.group_rotations(torch.float64)
    assert r.shape == (60, 3, 3)
    eye = torch.eye(3, dtype=torch.float64)
    assert torch.allclose(r[0], eye, atol=1e-15)
    assert torch.allclose(r @ r.transpose(1, 2), eye.expand(60, 3, 3), atol=1e-13)
    assert torch.allclose(torch.linalg.det(r), torch.ones(60, dtype=torch.float64), atol=1e-13)
    # all distinct
    d = (r[:, None] - r[None]).abs().flatten(2).amax(-1) + torch.eye(60, dtype=torch.float64)
    assert float(d.min()) > 0.1


def test_cayley_is_latin_square_and_matches_products():
    r = G.group_rotations(torch.float64)
    c = G.cayley_table()
    ar = torch.arange(60)
    assert torch.equal(c.sort(0).values, ar[:, None].expand(60, 60))
    assert torch.equal(c.sort(1).values, ar[None].expand(60, 60))
    assert torch.equal(c[0], ar) and torch.equal(c[:, 0], ar)
    prod = r[:, None] @ r[None]
    assert torch.allclose(prod, r[c], atol=1e-13)
    # associativity spot check
    i, j, k = 7, 23, 41
    assert c[c[i, j], k] == c[i, c[j, k]]


def test_inverse_table():
    r = G.group_rotations(torch.float64)
    inv = G.inverse_table()
    c = G.cayley_table()
    assert torch.all(c[torch.arange(60), inv] == 0)
    assert torch.allclose(r[inv], r.transpose(1, 2), atol=1e-13)


def test_element_order_census_and_angles():
    orders = G.element_orders()
    counts = {o: int((orders == o).sum()) for o in (1, 2, 3, 5)}
    assert counts == {1: 1, 2: 15, 3: 20, 5: 24}
    ang = G.rotation_angles()
    deg = torch.round(torch.rad2deg(ang)).long()
    assert sorted(set(deg.tolist())) == [0, 72, 120, 144, 180]
    assert int((deg == 72).sum()) == 12 and int((deg == 144).sum()) == 12


def test_left_permutations_are_left_multiplication():
    r = G.group_rotations(torch.float64)
    p = G.left_permutations()
    for g in (3, 17, 59):
        assert torch.allclose(r[g] @ r, r[p[g]], atol=1e-13)


def test_neighbourhood_commutes_with_left_multiplication():
    h = G.group_neighbourhood()
    idx = G.group_conv_index()
    c = G.cayley_table()
    assert h[0] == 0 and h.numel() == 13 and idx.shape == (60, 13)
    ang = G.rotation_angles()[h[1:]]
    assert torch.allclose(ang, torch.full_like(ang, 2 * math.pi / 5))
    assert torch.equal(idx, c[:, h])
    for j in range(60):
        assert torch.equal(idx[c[j]], c[j][idx])  # idx[j g, k] == j idx[g, k]


def test_rotate_group_features_is_a_left_action():
    x = torch.randn(2, 5, 60, 3)
    c = G.cayley_table()
    i, j = 11, 37
    a = G.rotate_group_features(G.rotate_group_features(x, j), i)
    b = G.rotate_group_features(x, int(c[i, j]))
    assert torch.equal(a, b)
    # the value at b moves to cayley[j, b]
    y = G.rotate_group_features(x, j)
    assert torch.equal(y[:, :, c[j]], x)
    with pytest.raises(ValueError, match="size 7"):
        G.rotate_group_features(torch.zeros(7, 3), 1, dim=0)


@pytest.mark.parametrize("kind,n", [("paper24", 24), ("ico13", 13), ("ico33", 33)])
def test_kernel_points(kind, n):
    k = G.kernel_points(kind, radius=0.5, dtype=torch.float64)
    assert k.shape == (n, 3)
    assert torch.allclose(k[0], torch.zeros(3, dtype=torch.float64))
    assert torch.allclose(k[1:].norm(dim=-1), torch.full((n - 1,), 0.5, dtype=torch.float64))
    # well spread: no two sphere points closer than a third of the radius
    d = torch.cdist(k[1:], k[1:]) + torch.eye(n - 1, dtype=torch.float64)
    assert float(d.min()) > 0.5 / 3
    rk = G.rotated_kernel_points(kind, 0.5, torch.float64)
    assert torch.allclose(rk, torch.einsum("aij,nj->ani", G.group_rotations(torch.float64), k))
    perm = G.kernel_permutation(kind)
    if kind == "paper24":
        assert perm is None
    else:
        assert perm.shape == (60, n)
        assert torch.equal(perm.sort(1).values, torch.arange(n).expand(60, n))
        assert torch.allclose(rk, k[perm], atol=1e-13)


def test_kernel_points_bad_input():
    with pytest.raises(ValueError, match="unknown kind"):
        G.kernel_points("cube8")
    with pytest.raises(ValueError, match="radius"):
        G.kernel_points("ico13", radius=0.0)
