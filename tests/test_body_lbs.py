"""LBS and BodyModel behaviour on a small synthetic SMPL-format model (fast, no files needed)."""

from __future__ import annotations

import pytest
import roma
import torch

from arteq.body import BodyModel, lbs
from arteq.body.skeleton import NUM_JOINTS, PARENTS


def _synthetic(V: int = 300, nb: int = 8, posedirs_features: int | None = 189, seed: int = 0) -> BodyModel:
    g = torch.Generator().manual_seed(seed)
    v = torch.randn(V, 3, generator=g, dtype=torch.float64)
    # sparse skinning: each vertex on 3 random parts
    w = torch.zeros(V, NUM_JOINTS, dtype=torch.float64)
    w.scatter_(
        1,
        torch.randint(0, NUM_JOINTS, (V, 3), generator=g),
        torch.rand(V, 3, generator=g, dtype=torch.float64),
    )
    w = w / w.sum(1, keepdim=True)
    jr = torch.rand(NUM_JOINTS, V, generator=g, dtype=torch.float64)
    jr = jr / jr.sum(1, keepdim=True)
    sd = 0.05 * torch.randn(V, 3, nb, generator=g, dtype=torch.float64)
    pd = None
    if posedirs_features:
        pd = 0.01 * torch.randn(posedirs_features, V * 3, generator=g, dtype=torch.float64)
    faces = torch.randint(0, V, (50, 3), generator=g)
    return BodyModel(v, sd, pd, jr, w, faces, name="synthetic", dtype=torch.float64)


def _random_pose(B: int, scale: float = 0.8, seed: int = 1) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return scale * torch.randn(B, NUM_JOINTS, 3, generator=g, dtype=torch.float64)


def test_rest_gives_template_and_shapes():
    body = _synthetic()
    out = body()
    assert out.vertices.shape == (1, 300, 3) and out.joints.shape == (1, 22, 3)
    assert out.global_rotmats.shape == (1, 22, 3, 3) and out.rest_joints.shape == (1, 22, 3)
    torch.testing.assert_close(out.vertices[0], body.v_template)
    torch.testing.assert_close(out.joints[0], body.J_regressor @ body.v_template)
    zero = body(betas=torch.zeros(3, 8), pose=torch.zeros(3, 66, dtype=torch.float64))
    torch.testing.assert_close(zero.vertices, body.v_template.expand(3, -1, -1))
    assert body.part_labels.shape == (300,) and body.part_labels.dtype == torch.long


def test_root_rotation_rotates_about_pelvis():
    body = _synthetic(posedirs_features=None)
    betas = torch.randn(2, 8, dtype=torch.float64)
    rest = body(betas=betas)
    R = roma.random_rotmat(2, dtype=torch.float64)
    pose = torch.eye(3, dtype=torch.float64).repeat(2, 22, 1, 1)
    pose[:, 0] = R
    out = body(betas=betas, pose=pose)
    j0 = rest.rest_joints[:, :1]
    expect = (rest.vertices - j0) @ R.transpose(1, 2) + j0
    torch.testing.assert_close(out.vertices, expect)
    torch.testing.assert_close(out.joints[:, 0], rest.rest_joints[:, 0])


def test_joints_move_with_betas_and_translation():
    body = _synthetic()
    a = body(betas=torch.zeros(1, 8))
    b = body(betas=torch.full((1, 8), 2.0))
    assert (a.rest_joints - b.rest_joints).norm(dim=-1).min() > 1e-4
    v_shaped = body.v_template + torch.einsum(
        "l,vcl->vc", torch.full((8,), 2.0, dtype=torch.float64), body.shapedirs
    )
    torch.testing.assert_close(b.rest_joints[0], body.J_regressor @ v_shaped)
    t = torch.tensor([[0.3, -1.0, 2.0]], dtype=torch.float64)
    c = body(betas=torch.full((1, 8), 2.0), transl=t)
    torch.testing.assert_close(c.vertices, b.vertices + t[:, None])
    torch.testing.assert_close(c.joints, b.joints + t[:, None])


def test_single_joint_moves_only_its_subtree():
    body = _synthetic(posedirs_features=None)
    k = PARENTS.index(4)  # left_ankle (7) is the child of left_knee (4)
    subtree = {4}
    for j in range(NUM_JOINTS):
        if PARENTS[j] in subtree:
            subtree.add(j)
    pose = torch.zeros(1, 22, 3, dtype=torch.float64)
    pose[0, 4] = torch.tensor([0.7, -0.2, 0.1])
    out = body(pose=pose)
    free = body.lbs_weights[:, sorted(subtree)].sum(1) < 1e-12
    assert k == 7 and free.any()
    torch.testing.assert_close(out.vertices[0, free], body.v_template[free])
    moved = [j for j in range(22) if j not in subtree]
    torch.testing.assert_close(out.joints[0, moved], out.rest_joints[0, moved])


