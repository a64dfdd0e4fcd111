"""Articulated equivariance: part-local backbone features, a parent conditioning that survives a turn of
the child, and the probe that measures both (arteq.models.articulation)."""

from __future__ import annotations

import pytest
import torch

from arteq.body.skeleton import JOINT_NAMES, PARENTS
from arteq.equivariant import (
    EquivariantBackbone,
    SeparableConvBlock,
    element_orders,
    group_rotations,
    rotate_group_features,
)
from arteq.geometry.pointops import ball_query
from arteq.models.articulation import articulated_equivariance, default_net_config, subtree, turn_subtree
from arteq.models.heads import PoseHead, parent_mode
from arteq.models.registry import build_net


def _cloud(n=150, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(1, n, 3, generator=g, dtype=torch.float64) - 0.5) * 0.6


def test_duplicated_points_leave_normalised_features_unchanged():
    # Every point twice: the count-normalised neighbour mean sees each neighbourhood's points twice over
    # (the same mean), instance norm the same statistics, so the backbone's features do not move.
    torch.manual_seed(0)
    net = EquivariantBackbone(
        channels=(4, 6), strides=(1, 1), radii=(0.15, 0.2), neighbours=(400, 400), kernel="ico13",
        normalize=True,
    ).double().eval()  # fmt: skip
    x = _cloud()
    with torch.no_grad():
        a = net(x)
        b = net(torch.cat([x, x], 1))
    assert float((b[:, : x.shape[1]] - a).abs().max() / a.abs().max()) < 1e-10
    assert float((b[:, x.shape[1] :] - a).abs().max() / a.abs().max()) < 1e-10


@pytest.mark.parametrize("normalize", [True, False])
def test_neighbour_mean_does_not_follow_local_density(normalize):
    # One cluster of the cloud sampled twice as densely (its points duplicated), another left alone: a
    # centre inside the dense cluster gets the same spatial response with the neighbour mean, twice it
    # with the plain masked sum (the scale that made small balls unusable at 500 points).
    torch.manual_seed(0)
    blk = SeparableConvBlock(
        3, 4, radius=0.12, n_neighbours=128, kernel="ico13", normalize=normalize
    ).double()
    g = torch.Generator().manual_seed(1)
    a = (torch.rand(30, 3, generator=g, dtype=torch.float64) - 0.5) * 0.1
    far = a + 2.0
    xyz = torch.cat([a, far])[None]
    feats = torch.randn(1, 60, 60, 3, generator=g, dtype=torch.float64)
    xyz2 = torch.cat([xyz, xyz[:, :30]], 1)
    feats2 = torch.cat([feats, feats[:, :30]], 1)
    centres = xyz[:, :5]
    outs = []
    for p, f in ((xyz, feats), (xyz2, feats2)):
        idx, mask = ball_query(centres, p, blk.radius, blk.n_neighbours)
        outs.append(blk._spatial_chunk(p, f, centres, idx, mask))
    ratio = float(outs[1].norm() / outs[0].norm())
    assert ratio == pytest.approx(1.0 if normalize else 2.0, abs=1e-9)


def test_normalize_default_is_the_old_plain_sum():
    # networks saved before the option exist: the constructor default must build them unchanged
    net = EquivariantBackbone(channels=(4,), strides=(1,), radii=(0.2,), neighbours=(8,))
    assert not net.normalize and not net.blocks[0].normalize


def test_parent_modes():
    assert parent_mode(True) == "aligned" and parent_mode(False) == "none"
    assert parent_mode("invariant") == "invariant"
    with pytest.raises(ValueError, match="parent_conditioning must be one of"):
        parent_mode("sideways")


@pytest.mark.parametrize("mode", ["invariant", "aligned"])
def test_child_prediction_under_a_turn_relative_to_its_parent(mode):
    # Turn only the left forearm's subtree (its tokens permuted by g, the parent's left alone): with the
    # invariant parent feature the forearm's rotation turns by exactly g; the aligned form sees token
    # pairs it was never given and does not.
    torch.manual_seed(0)
    head = PoseHead(8, group_rotations(torch.float64), PARENTS, dim=16, heads=4, parent_conditioning=mode)
    head = head.double()
    torch.nn.init.normal_(head.part_embedding)
    feats = torch.randn(1, 22, 60, 8, dtype=torch.float64)
    g = int(torch.nonzero(element_orders() == 5)[0])
    moved = feats.clone()
    sub = subtree(JOINT_NAMES.index("left_elbow"))
    moved[:, sub] = rotate_group_features(feats[:, sub], g, dim=2)
    r = group_rotations(torch.float64)[g]
    before, after = head(feats)["rotmats"][0], head(moved)["rotmats"][0]
    k = JOINT_NAMES.index("left_elbow")
    err = float((after[k] - r @ before[k]).abs().max())
    if mode == "invariant":
        assert err < 1e-9
        # the parent (upper arm) did not move and its prediction does not either
        p = PARENTS[k]
        assert float((after[p] - before[p]).abs().max()) < 1e-9
    else:
        assert err > 1e-3


