"""Left and right from the torso's frame (model.net.sides = torso, arteq.models.sides)."""

from __future__ import annotations

import pytest
import roma
import torch

from arteq.body.skeleton import JOINT_NAMES
from arteq.equivariant import element_orders, group_rotations
from arteq.models.arteq_net import ArtEqNet
from arteq.models.heads import PoseHead
from arteq.models.sides import LEFT_AXIS, LEFT_PARTS, RIGHT_PARTS, TORSO_PARTS, resolve_sides, torso_frame

SMALL = {
    "backbone": {"channels": [4, 4], "strides": [2, 1], "radii": [0.3, 0.4], "neighbours": [8, 8],
                 "kernel": "ico13", "normalize": True},
    "segmenter": {"hidden": 16}, "parent_conditioning": "invariant",
    "pose_head": {"dim": 16, "heads": 4, "mlp_hidden": 16, "logit_eps": 1e-4, "geometry": True},
    "shape_head": {"dim": 16, "heads": 4, "mlp_hidden": 16},
}  # fmt: skip


def _cloud(n=120, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.rand(1, n, 3, generator=g, dtype=torch.float64) - 0.5) * 0.6


def test_mirror_pairs_and_torso_parts():
    assert len(LEFT_PARTS) == len(RIGHT_PARTS) == 8
    for left, right in zip(LEFT_PARTS, RIGHT_PARTS):
        assert JOINT_NAMES[left].replace("left_", "right_") == JOINT_NAMES[right]
    assert [JOINT_NAMES[k] for k in TORSO_PARTS] == ["pelvis", "spine1", "spine2", "spine3"]


@pytest.mark.parametrize("body", ["anny22", "toy_body"])
def test_left_axis_points_to_the_bodys_left_in_its_rest_pose(body, request):
    # Every body's left limbs lie on the +x side of its rest pose (SMPL's convention, followed by the
    # Anny bodies and the toy): the side rule depends on it.
    b = request.getfixturevalue(body)
    out = b(pose=torch.eye(3).repeat(1, 22, 1, 1))
    j = out.joints[0].double()
    axis = torch.tensor(LEFT_AXIS, dtype=j.dtype)
    for left, right in zip(LEFT_PARTS, RIGHT_PARTS):
        assert float((j[left] - j[right]) @ axis) > 0.02, (JOINT_NAMES[left], j[left], j[right])


def test_resolve_sides_splits_each_pair_by_the_lateral_coordinate():
    torch.manual_seed(0)
    logits = torch.randn(2, 50, 22, dtype=torch.float64)
    pts = torch.randn(2, 50, 3, dtype=torch.float64)
    rot = roma.random_rotmat(2, dtype=torch.float64)
    centre, left = torch.zeros(2, 3, dtype=torch.float64), rot @ torch.tensor(LEFT_AXIS, dtype=torch.float64)
    out = resolve_sides(logits, pts, centre, left, scale=0.02).exp()
    p = logits.softmax(-1)
    torch.testing.assert_close(out.sum(-1), torch.ones(2, 50, dtype=torch.float64))
    # side-free mass and the torso are kept
    torch.testing.assert_close(
        out[..., LEFT_PARTS] + out[..., RIGHT_PARTS], p[..., LEFT_PARTS] + p[..., RIGHT_PARTS]
    )
    torch.testing.assert_close(out[..., TORSO_PARTS], p[..., TORSO_PARTS])
    # a point well on the body's left is given the left part of its pair, one on the right the right part
    x = ((pts - centre[:, None]) * left[:, None]).sum(-1)
    far = x.abs() > 0.2
    pick_left = out[..., LEFT_PARTS] > out[..., RIGHT_PARTS]
    assert bool((pick_left == (x > 0)[..., None])[far].all())


