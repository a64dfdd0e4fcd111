"""The toy body is a BodyModel posed by the shared LBS, with the outputs of its former own skinning;
create_body is the one factory; body buffers never enter a state dict."""

import pytest
import roma
import torch

from arteq.body import BodyModel, create_body
from arteq.body.skeleton import NUM_JOINTS, PARENTS, local_to_global
from arteq.body.toy import ToyBody


def _former_toy_forward(body, betas, pose, transl):
    """The toy body's own skinning before it became a BodyModel (reference)."""
    scale = 1 + 0.05 * betas[:, :1]
    thick = 1 + 0.1 * betas[:, 1:2]
    jr = body.j_template[None] * scale[..., None]
    owner_j = body.j_template[body.part_labels]
    vr = (owner_j[None] + (body.v_template - owner_j)[None] * thick[..., None]) * scale[..., None]
    grot = local_to_global(pose)
    jp = [jr[:, 0]]
    for k in range(1, NUM_JOINTS):
        p = PARENTS[k]
        jp.append(jp[p] + (grot[:, p] @ (jr[:, k] - jr[:, p])[..., None])[..., 0])
    joints = torch.stack(jp, 1)
    per_part = torch.einsum("bkij,bvkj->bvki", grot, vr[:, :, None, :] - jr[:, None]) + joints[:, None]
    verts = (body.lbs_weights[None, :, :, None] * per_part).sum(2)
    return verts + transl[:, None], joints + transl[:, None], grot, jr


def test_toy_body_is_a_body_model_with_its_former_outputs():
    body = ToyBody()
    assert isinstance(body, BodyModel) and body.name == "toy" and body.num_betas == 2
    g = torch.Generator().manual_seed(0)
    betas = torch.randn(3, 2, generator=g) * 1.5
    pose = roma.rotvec_to_rotmat(torch.randn(3, NUM_JOINTS, 3, generator=g) * 0.6)
    transl = torch.randn(3, 3, generator=g)
    out = body(betas=betas, pose=pose, transl=transl)
    ref = _former_toy_forward(body, betas, pose, transl)
    for got, want in zip((out.vertices, out.joints, out.global_rotmats, out.rest_joints), ref):
        torch.testing.assert_close(got, want, atol=2e-6, rtol=1e-5)
    # the joint regressor reproduces the rest joints; the shape directions are first-order exact
    torch.testing.assert_close(body.J_regressor @ body.v_template, body.j_template, atol=1e-6, rtol=0)
    small = torch.tensor([[1e-3, -1e-3]])
    lin = body.v_template + torch.einsum("bl,vcl->bvc", small, body.shapedirs)[0]
    torch.testing.assert_close(body.shape(small)[0][0], lin, atol=1e-6, rtol=0)


def test_create_body():
    toy = create_body({"name": "toy", "_target_": "ignored"})
    assert isinstance(toy, ToyBody)
    assert create_body(toy) is toy
    assert create_body(name="toy", num_betas=1).num_betas == 1
    omega = pytest.importorskip("omegaconf").OmegaConf.create({"name": "toy"})
    assert isinstance(create_body(omega), ToyBody)
    with pytest.raises(TypeError, match="config keys"):
        create_body(toy, name="toy")
    with pytest.raises(TypeError, match="config mapping"):
        create_body("toy")


def test_body_buffers_never_in_state_dict():
    body = ToyBody()
    assert dict(body.state_dict()) == {}
    holder = torch.nn.Module()
    holder.body = body
    holder.lin = torch.nn.Linear(2, 2)
    assert sorted(holder.state_dict()) == ["lin.bias", "lin.weight"]
