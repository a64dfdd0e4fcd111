"""ArtEq heads: pose-head equivariance, safe gradients, pooling, placement, metrics, losses."""

import math

import pytest
import roma
import torch

from arteq.body.skeleton import PARENTS, global_to_local, local_to_global
from arteq.equivariant import element_orders, group_rotations, rotate_group_features
from arteq.geometry.rotations import geodesic_deg
from arteq.models.heads import PartSegmenter, PoseHead, ShapeHead, pool_parts
from arteq.models.placement import estimate_translation, part_centroid_matrix, vertex_areas
from arteq.training.losses import arteq_losses
from arteq.training.metrics import BodyFitMetrics


def _elements(order: int, count: int = 2) -> list[int]:
    return [int(i) for i in torch.nonzero(element_orders() == order).flatten()[:count]]


@pytest.mark.parametrize("parent_conditioning", [True, False])
@pytest.mark.parametrize("element", _elements(3) + _elements(5))
def test_pose_head_is_equivariant(parent_conditioning, element):
    torch.manual_seed(0)
    head = PoseHead(
        8, group_rotations(torch.float64), PARENTS, dim=16, heads=4, parent_conditioning=parent_conditioning
    ).double()
    torch.nn.init.normal_(head.part_embedding)  # zero at init: make it matter
    feats = torch.randn(2, 22, 60, 8, dtype=torch.float64)
    out = head(feats)
    out_rot = head(rotate_group_features(feats, element, dim=2))
    r = group_rotations(torch.float64)[element]
    torch.testing.assert_close(out_rot["rotmats"], r @ out["rotmats"], atol=1e-9, rtol=0)
    torch.testing.assert_close(out_rot["mean"], r @ out["mean"], atol=1e-9, rtol=0)


def test_pose_head_outputs_rotations():
    head = PoseHead(8, group_rotations(torch.float64), PARENTS, dim=16, heads=4)
    out = head(torch.randn(3, 22, 60, 8))
    rot = out["rotmats"]
    eye = torch.eye(3).expand_as(rot)
    torch.testing.assert_close(rot.transpose(-1, -2) @ rot, eye, atol=1e-5, rtol=0)
    torch.testing.assert_close(torch.linalg.det(rot), torch.ones(3, 22), atol=1e-5, rtol=0)


def test_pose_head_gradients_finite_when_mean_is_zero():
    # Identical tokens -> uniform weights -> the weighted mean of the 60 group rotations is exactly 0,
    # the worst case for the SVD projection. Gradients must stay finite and bounded.
    head = PoseHead(8, group_rotations(torch.float64), PARENTS, dim=16, heads=4)
    feats = torch.ones(1, 22, 60, 8, requires_grad=True)
    out = head(feats)
    assert out["mean"].abs().max() < 1e-5
    target = roma.random_rotmat(22)[None]
    loss = (out["rotmats"] - target).square().mean()
    loss.backward()
    grads = [p.grad for p in head.parameters() if p.grad is not None] + [feats.grad]
    assert all(torch.isfinite(g).all() for g in grads)
    assert max(g.abs().max() for g in grads) < 1e4


def test_segmenter_and_shape_head_shapes_and_point_order():
    seg = PartSegmenter(8, hidden=16)
    x = torch.randn(2, 50, 8)
    perm = torch.randperm(50)
    torch.testing.assert_close(seg(x)[:, perm], seg(x[:, perm]), atol=1e-6, rtol=0)
    assert ShapeHead(8, num_betas=7)(torch.randn(2, 22, 8)).shape == (2, 7)


def test_pool_parts_is_a_weighted_mean():
    feats = torch.randn(2, 30, 60, 4)
    labels = torch.randint(0, 22, (2, 30))
    labels[:, :22] = torch.arange(22)
    onehot = torch.nn.functional.one_hot(labels, 22).float()
    pooled = pool_parts(feats, onehot)
    for k in (0, 5, 21):
        mask = labels[1] == k
        torch.testing.assert_close(pooled[1, k], feats[1, mask].mean(0), atol=1e-5, rtol=0)


def test_translation_recovers_shift_and_is_rotation_equivariant():
    torch.manual_seed(1)
    verts = torch.randn(200, 3)
    faces = torch.randint(0, 200, (300, 3))
    labels = torch.randint(0, 22, (200,))
    cm = part_centroid_matrix(vertex_areas(verts, faces), labels, 22)
    # A "cloud" made of the area-weighted part centroids themselves, one point per part.
    centroids = cm.T @ verts  # [22, 3]
    shift = torch.tensor([0.3, -1.0, 2.0])
    pts = (centroids + shift)[None]
    w = torch.eye(22)[None]
    t = estimate_translation(verts[None], cm, pts, w)
    torch.testing.assert_close(t[0], shift, atol=1e-5, rtol=0)
    r = roma.random_rotmat()
    t_rot = estimate_translation((verts @ r.T)[None], cm, pts @ r.T, w)
    torch.testing.assert_close(t_rot[0], shift @ r.T, atol=1e-5, rtol=0)


