"""PointNet2Regressor: the output contract of ArtEqNet, rotations, pooling and bad input."""

import pytest
import torch

from arteq.body.skeleton import global_to_local
from arteq.models.baselines import PointNet2Regressor


@pytest.fixture(scope="module")
def net(tiny_pn2_net):
    torch.manual_seed(0)
    return PointNet2Regressor(num_betas=7, **tiny_pn2_net)


def test_output_contract(net):
    b, n = 2, 150
    pts = torch.randn(b, n, 3) * 0.4
    out = net(pts)
    assert net.num_parts == 22
    assert out["seg_logits"].shape == (b, n, 22)
    assert torch.allclose(out["part_probs"].sum(-1), torch.ones(b, n), atol=1e-5)
    assert torch.equal(out["pool_weights"], out["part_probs"])
    for key in ("global_rotmats", "rot_mean", "local_rotmats"):
        assert out[key].shape == (b, 22, 3, 3)
    assert out["betas"].shape == (b, 7)
    r = out["global_rotmats"]
    eye = torch.eye(3).expand_as(r)
    assert torch.allclose(r.transpose(-1, -2) @ r, eye, atol=1e-5)
    assert torch.allclose(torch.linalg.det(r), torch.ones(b, 22), atol=1e-5)
    assert torch.allclose(out["local_rotmats"], global_to_local(r), atol=1e-6)


def test_gt_labels_are_pooling_weights_and_change_the_pose(net):
    pts = torch.randn(1, 120, 3) * 0.4
    labels = torch.randint(0, 22, (1, 120))
    with torch.no_grad():
        net.rot_head[-1].weight.normal_(0, 0.1)  # leave the identity start so poses depend on features
        a, b = net(pts, gt_labels=labels), net(pts)
    assert torch.equal(a["pool_weights"], torch.nn.functional.one_hot(labels, 22).float())
    assert not torch.allclose(a["global_rotmats"], b["global_rotmats"])


def test_fewer_points_than_centres_and_gradients(tiny_pn2_net):
    net = PointNet2Regressor(num_betas=3, **tiny_pn2_net)
    pts = (torch.randn(1, 10, 3) * 0.3).requires_grad_(True)
    out = net(pts)
    (out["global_rotmats"].sum() + out["betas"].sum() + out["seg_logits"].sum()).backward()
    assert all(p.grad is not None for p in net.rot_head.parameters())
    assert torch.isfinite(pts.grad).all()


def test_translation_invariant_not_rotation_invariant(net):
    torch.manual_seed(1)
    pts = torch.randn(1, 100, 3) * 0.4
    with torch.no_grad():
        a = net(pts)["seg_logits"]
        b = net(pts + torch.tensor([1.0, -2.0, 0.5]))["seg_logits"]
        rot = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        c = net(pts @ rot.T)["seg_logits"]
    assert torch.allclose(a, b, atol=1e-4)
    assert not torch.allclose(a, c, atol=1e-3)  # the baseline is not equivariant: that is its point


def test_bad_input(net):
    with pytest.raises(ValueError, match=r"\[B, N, 3\]"):
        net(torch.zeros(2, 10))
    with pytest.raises(ValueError, match="empty"):
        net(torch.zeros(1, 0, 3))
    with pytest.raises(ValueError, match="NaN"):
        net(torch.full((1, 5, 3), float("nan")))
    with pytest.raises(ValueError, match="one entry per level"):
        PointNet2Regressor(npoints=(32,), radii=(0.1, 0.2))
