"""The fingers' curl (arteq.body.hands) against Anny's own skinning, and the hands' last pass
(arteq.fit.hands) recovering a curl from a scan.

Numbers behind the bounds: experiments/fitting/native_anny/README.md (the curl against the stock model
within 1.5 mm; the pass on scans of the stock model).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch


@pytest.fixture(scope="module")
def body():
    pytest.importorskip("anny")
    from arteq.body import load_body_model

    return load_body_model("anny_allages", num_betas=32).double()


@pytest.fixture(scope="module")
def hands(body):
    from arteq.body.hands import hands_for

    hc = hands_for(body)
    assert hc is not None and hc.held_out_mm < 5.0  # the heads' regressor, on held-out shapes
    return hc


def _native_curl(model, bake, hc, phen_kw, curl):
    """Anny's own mesh (SMPL axes, pelvis at the origin) in the body's T-pose with its finger bones turned
    as :class:`HandCurl` turns them (each bone's own delta, the bake undone)."""
    import roma

    from arteq.body import anny_rig
    from arteq.body.hands import FINGER_BONES, SIDES

    C = torch.as_tensor(anny_rig.ANNY_TO_SMPL)
    idx = {b: i for i, b in enumerate(model.bone_labels)}
    glob = anny_rig.baked_globals(model, bake)
    deltas = anny_rig.anny_deltas_from_pose(
        model, bake, torch.eye(3, dtype=torch.float64).repeat(1, 22, 1, 1)
    )
    for hand, side in enumerate(SIDES):
        for j, name in enumerate(FINGER_BONES):
            b = idx[f"{name}.{side}"]
            axis = glob[b].T @ C.T @ hc.axes[hand * 5 + j // 3].double()
            turn = roma.rotvec_to_rotmat(axis * curl[hand] * float(hc.max_rad[hand * 15 + j]))
            deltas[0, b, :3, :3] = deltas[0, b, :3, :3] @ turn
    with torch.no_grad():
        out = model(pose_parameters=deltas, phenotype_kwargs=phen_kw)
    v, j = anny_rig._to_smpl(model, out["vertices"], out["bone_poses"][..., :3, 3])
    return v[0] - j[0, 0]


def test_the_curl_is_anny_s_own_finger_skinning(body, hands):
    """A child's and an adult's phenotype (Anny's sampler), projected on the body's 32 components: the
    body's rest mesh curled by :class:`HandCurl` against the stock model with the same finger bones turned
    (measured 0.1-0.7 mm mean, 1.5 mm worst on the hands' vertices; flat against curled: 3-5 cm)."""
    from arteq.body import anny_allages, anny_rig
    from arteq.fit.anny_params import PHENOTYPE_LABELS

    model = anny_rig.load_anny()
    bake = anny_rig.compute_bake(model)
    pinv = torch.linalg.pinv(body.shapedirs.reshape(-1, body.num_betas))
    torch.manual_seed(3)
    for ages in ((4.0, 10.0), (25.0, 70.0)):
        _, phen, _ = anny_allages.make_sampler(model, ages, extreme_fraction=0.0)(1)
        kw = {k: phen[k][:1].double() for k in PHENOTYPE_LABELS}
        flat = _native_curl(model, bake, hands, kw, (0.0, 0.0))
        betas = pinv @ (flat - body.v_template).reshape(-1)
        rest, _ = body.shape(betas[None])
        assert torch.equal(
            hands(rest, torch.zeros(1, 2, dtype=rest.dtype)), rest
        )  # curl 0: the body as it is
        for curl in ((0.5, 1.0), (1.0, 0.3)):
            nat = _native_curl(model, bake, hands, kw, curl)
            ours = hands(rest, torch.tensor([curl], dtype=rest.dtype))[0]
            moved = hands.moved
            err = (ours - nat).norm(dim=1)
            assert err[moved].mean() < 1.5e-3 and err[moved].max() < 4e-3, (ages, curl, err[moved].max())
            assert (rest[0] - nat)[moved].norm(dim=1).mean() > 0.02  # the curl is centimetres
            others = torch.ones(len(ours), dtype=torch.bool)
            others[moved] = False
            assert torch.equal(ours[others], rest[0][others])  # nothing but the fingers moves


def test_the_fingers_curl_towards_the_palm(body, hands):
    """The direction, apart from the machinery: a curl brings the index finger's last phalanx towards the
    thumb's base (on the palm's side) far more than the same turn backwards (measured 12.7 cm flat, 5.5
    curled 0.6, 9.4 bent back as far)."""
    from arteq.body.hands import FINGER_BONES

    rest, _ = body.shape(torch.zeros(1, 16, dtype=torch.float64))
    heads = hands.heads(rest)
    for hand in (0, 1):
        tip = hand * 15 + FINGER_BONES.index("finger2-3")
        thumb = heads[0, hand * 15 + FINGER_BONES.index("finger1-1")]
        sel = hands.vert[(hands.bone == tip) & (hands.weight > 0.9)]
        flat = (rest[0, sel].mean(0) - thumb).norm()
        dist = {
            c: (hands(rest, torch.full((1, 2), c, dtype=rest.dtype))[0, sel].mean(0) - thumb).norm()
            for c in (0.6, -0.6)
        }
        assert dist[0.6] < 0.6 * flat and dist[0.6] < dist[-0.6] - 0.02, (hand, flat, dist)
    # one curl per finger ([B, 10]), all five of a hand alike, is the hand's curl ([B, 2])
    per_hand = hands(rest, torch.tensor([[0.7, 0.2]], dtype=rest.dtype))
    per_finger = hands(rest, torch.tensor([[0.7] * 5 + [0.2] * 5], dtype=rest.dtype))
    assert torch.allclose(per_hand, per_finger, atol=1e-12)
    only_index = hands(rest, torch.tensor([[0, 0.7, 0, 0, 0] + [0] * 5], dtype=rest.dtype))
    moved = (only_index - rest)[0].norm(dim=1) > 1e-9
    assert moved.any() and moved.sum() < 0.3 * len(hands.moved)  # one finger of one hand
    with pytest.raises(ValueError, match="curl must be"):
        hands(rest, torch.zeros(1, 3, dtype=rest.dtype))
    with pytest.raises(ValueError, match="a body of 13718 vertices"):
        hands(rest[:, :100], torch.zeros(1, 2, dtype=rest.dtype))


def test_the_hands_pass_finds_a_curl_and_leaves_a_flat_hand_flat(body, hands):
    """A body whose left hand is half closed and right hand flat, a fit of it with both hands flat and the
    wrists 10 degrees off: the pass finds the left curl within 0.15, keeps the right within 0.1 of flat
    and brings the hands' vertices nearer the truth."""
    import roma

    def rodrigues(axis, angle):  # about a unit axis
        return roma.rotvec_to_rotmat(axis * angle)

    from arteq.fit.hands import HAND_JOINTS, fit_hands

    rng = np.random.default_rng(0)
    betas = torch.as_tensor(rng.normal(0, 0.5, (1, 32)))
    pose = torch.eye(3, dtype=torch.float64).repeat(1, 22, 1, 1)
    pose[0, 16] = rodrigues(
        torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(-1.1)
    )  # arms down
    pose[0, 17] = rodrigues(torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64), torch.tensor(1.1))
    rest, joints = body.shape(betas)
    from arteq.body.lbs import skin
    from arteq.body.skeleton import PARENTS

    truth_curl = torch.tensor([[0.5, 0.0]], dtype=torch.float64)
    truth = skin(hands(rest, truth_curl), joints, pose, body.lbs_weights, PARENTS)[0][0]
    faces = body.faces.numpy()
    tri = truth.numpy()[faces]
    area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    f = rng.choice(len(faces), 8000, p=area / area.sum())
    u, v = rng.random((2, 8000))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    pts = tri[f, 0] + u[:, None] * (tri[f, 1] - tri[f, 0]) + v[:, None] * (tri[f, 2] - tri[f, 0])
    pts += rng.normal(0, 0.002, pts.shape)
    start = pose.clone()
    for j in HAND_JOINTS:
        start[0, j] = rodrigues(torch.tensor([1.0, 0.0, 0.0], dtype=torch.float64), torch.tensor(0.17))
    init = {"local_rotmats": start, "betas": betas, "transl": torch.zeros(1, 3, dtype=torch.float64)}
    out = fit_hands(body, hands, [pts], init)
    assert abs(float(out["curl"][0, 0]) - 0.5) < 0.15 and float(out["curl"][0, 1]) < 0.1, out["curl"]
    hv = torch.isin(body.part_labels, torch.tensor(HAND_JOINTS))
    before = skin(rest, joints, start, body.lbs_weights, PARENTS)[0][0]
    e0 = (before - truth)[hv].norm(dim=1).mean()
    e1 = (out["vertices"][0] - truth)[hv].norm(dim=1).mean()
    assert e1 < 0.5 * e0, (e0, e1)
    # nothing moves but what the wrists' skinning weights or the fingers' reach
    still = body.lbs_weights[:, list(HAND_JOINTS)].sum(1) == 0
    still[hands.moved] = False
    assert torch.equal(out["vertices"][0][still], before[still])