def test_turn_subtree_moves_exactly_the_subtree(toy_body):
    torch.manual_seed(0)
    pose = torch.eye(3, dtype=torch.float64).repeat(22, 1, 1)
    out = toy_body(pose=pose[None].float())
    k = JOINT_NAMES.index("left_knee")
    r = group_rotations(torch.float64)[int(torch.nonzero(element_orders() == 5)[0])]
    turned = turn_subtree(pose, out.global_rotmats[0].double(), k, r)
    out2 = toy_body(pose=turned[None].float())
    j1, j2 = out.joints[0].double(), out2.joints[0].double()
    sub = subtree(k)
    for q in range(22):
        expect = (j1[q] - j1[k]) @ r.T + j1[k] if q in sub else j1[q]
        torch.testing.assert_close(j2[q], expect, atol=1e-5, rtol=0)
    g2 = out2.global_rotmats[0].double()
    torch.testing.assert_close(g2[sub], r @ out.global_rotmats[0].double()[sub], atol=1e-5, rtol=0)


def test_local_network_is_far_more_part_equivariant_than_the_default(anny22):
    # The property the method is named after, at initialisation (same seed): the moved part's pooled
    # feature against its group-rotated original. The default configuration (radii scaled to 0.25-0.51 m
    # at 500 points, plain sums, 125 deep centres) scores ~0.77; see benchmarks/bench_articulation.py.
    res = {}
    for name in ("arteq_local", "arteq"):
        torch.manual_seed(0)
        net = build_net(default_net_config(500, name))
        res[name] = articulated_equivariance(
            net, anny22, joints=("left_elbow", "left_knee"), num_poses=1, elements_per_joint=2
        ).mean
    assert res["arteq_local"]["feat_moved"] < 0.7 * res["arteq"]["feat_moved"], res
    assert res["arteq_local"]["feat_far"] < 0.5 * res["arteq"]["feat_far"], res
    local = default_net_config(500, "arteq_local")
    assert local["backbone"]["normalize"] and local["parent_conditioning"] == "invariant"


def test_weights_of_another_radius_keep_this_networks_kernel_points(caplog):
    # Old checkpoints hold kernel points scaled to their (much larger) radii as persistent buffers:
    # loading them into a network with other radii must not carry those points over.
    torch.manual_seed(0)
    old = EquivariantBackbone(
        channels=(4, 4), strides=(2, 1), radii=(0.25, 0.36), neighbours=(8, 8), kernel="ico13"
    )
    new = EquivariantBackbone(
        channels=(4, 4), strides=(2, 1), radii=(0.08, 0.11), neighbours=(8, 8), kernel="ico13"
    )
    own = new.blocks[0].kernels.clone()
    with caplog.at_level("WARNING"):
        new.load_state_dict(old.state_dict())
    torch.testing.assert_close(new.blocks[0].kernels, own)
    torch.testing.assert_close(new.blocks[0].spatial_weight, old.blocks[0].spatial_weight)
    assert "belong to another ball radius" in caplog.text


@pytest.mark.parametrize("spread", [0.0, 1e-5])
def test_pose_head_gradients_stay_bounded_when_a_parts_tokens_are_alike(spread):
    # An empty part pools to zeros (spread 0); local features of a part with one or two points per ball are
    # nearly alike over the group (spread 1e-5). With the invariant parent feature nothing else tells the
    # 60 tokens apart. The bounded standardisation (logit_eps) keeps the gradients small; the bare standard
    # deviation amplified the rounding noise (max gradient 1.7e4 here at spread 1e-5; 3e2-4e5 per step at
    # initialisation in training, so clipping scaled every other gradient to nothing and nothing learned).
    grads = {}
    for eps in (None, 1e-4):
        torch.manual_seed(0)
        head = PoseHead(8, group_rotations(torch.float64), PARENTS, dim=16, heads=4,
                        parent_conditioning="invariant", logit_eps=eps)  # fmt: skip
        feats = torch.randn(2, 22, 60, 8)
        feats[:, JOINT_NAMES.index("left_foot")] = spread * torch.randn(2, 60, 8)
        feats.requires_grad_(True)
        out = head(feats)
        if eps is not None and spread == 0:  # nothing to choose from: uniform weights
            w = out["weights"][:, JOINT_NAMES.index("left_foot")]
            torch.testing.assert_close(w, torch.full_like(w, 1 / 60))
        out["mean"].square().sum().backward()
        g = [p.grad for p in head.parameters() if p.grad is not None] + [feats.grad]
        assert all(torch.isfinite(x).all() for x in g) or eps is None
        grads[eps] = max(float(x.abs().nan_to_num(float("inf")).max()) for x in g)
    assert grads[1e-4] < 1e3
    if spread > 0:
        assert grads[None] > 10 * grads[1e-4]
    with pytest.raises(ValueError, match="logit_eps"):
        PoseHead(8, group_rotations(torch.float64), PARENTS, logit_eps=0.0)


