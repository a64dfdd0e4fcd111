"""Point ops against brute-force references."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from arteq.geometry.pointops import (
    ball_query,
    centroid_nearest_index,
    farthest_point_sample,
    gather,
    knn,
    three_nn_interpolate,
)


def _fps_reference(x: np.ndarray, m: int, start: int) -> list[int]:
    idx = [start]
    mind = np.full(len(x), np.inf)
    for _ in range(m - 1):
        mind = np.minimum(mind, ((x - x[idx[-1]]) ** 2).sum(-1))
        idx.append(int(mind.argmax()))
    return idx


def test_fps_matches_simple_loop_and_is_prefix_consistent():
    g = torch.Generator().manual_seed(0)
    x = torch.rand(3, 400, 3, generator=g)
    starts = torch.tensor([0, 5, 399])
    idx = farthest_point_sample(x, 100, start=starts)
    assert idx.shape == (3, 100) and idx.dtype == torch.long
    for b in range(3):
        assert idx[b].tolist() == _fps_reference(x[b].double().numpy(), 100, int(starts[b]))
        assert idx[b].unique().numel() == 100
    # prefix of a longer run, and FPS of the sampled subset reproduces the prefix
    short = farthest_point_sample(x, 40, start=starts)
    assert torch.equal(short, idx[:, :40])
    sub = gather(x, idx)
    again = farthest_point_sample(sub, 40, start=0)
    assert torch.equal(gather(idx[..., None], again)[..., 0], idx[:, :40])


def test_fps_torch_loop_matches_numpy_loop():
    from arteq.geometry.pointops import _fps_torch

    x = torch.rand(2, 300, 3, dtype=torch.float64)
    start = torch.tensor([3, 7])
    assert torch.equal(_fps_torch(x, start, 60), farthest_point_sample(x, 60, start=start))


def test_fps_float32_input_uses_float64():
    x = torch.rand(1, 300, 3, dtype=torch.float64)
    assert torch.equal(farthest_point_sample(x.float(), 50), farthest_point_sample(x.float().double(), 50))


@pytest.mark.parametrize("backend", ["torch", "scipy", "auto"])
def test_knn_matches_full_sort(backend):
    g = torch.Generator().manual_seed(1)
    q, r = torch.rand(2, 300, 3, generator=g), torch.rand(2, 500, 3, generator=g)
    d, idx = knn(q, r, 9, backend=backend)
    full = ((q.double()[:, :, None] - r.double()[:, None]) ** 2).sum(-1)
    ref_d, ref_i = full.sort(-1)
    assert torch.equal(idx, ref_i[..., :9])
    assert torch.allclose(d, ref_d[..., :9], rtol=0, atol=1e-15)
    assert d.dtype == torch.float64


def test_knn_chunked_path(monkeypatch):
    import arteq.geometry.pointops as po

    monkeypatch.setattr(po, "_CHUNK_ELEMS", 1000)  # forces ~4-query chunks
    q, r = torch.rand(2, 50, 3), torch.rand(2, 256, 3)
    assert torch.equal(knn(q, r, 5, backend="torch")[1], knn(q, r, 5, backend="scipy")[1])


def test_ball_query_semantics():
    g = torch.Generator().manual_seed(2)
    r = torch.rand(2, 400, 3, generator=g)
    q = r[:, :50]
    radius, k = 0.15, 16
    idx, mask = ball_query(q, r, radius, k)
    assert idx.shape == mask.shape == (2, 50, k)
    d = ((q.double()[:, :, None] - r.double()[:, None]) ** 2).sum(-1)
    inside = d <= radius**2
    for b in range(2):
        for m in range(50):
            ids = set(torch.nonzero(inside[b, m])[:, 0].tolist())
            got = idx[b, m][mask[b, m]].tolist()
            assert len(got) == len(set(got)) == min(k, len(ids))
            assert set(got) <= ids
            if len(ids) > k:  # the k nearest of those inside
                assert set(got) == set(d[b, m].topk(k, largest=False).indices.tolist())
            assert torch.all(idx[b, m][~mask[b, m]] == idx[b, m, 0])
            assert bool(mask[b, m, 0])  # the query itself is a reference point
    # k larger than N: padded with slot 0 and masked
    idx2, mask2 = ball_query(q[:, :3], r[:, :10], 10.0, 12)
    assert idx2.shape == (2, 3, 12) and mask2[..., :10].all() and not mask2[..., 10:].any()
    assert torch.equal(idx2[..., 10:], idx2[..., :1].expand(2, 3, 2))
    # nothing inside
    idx3, mask3 = ball_query(r[:, :2] + 10.0, r, 0.1, 4)
    assert not mask3.any()


def test_gather_shapes_and_values():
    x = torch.randn(2, 10, 4, 3, requires_grad=True)
    idx = torch.randint(0, 10, (2, 5, 7))
    out = gather(x, idx)
    assert out.shape == (2, 5, 7, 4, 3)
    assert torch.equal(out[1, 2, 3], x[1, idx[1, 2, 3]])
    out.sum().backward()
    assert x.grad is not None
    with pytest.raises(ValueError, match="gather"):
        gather(x, torch.zeros(3, 2, dtype=torch.long))


def test_three_nn_interpolate_matches_loop():
    g = torch.Generator().manual_seed(3)
    q, r = torch.rand(2, 40, 3, generator=g), torch.rand(2, 30, 3, generator=g)
    f = torch.randn(2, 30, 60, 4, generator=g, dtype=torch.float64)
    out = three_nn_interpolate(q, r, f)
    assert out.shape == (2, 40, 60, 4)
    for b in range(2):
        for m in range(40):
            d = ((q[b, m].double() - r[b].double()) ** 2).sum(-1)
            dv, iv = d.topk(3, largest=False)
            w = 1 / (dv + 1e-8)
            w = w / w.sum()
            ref = (f[b, iv] * w[:, None, None]).sum(0)
            assert torch.allclose(out[b, m], ref, atol=1e-12)
    # reproduces features at reference points, constants exactly
    at_ref = three_nn_interpolate(r, r, f)
    assert torch.allclose(at_ref, f, atol=1e-4)  # eps = 1e-8 vs d^2 ~ 1e-2 to the other two
    ones = three_nn_interpolate(q, r, torch.ones(2, 30, 5, dtype=torch.float64))
    assert torch.allclose(ones, torch.ones_like(ones), atol=1e-14)
    # fewer than 3 reference points
    assert three_nn_interpolate(q, r[:, :2], f[:, :2]).shape == (2, 40, 60, 4)


def test_centroid_nearest_index_invariant_to_rotation_and_order():
    x = torch.randn(1, 200, 3, dtype=torch.float64)
    i = int(centroid_nearest_index(x))
    perm = torch.randperm(200)
    assert int(perm[centroid_nearest_index(x[:, perm])]) == i
    q = torch.linalg.qr(torch.randn(3, 3, dtype=torch.float64)).Q
    assert int(centroid_nearest_index(x @ q.T + 3.0)) == i


def test_bad_inputs_are_named():
    x = torch.rand(1, 20, 3)
    with pytest.raises(ValueError, match=r"xyz must have shape \[B, N, 3\]"):
        farthest_point_sample(torch.rand(20, 3), 5)
    with pytest.raises(ValueError, match="m must be"):
        farthest_point_sample(x, 21)
    with pytest.raises(ValueError, match="NaN"):
        knn(x, torch.full((1, 5, 3), float("nan")), 2)
    with pytest.raises(ValueError, match="empty"):
        knn(x, torch.rand(1, 0, 3), 1)
    with pytest.raises(ValueError, match="k must be"):
        knn(x, x, 21)
    with pytest.raises(ValueError, match="batch sizes differ"):
        knn(x, torch.rand(2, 20, 3), 2)
    with pytest.raises(ValueError, match="radius"):
        ball_query(x, x, -1.0, 4)
    with pytest.raises(ValueError, match="feats"):
        three_nn_interpolate(x, x, torch.rand(1, 19, 2))