def test_batched_unbatched_and_pose_formats_agree():
    body = _synthetic()
    aa = _random_pose(4)
    betas = torch.randn(4, 8, dtype=torch.float64)
    batched = body(betas=betas, pose=aa)
    rot = roma.rotvec_to_rotmat(aa)
    torch.testing.assert_close(body(betas=betas, pose=rot).vertices, batched.vertices)
    torch.testing.assert_close(body(betas=betas, pose=aa.reshape(4, 66)).vertices, batched.vertices)
    for i in range(4):
        single = body(betas=betas[i], pose=aa[i])
        assert single.vertices.dim() == 2
        torch.testing.assert_close(single.vertices, batched.vertices[i])
        torch.testing.assert_close(body(betas=betas[i], pose=rot[i]).joints, batched.joints[i])
    # betas with fewer columns are zero-padded; batch size 1 broadcasts
    few = body(betas=betas[:1, :3], pose=aa)
    pad = torch.cat([betas[:1, :3], torch.zeros(1, 5, dtype=torch.float64)], 1).expand(4, -1)
    torch.testing.assert_close(few.vertices, body(betas=pad, pose=aa).vertices)


def test_gradients_flow_to_betas_and_pose():
    body = _synthetic().float()
    betas = torch.zeros(2, 8, requires_grad=True)
    aa = (0.3 * torch.randn(2, 22, 3)).requires_grad_()
    out = body(betas=betas, pose=aa)
    (out.vertices.square().sum() + out.joints.sum()).backward()
    assert betas.grad is not None and betas.grad.abs().sum() > 0 and torch.isfinite(betas.grad).all()
    assert aa.grad is not None and aa.grad.abs().sum() > 0 and torch.isfinite(aa.grad).all()
    assert out.vertices.dtype == torch.float32


def test_smpl_posedirs_with_207_features_take_hands_at_identity():
    b189 = _synthetic(posedirs_features=189)
    pd207 = torch.cat([b189.posedirs, torch.randn(18, b189.posedirs.shape[1], dtype=torch.float64)])
    b207 = BodyModel(
        b189.v_template,
        b189.shapedirs,
        pd207,
        b189.J_regressor,
        b189.lbs_weights,
        b189.faces,
        dtype=torch.float64,
    )
    aa = _random_pose(3)
    torch.testing.assert_close(b207(pose=aa).vertices, b189(pose=aa).vertices)
    # pose blendshapes really act: without them the result differs
    none = BodyModel(
        b189.v_template,
        b189.shapedirs,
        None,
        b189.J_regressor,
        b189.lbs_weights,
        b189.faces,
        dtype=torch.float64,
    )
    assert (none(pose=aa).vertices - b189(pose=aa).vertices).abs().max() > 1e-4


def test_bad_inputs_raise_clear_errors():
    body = _synthetic()
    with pytest.raises(ValueError, match="betas"):
        body(betas=torch.zeros(1, 9))
    with pytest.raises(ValueError, match="pose"):
        body(pose=torch.zeros(2, 21, 3))
    with pytest.raises(ValueError, match="batch sizes"):
        body(betas=torch.zeros(2, 8), pose=torch.zeros(3, 66))
    with pytest.raises(ValueError, match="J_regressor"):
        lbs(
            torch.zeros(1, 2),
            torch.eye(3).expand(1, 22, 3, 3),
            torch.zeros(10, 3),
            torch.zeros(10, 3, 2),
            None,
            torch.zeros(21, 10),
            PARENTS,
            torch.zeros(10, 22),
        )


def _kinematics_by_joint(local: torch.Tensor, rest_joints: torch.Tensor, parents) -> tuple:
    """The textbook recursion, one joint at a time: R_k = R_p theta_k, J'_k = J'_p + R_p (J_k - J_p)."""
    rots, joints = [local[:, 0]], [rest_joints[:, 0]]
    for k in range(1, len(parents)):
        p = parents[k]
        rots.append(rots[p] @ local[:, k])
        joints.append(joints[p] + (rots[p] @ (rest_joints[:, k] - rest_joints[:, p])[..., None])[..., 0])
    return torch.stack(rots, 1), torch.stack(joints, 1)


@pytest.mark.parametrize("parents", [PARENTS, (-1, 0, 1, 0, 3, 1, 5, 5, 2)])
def test_batched_kinematics_agree_with_the_joint_by_joint_recursion(parents):
    from arteq.body.lbs import skin
    from arteq.body.skeleton import local_to_global

    k = len(parents)
    g = torch.Generator().manual_seed(3)
    local = roma.rotvec_to_rotmat(torch.randn(4, k, 3, generator=g, dtype=torch.float64))
    rest = torch.randn(4, k, 3, generator=g, dtype=torch.float64)
    rots, joints = _kinematics_by_joint(local, rest, parents)
    torch.testing.assert_close(local_to_global(local, tuple(parents)), rots, rtol=0, atol=1e-13)
    verts = torch.randn(4, 10, 3, generator=g, dtype=torch.float64)
    weights = torch.softmax(torch.randn(10, k, generator=g, dtype=torch.float64), -1)
    _, posed, _ = skin(verts, rest, local, weights, parents=parents)
    torch.testing.assert_close(posed, joints, rtol=0, atol=1e-13)


def test_kinematics_refuse_a_parent_after_its_child():
    from arteq.body.skeleton import local_to_global

    with pytest.raises(ValueError, match="parent before its child"):
        local_to_global(torch.eye(3).expand(1, 3, 3, 3), (-1, 2, 0))