def _labelled_cloud(seed=0):
    g = torch.Generator().manual_seed(seed)
    pts = torch.randn(2, 220, 3, generator=g, dtype=torch.float64) * torch.tensor([0.3, 0.1, 0.05])
    labels = torch.arange(220).remainder(22).expand(2, -1)
    return pts, torch.nn.functional.one_hot(labels, 22).double()


def test_part_geometry_tokens_follow_a_rotation_of_the_part_and_nothing_else():
    # Rotating only part k's points by a group element permutes part k's tokens exactly as the backbone's
    # features are permuted; every other part's tokens and a translation of the whole cloud leave them be.
    from arteq.models.heads import part_geometry

    pts, w = _labelled_cloud()
    rots = group_rotations(torch.float64)
    geo = part_geometry(pts, w, rots)
    assert geo.shape == (2, 22, 60, 16) and torch.isfinite(geo).all()
    g = int(torch.nonzero(element_orders() == 5)[0])
    k = JOINT_NAMES.index("left_elbow")
    mask = w[..., k].bool()
    moved = pts.clone()
    pivot = torch.tensor([0.2, -0.1, 0.3], dtype=torch.float64)
    moved[mask] = (pts[mask] - pivot) @ rots[g].T + pivot  # turned about some joint
    geo2 = part_geometry(moved + torch.tensor([1.0, 2.0, -3.0], dtype=torch.float64), w, rots)
    torch.testing.assert_close(geo2[:, k], rotate_group_features(geo[:, k], g, dim=1), atol=1e-10, rtol=0)
    others = [q for q in range(22) if q != k]
    torch.testing.assert_close(geo2[:, others], geo[:, others], atol=1e-10, rtol=0)
    # a part with no points gets finite zeros
    w0 = w.clone()
    w0[..., 3] = 0
    assert part_geometry(pts, w0, rots)[:, 3].abs().max() == 0


def test_geometry_head_predicts_the_turned_part_exactly():
    # End to end with ground-truth pooling, a head reading only part geometry (+ invariant parent) turns the
    # moved part's prediction by exactly g: articulated equivariance of the pose head by construction.
    from arteq.models.heads import part_geometry

    torch.manual_seed(0)
    head = PoseHead(4, group_rotations(torch.float64), PARENTS, dim=16, heads=4,
                    parent_conditioning="invariant", logit_eps=1e-4, geometry=True).double()  # fmt: skip
    torch.nn.init.normal_(head.part_embedding)
    pts, w = _labelled_cloud(1)
    rots = group_rotations(torch.float64)
    feats = torch.zeros(2, 22, 60, 4, dtype=torch.float64)  # invariant (constant) backbone features
    g = int(torch.nonzero(element_orders() == 5)[1])
    k = JOINT_NAMES.index("right_knee")
    moved = pts.clone()
    moved[w[..., k].bool()] = pts[w[..., k].bool()] @ rots[g].T
    before = head(feats, part_geometry(pts, w, rots))["rotmats"]
    after = head(feats, part_geometry(moved, w, rots))["rotmats"]
    torch.testing.assert_close(after[:, k], rots[g] @ before[:, k], atol=1e-8, rtol=0)
    with pytest.raises(ValueError, match="part_geometry"):
        head(feats)


@pytest.mark.parametrize("pooling", ["predicted", "ground truth"])
def test_network_with_part_geometry_stays_equivariant(pooling):
    # The whole network with geometry tokens: rotating the cloud by a group element rotates every part's
    # prediction by that element (float64: to rounding), with predicted and with ground-truth pooling.
    torch.manual_seed(0)
    net = build_net({
        "backbone": {"channels": [4, 4], "strides": [2, 1], "radii": [0.3, 0.4], "neighbours": [8, 8],
                     "kernel": "ico13", "normalize": True},
        "segmenter": {"hidden": 16}, "parent_conditioning": "invariant",
        "pose_head": {"dim": 16, "heads": 4, "mlp_hidden": 16, "logit_eps": 1e-4, "geometry": True},
        "shape_head": {"dim": 16, "heads": 4, "mlp_hidden": 16},
    }).double().eval()  # fmt: skip
    pts = _cloud(120)
    labels = torch.arange(120).remainder(22)[None] if pooling == "ground truth" else None
    g = int(torch.nonzero(element_orders() == 3)[0])
    r = group_rotations(torch.float64)[g]
    with torch.no_grad():
        out, out_rot = net(pts, labels), net(pts @ r.T, labels)
    torch.testing.assert_close(out_rot["global_rotmats"], r @ out["global_rotmats"], atol=1e-7, rtol=0)
    assert net.pose_head.geometry