def test_torso_frame_centre_is_the_torso_mass_and_falls_back_to_the_cloud():
    pts = torch.tensor([[[1.0, 0, 0], [3.0, 0, 0], [10.0, 0, 0]]], dtype=torch.float64)
    w = torch.zeros(1, 3, 22, dtype=torch.float64)
    w[0, 0, 0] = w[0, 1, 3] = 1.0  # two torso points, the third a hand
    rot = torch.eye(3, dtype=torch.float64).expand(1, 4, 3, 3)
    centre, left = torso_frame(pts, w, rot)
    torch.testing.assert_close(centre[0], torch.tensor([2.0, 0, 0], dtype=torch.float64), atol=1e-5, rtol=0)
    torch.testing.assert_close(left[0], torch.tensor(LEFT_AXIS, dtype=torch.float64))
    centre, _ = torso_frame(pts, torch.zeros_like(w), rot)
    torch.testing.assert_close(centre[0], pts[0].mean(0))


def test_pose_head_on_a_subset_of_parts_matches_the_full_call():
    torch.manual_seed(0)
    head = PoseHead(8, group_rotations(torch.float64), tuple(range(-1, 21)), dim=16, heads=4, mlp_hidden=16,
                    parent_conditioning="invariant", logit_eps=1e-4).double()  # fmt: skip
    feats = torch.randn(2, 22, 60, 8, dtype=torch.float64)
    full = head(feats)
    sub = head(feats, parts=(0, 3, 9))
    torch.testing.assert_close(sub["rotmats"], full["rotmats"][:, [0, 3, 9]])
    torch.testing.assert_close(sub["weights"], full["weights"][:, [0, 3, 9]])


@pytest.mark.parametrize("sides", ["torso", "roots"])
@pytest.mark.parametrize("pooling", ["predicted", "ground truth"])
def test_network_with_torso_sides_stays_equivariant(pooling, sides):
    # Rotating the cloud by a group element: the parts (sides included) do not change, every part's
    # rotation turns by that element (float64, to rounding).
    torch.manual_seed(0)
    net = ArtEqNet(**SMALL, sides=sides).double().eval()
    pts = _cloud()
    labels = torch.arange(120).remainder(22)[None] if pooling == "ground truth" else None
    for order in (2, 3, 5):
        r = group_rotations(torch.float64)[int(torch.nonzero(element_orders() == order)[0])]
        with torch.no_grad():
            out, out_rot = net(pts, labels), net(pts @ r.T, labels)
        torch.testing.assert_close(out_rot["part_probs"], out["part_probs"], atol=1e-9, rtol=0)
        torch.testing.assert_close(out_rot["global_rotmats"], r @ out["global_rotmats"], atol=1e-7, rtol=0)


def test_torso_sides_add_no_weights_and_learned_is_the_segmenters_own_answer():
    torch.manual_seed(0)
    learned = ArtEqNet(**SMALL).double().eval()
    torso = ArtEqNet(**SMALL, sides="torso").double().eval()
    assert learned.sides == "learned"
    torso.load_state_dict(learned.state_dict())  # strict: the same keys
    pts = _cloud()
    with torch.no_grad():
        a, b = learned(pts), torso(pts)
        feats = learned.backbone(pts)
        own = learned.segmenter(learned.segmenter.invariant(feats)).softmax(-1)
    torch.testing.assert_close(a["part_probs"], own)
    # the torso's parts and rotations are the same in both; only the pairs' split differs
    torch.testing.assert_close(b["part_probs"][..., TORSO_PARTS], a["part_probs"][..., TORSO_PARTS])
    torch.testing.assert_close(b["global_rotmats"][:, TORSO_PARTS], a["global_rotmats"][:, TORSO_PARTS])
    pair = list(LEFT_PARTS) + list(RIGHT_PARTS)
    assert not torch.allclose(b["part_probs"][..., pair], a["part_probs"][..., pair])


def test_torso_sides_train_with_finite_gradients():
    torch.manual_seed(0)
    net = ArtEqNet(**SMALL, sides="torso").double()
    pts = _cloud()
    labels = torch.arange(120).remainder(22)[None]
    for gt in (labels, None):
        out = net(pts, gt)
        loss = (
            torch.nn.functional.cross_entropy(out["seg_logits"][0], labels[0]) + out["global_rotmats"].sum()
        )
        net.zero_grad()
        loss.backward()
        grads = [p.grad for p in net.parameters() if p.grad is not None]
        assert grads and all(bool(torch.isfinite(g).all()) for g in grads)