def test_global_local_roundtrip():
    g = roma.random_rotmat(4 * 22).reshape(4, 22, 3, 3)
    torch.testing.assert_close(local_to_global(global_to_local(g)), g, atol=1e-5, rtol=0)


def test_metrics_against_hand_computed_values():
    m = BodyFitMetrics()
    v = torch.zeros(2, 5, 3)
    j = torch.zeros(2, 22, 3)
    rot = torch.eye(3).expand(2, 22, 3, 3).clone()
    rot_pred = rot.clone()
    rot_pred[:, 3] = roma.rotvec_to_rotmat(torch.tensor([0.0, 0.0, math.pi / 2]))
    m.update(v + torch.tensor([0.01, 0, 0]), v, j + torch.tensor([0, 0.02, 0]), j, rot_pred, rot,
             torch.tensor([[1, 2, 3, 4]]), torch.tensor([[1, 2, 0, 0]]))  # fmt: skip
    out = m.compute()
    assert out["v2v_cm"].item() == pytest.approx(1.0)
    assert out["mpjpe_cm"].item() == pytest.approx(2.0)
    assert out["part_acc"].item() == pytest.approx(50.0)
    assert out["rot_err_deg_per_part"][3].item() == pytest.approx(90.0, abs=1e-4)
    assert out["rot_err_deg"].item() == pytest.approx(90.0 / 22, abs=1e-4)
    assert geodesic_deg(rot, rot).abs().max() < 1e-3


def test_losses_reject_unknown_terms_and_weight_terms():
    b = 2
    pred = {
        "local_rotmats": torch.eye(3).expand(b, 22, 3, 3), "rot_mean": torch.zeros(b, 22, 3, 3),
        "betas": torch.zeros(b, 10), "vertices": torch.zeros(b, 5, 3), "joints": torch.zeros(b, 22, 3),
        "seg_logits": torch.zeros(b, 7, 22),
    }  # fmt: skip
    gt = {
        "pose": torch.eye(3).expand(b, 22, 3, 3), "global_rotmats": torch.eye(3).expand(b, 22, 3, 3),
        "betas": torch.ones(b, 10), "vertices": torch.zeros(b, 5, 3), "joints": torch.zeros(b, 22, 3),
        "labels": torch.zeros(b, 7, dtype=torch.long),
    }  # fmt: skip
    out = arteq_losses(pred, gt, {"betas": 2.0, "global_rot": 1.0, "parts": 0.0}, torch.ones(5))
    assert out["betas"].item() == pytest.approx(1.0)
    assert out["global_rot"].item() == pytest.approx(3 / 9)
    assert "parts" not in out
    assert out["loss"].item() == pytest.approx(2.0 + 1 / 3)
    with pytest.raises(ValueError, match="unknown loss weight"):
        arteq_losses(pred, gt, {"vertex": 1.0}, torch.ones(5))


def test_group_targets_peak_at_the_nearest_element_and_the_cross_entropy_prefers_it():
    from arteq.training.losses import group_cross_entropy, group_targets

    rots = group_rotations(torch.float64)
    r = roma.random_rotmat(64, dtype=torch.float64)
    q = group_targets(r, rots)
    torch.testing.assert_close(q.sum(-1), torch.ones(64, dtype=torch.float64))
    nearest = geodesic_deg(r[:, None], rots[None]).argmin(-1)
    assert (q.argmax(-1) == nearest).all()
    # on a group element itself the target is (almost) one-hot
    assert group_targets(rots[7:8], rots)[0, 7] > 0.99
    # weights on the nearest element score better than uniform ones (which the chordal terms reward)
    confident = torch.nn.functional.one_hot(nearest, 60).double() * 0.9 + 0.1 / 60
    uniform = torch.full((64, 60), 1 / 60, dtype=torch.float64)
    assert group_cross_entropy(confident, r) < group_cross_entropy(uniform, r)


def test_group_ce_needs_a_pose_head():
    with pytest.raises(ValueError, match="group_ce"):
        arteq_losses({"betas": torch.zeros(1, 10)}, {"global_rotmats": torch.eye(3)[None]}, {"group_ce": 1.0},
                     torch.ones(3))  # fmt: skip


def test_group_self_attention_is_multihead_attention_with_its_keys():
    # written as plain batched products for speed: the same map as nn.MultiheadAttention with the same
    # parameters, and the same state-dict keys (older checkpoints load)
    from arteq.models.heads import GroupSelfAttention

    torch.manual_seed(0)
    m = GroupSelfAttention(16, 4).double()
    x = torch.randn(3, 60, 16, dtype=torch.float64, requires_grad=True)
    ref = x + m.attn(x, x, x, need_weights=False)[0]
    got = m(x)
    assert torch.allclose(got, ref, atol=1e-12)
    g_ref = torch.autograd.grad(ref.square().sum(), x)[0]
    g_got = torch.autograd.grad(got.square().sum(), x)[0]
    assert torch.allclose(g_got, g_ref, atol=1e-10)
    assert set(m.state_dict()) == {"attn.in_proj_weight", "attn.in_proj_bias", "attn.out_proj.weight",
                                   "attn.out_proj.bias"}  # fmt: skip