def test_bad_side_settings_are_errors():
    with pytest.raises(ValueError, match="model.net.sides"):
        ArtEqNet(**SMALL, sides="mirror")
    with pytest.raises(ValueError, match="side_scale"):
        ArtEqNet(**SMALL, sides="torso", side_scale=0.0)


def test_roots_sides_read_each_limb_in_its_root_parts_frame():
    """A body folded at the waist: the pelvis faces +x-left, spine3 turned 180 degrees about the up axis.
    ``roots`` puts a knee-pair point at +x on the left (the pelvis's frame) and an elbow-pair point at +x on
    the right (spine3's); ``torso`` (their chordal mean, here the pelvis's) puts both on the left."""
    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    pts = torch.tensor([[[0.0, 0, 0], [0, 0, 0.5], [0.2, 0, -0.3], [0.2, 0, 0.4]]], dtype=torch.float64)
    weights = torch.zeros(1, 4, 22, dtype=torch.float64)
    weights[0, 0, j["pelvis"]] = weights[0, 1, j["spine3"]] = 1.0
    logits = torch.zeros(1, 4, 22, dtype=torch.float64)
    logits[0, 2, [j["left_knee"], j["right_knee"]]] = 5.0
    logits[0, 3, [j["left_elbow"], j["right_elbow"]]] = 5.0
    torso = torch.eye(3, dtype=torch.float64).repeat(1, 4, 1, 1)
    torso[0, TORSO_PARTS.index(j["spine3"])] = torch.diag(
        torch.tensor([-1.0, -1.0, 1.0], dtype=torch.float64)
    )
    got = {}
    for mode in ("torso", "roots"):
        net = ArtEqNet(**SMALL, sides=mode).double().eval()
        got[mode] = net._resolve_sides(logits, pts, weights, torso).exp()[0]
    for mode, elbow_side in (("torso", "left"), ("roots", "right")):
        p = got[mode]
        assert p[2, j["left_knee"]] > 0.99 * (p[2, j["left_knee"]] + p[2, j["right_knee"]]), mode
        other = "right" if elbow_side == "left" else "left"
        assert p[3, j[f"{elbow_side}_elbow"]] > 100 * p[3, j[f"{other}_elbow"]], mode
        torch.testing.assert_close(p.sum(-1), torch.ones(4, dtype=torch.float64))


@pytest.mark.parametrize("sides", ["torso", "roots"])
def test_torso_shift_turns_with_the_cloud_and_moves_the_split(sides):
    # A one-sided scan's torso centre moved by ``torso_shift``: the labels move, the pose and shape (pooled
    # with the split the heads were trained with) do not; rotating the cloud and the shift together by a
    # group element changes no part (equivariance holds); a shift far to the body's right puts every limb
    # pair's mass on its left part; a zero shift is no shift.
    torch.manual_seed(0)
    net = ArtEqNet(**SMALL, sides=sides).double().eval()
    pts = _cloud()
    shift = torch.tensor([[0.05, -0.09, 0.02]], dtype=torch.float64)
    with torch.no_grad():
        plain, zero, moved = net(pts), net(pts, torso_shift=torch.zeros(1, 3)), net(pts, torso_shift=shift)
    torch.testing.assert_close(zero["part_probs"], plain["part_probs"])
    assert not torch.allclose(moved["part_probs"], plain["part_probs"])
    for key in ("pool_weights", "global_rotmats", "betas"):
        torch.testing.assert_close(moved[key], plain[key])
    r = group_rotations(torch.float64)[int(torch.nonzero(element_orders() == 5)[0])]
    with torch.no_grad():
        turned = net(pts @ r.T, torso_shift=shift @ r.T)
    torch.testing.assert_close(turned["part_probs"], moved["part_probs"], atol=1e-9, rtol=0)

    # the torso's own left axis (the chordal mean of its predicted rotations, as the network reads it)
    left = (
        roma.special_procrustes(plain["global_rotmats"][:, TORSO_PARTS].sum(1))[0]
        @ torch.tensor(LEFT_AXIS).double()
    )
    with torch.no_grad():
        far_right = net(pts, torso_shift=-5.0 * left[None])["part_probs"][0]
    pairs = far_right[:, list(LEFT_PARTS)] + far_right[:, list(RIGHT_PARTS)]
    torch.testing.assert_close(far_right[:, list(LEFT_PARTS)], pairs, atol=1e-12, rtol=1e-9)
    assert float(pairs.sum()) > 1.0  # the network gave the pairs mass to split


@pytest.mark.parametrize("sides", ["torso", "roots"])
def test_torso_read_turned_round_mirrors_every_pair_and_turns_the_torso(sides):
    # ``turn_torso``: the torso's rotations turned half a turn about their long axis, so every pair's split
    # is the plain reading's mirrored (left gets what right got) and the torso keeps its parts; the torso's
    # returned rotations are the plain ones turned; group equivariance holds; bad uses are errors.
    from arteq.models.arteq_net import TORSO_TURN

    torch.manual_seed(0)
    net = ArtEqNet(**SMALL, sides=sides).double().eval()
    pts = _cloud()
    with torch.no_grad():
        plain, turned = net(pts), net(pts, turn_torso=True)
    p, t = plain["part_probs"][0], turned["part_probs"][0]
    assert float((p[:, list(LEFT_PARTS)] - p[:, list(RIGHT_PARTS)]).abs().max()) > 1e-3  # a split to mirror
    torch.testing.assert_close(t[:, list(LEFT_PARTS)], p[:, list(RIGHT_PARTS)])
    torch.testing.assert_close(t[:, list(RIGHT_PARTS)], p[:, list(LEFT_PARTS)])
    torch.testing.assert_close(t[:, list(TORSO_PARTS)], p[:, list(TORSO_PARTS)])
    torso = list(TORSO_PARTS)
    torch.testing.assert_close(
        turned["global_rotmats"][:, torso], plain["global_rotmats"][:, torso] @ TORSO_TURN.double()
    )
    r = group_rotations(torch.float64)[int(torch.nonzero(element_orders() == 5)[0])]
    with torch.no_grad():
        rotated = net(pts @ r.T, turn_torso=True)
    torch.testing.assert_close(rotated["part_probs"], turned["part_probs"], atol=1e-9, rtol=0)
    torch.testing.assert_close(rotated["global_rotmats"], r @ turned["global_rotmats"], atol=1e-7, rtol=0)
    with pytest.raises(ValueError, match="turn_torso"):
        net(pts, torch.arange(120).remainder(22)[None], turn_torso=True)
    with pytest.raises(ValueError, match="turn_torso"):
        ArtEqNet(**SMALL).double().eval()(pts, turn_torso=True)


def test_torso_turned_per_cloud_reads_each_cloud_as_alone():
    # a [B] mask: the clouds flagged read as with turn_torso=True alone, the others as plain; a mask of the
    # wrong length is an error
    torch.manual_seed(0)
    net = ArtEqNet(**SMALL, sides="torso").double().eval()
    a = _cloud()
    b = a @ group_rotations(torch.float64)[7].T + 0.01 * torch.randn_like(a)
    both = torch.cat([a, b])
    with torch.no_grad():
        mixed = net(both, turn_torso=torch.tensor([True, False]))
        turned, plain = net(a, turn_torso=True), net(b)
    for key in ("part_probs", "global_rotmats", "local_rotmats", "betas"):
        torch.testing.assert_close(mixed[key][:1], turned[key], atol=1e-10, rtol=0)
        torch.testing.assert_close(mixed[key][1:], plain[key], atol=1e-10, rtol=0)
    with pytest.raises(ValueError, match="one flag per cloud"):
        net(both, turn_torso=torch.tensor([True]))
