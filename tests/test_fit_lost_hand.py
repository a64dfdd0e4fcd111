"""Lost hands (arteq.fit.lost_hand): an arm whose hand the fit laid by the thigh, put back on its points."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from arteq.fit.lost_hand import LostHandConfig, fit_lost_hand, place_hand
from arteq.fit.reach import LIMBS, aim_limb
from arteq.fit.refine import branch_parts
from fit_helpers import posed as _posed
from fit_helpers import unit as _unit


@pytest.fixture(scope="module")
def body(anny22):
    return anny22


@pytest.fixture(scope="module")
def scene(body):
    """A body whose left forearm reaches forward and down, the elbow bent (the truth, its 5000-point scan),
    and a fit of it whose left arm hangs by the thigh instead: the hand on the body's side, its points
    off."""
    from arteq.fit.demo import synthetic_scan
    from arteq.geometry.sampling import sample_surface

    s = synthetic_scan(body, "test_id", 2, 5000, offset=0.0, rotate=False)
    rest = _posed(body, s["pose"], s["betas"], s["transl"])
    j = rest["joints"]
    up = _unit(j[12] - j[0])  # pelvis -> neck
    left = _unit(j[16] - j[17])  # right -> left shoulder
    front = _unit(np.cross(left, up))
    down_arm = aim_limb(s["pose"], rest["global_rotmats"], j, "left_arm", _unit(-up + 0.25 * left),
                        _unit(-up + 0.2 * left + 0.05 * front))  # fmt: skip
    reach_arm = aim_limb(s["pose"], rest["global_rotmats"], j, "left_arm", _unit(-up + 0.4 * front),
                         _unit(front - 0.5 * up))  # fmt: skip
    truth = _posed(body, reach_arm, s["betas"], s["transl"])
    fit = _posed(body, down_arm, s["betas"], s["transl"])
    fit.update(local_rotmats=down_arm, betas=s["betas"], transl=s["transl"])
    g = torch.Generator().manual_seed(5)
    pts, _, _ = sample_surface(
        torch.as_tensor(truth["vertices"], dtype=torch.float32), body.faces, 5000, g, noise_std=0.003
    )
    return s, truth, fit, pts.double().numpy()


def _hand_error_cm(body, vertices, truth) -> float:
    hand = body.part_labels.numpy() == LIMBS["left_arm"][2]
    return float(np.linalg.norm(vertices[hand] - truth["vertices"][hand], axis=1).mean() * 100)


def test_place_hand_puts_the_hand_centre_on_the_target(body, scene):
    """The placed arm's hand centre lands on the target (within a few cm: the hand's centre is taken along
    the forearm) and the shoulder stays; a target out of reach gets the arm stretched toward it."""
    from scipy.spatial import cKDTree

    s, truth, fit, pts = scene
    parts = body.part_labels.numpy()
    hand = parts == LIMBS["left_arm"][2]
    target = truth["vertices"][hand].mean(0)
    ((d1, d2),) = place_hand(cKDTree(pts), fit["vertices"], fit["joints"], parts, "left_arm", target)
    aimed = aim_limb(fit["local_rotmats"], fit["global_rotmats"], fit["joints"], "left_arm", d1, d2)
    placed = _posed(body, aimed, s["betas"], s["transl"])
    np.testing.assert_allclose(placed["joints"][16], fit["joints"][16], atol=1e-5)
    assert np.linalg.norm(placed["vertices"][hand].mean(0) - target) < 0.05
    far = fit["joints"][16] + 3.0 * _unit(target - fit["joints"][16])
    ((d1, d2),) = place_hand(cKDTree(pts), fit["vertices"], fit["joints"], parts, "left_arm", far)
    assert d1 @ _unit(far - fit["joints"][16]) > 0.95 and d2 @ _unit(far - fit["joints"][16]) > 0.95


def test_the_lost_hand_is_put_back_and_nothing_else_moves(body, scene):
    """The fit's left hand lies by the thigh, 20+ cm from its points: the step keeps the left arm, the hand
    ends within 3 cm of the truth, and only the arm's three joints turn."""
    s, truth, fit, pts = scene
    parts = body.part_labels.numpy()
    before = _hand_error_cm(body, fit["vertices"], truth)
    rec = fit_lost_hand(body, pts, fit, parts)
    assert rec is not None and rec["arm"] == "left_arm", rec
    tried = rec["tried"]["left_arm"]
    assert sum(tried["after"]) < (1 - LostHandConfig().min_gain) * sum(tried["before"]), tried
    out = _posed(body, rec["local_rotmats"], s["betas"], s["transl"])
    after = _hand_error_cm(body, out["vertices"], truth)
    assert before > 20.0 and after < 3.0, (before, after)
    still = body.lbs_weights[:, branch_parts(16)].sum(1).numpy() == 0  # no skinning weight on the arm
    np.testing.assert_allclose(out["vertices"][still], fit["vertices"][still], atol=1e-5)
    new, old = rec["local_rotmats"], fit["local_rotmats"]
    turned = [k for k in range(22) if not np.allclose(new[k], old[k], atol=1e-6)]
    assert set(turned) <= set(LIMBS["left_arm"]), turned


def test_a_fit_that_explains_its_scan_is_left_alone(body, scene):
    """The truth as the fit: no group of points off it, nothing tried; a hand the network gave 1 % of the
    points or more is not tried (it was seen: the group is something else); a group out of both arms' reach
    (a patch 2 m away) is tried by neither arm."""
    s, truth, fit, pts = scene
    parts = body.part_labels.numpy()
    own = dict(truth, local_rotmats=fit["local_rotmats"], betas=s["betas"], transl=s["transl"])
    assert fit_lost_hand(body, pts, own, parts) is None
    seen = np.zeros(22)  # the network's share of the points per part: the left hand seen, the right not
    seen[LIMBS["left_arm"][2]] = 0.02
    rec = fit_lost_hand(body, pts, fit, parts, seen=seen)
    assert rec is None or "left_arm" not in rec["tried"], rec
    seen[LIMBS["left_arm"][2]] = 0.005
    assert fit_lost_hand(body, pts, fit, parts, seen=seen)["arm"] == "left_arm"
    rng = np.random.default_rng(0)
    patch = truth["vertices"].mean(0) + np.array([2.0, 0.0, 0.0]) + rng.normal(scale=0.02, size=(60, 3))
    assert fit_lost_hand(body, np.concatenate([pts, patch]), own, parts) is None


def test_the_fitter_puts_the_hand_back_and_says_so(body, scene, tmp_path, tiny_net):
    """Through ``Fitter``: a "network" that reads the arm hanging by the thigh is fitted with the hand on
    its points when the step is on (the crossing record names the arm) and keeps it lost when off."""
    from arteq.fit.crossing import CrossingConfig
    from arteq.fit.refine import RefineConfig
    from fit_helpers import reading_of, write_tiny_checkpoint

    s, truth, fit, pts = scene
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", tiny_net)
    Down = reading_of(fit["vertices"], fit["local_rotmats"], s["betas"], s["transl"])
    err, taken = {}, {}
    for on in (True, False):
        # the fit stays as read until this step: no refinement iterations, no other limb step (they bring a
        # flat hand hanging nearby back; a fist the network gives none of the hand's points they do not)
        alone = CrossingConfig(lost_hand=on, reach=False, torso=False, doubtful_tries_all=False, near_m=0.0)
        f = Down(ckpt=ckpt, device="cpu", anny=False, retries=0, hands=False,
                 refine_config=RefineConfig(iters=0), crossing=alone)  # fmt: skip
        r = f.fit_points(pts)
        err[on] = _hand_error_cm(body, r.vertices.astype(np.float64), truth)
        taken[on] = (r.crossing or {}).get("taken", "")
        if on:
            assert r.crossing["lost_hand"]["arm"] == "left_arm", r.crossing
            assert "hand_off_fit" not in r.quality["flags"], r.quality  # put back: nothing to flag
    assert "hand_left_arm" in taken[True] and "hand_" not in taken[False], taken
    assert err[True] < 4.0 < 15.0 < err[False], err


def test_a_hand_the_step_cannot_put_back_is_flagged(body, scene, tmp_path, tiny_net, monkeypatch):
    """Where the step tries arms and keeps none (here: made unable to keep any), the fit is written
    ``uncertain`` with ``hand_off_fit`` and a reason naming the group and the arm; with
    ``lost_hand_flag=False`` the same fit is not flagged for it."""
    import functools

    import arteq.fit.lost_hand as lost_hand
    from arteq.fit.crossing import CrossingConfig
    from arteq.fit.refine import RefineConfig
    from fit_helpers import reading_of, write_tiny_checkpoint

    s, truth, fit, pts = scene
    monkeypatch.setattr(lost_hand, "LostHandConfig", functools.partial(LostHandConfig, min_gain=10.0))
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", tiny_net)
    Down = reading_of(fit["vertices"], fit["local_rotmats"], s["betas"], s["transl"])
    flags = {}
    for flag in (True, False):
        alone = CrossingConfig(reach=False, torso=False, doubtful_tries_all=False, near_m=0.0,
                               lost_hand_flag=flag)  # fmt: skip
        f = Down(ckpt=ckpt, device="cpu", anny=False, retries=0, hands=False,
                 refine_config=RefineConfig(iters=0), crossing=alone)  # fmt: skip
        r = f.fit_points(pts)
        assert r.crossing["lost_hand"]["arm"] == "" and "left_arm" in r.crossing["lost_hand"]["tried"]
        assert _hand_error_cm(body, r.vertices.astype(np.float64), truth) > 15.0  # still lost
        flags[flag] = r.quality["flags"]
        if flag:
            assert r.status == "uncertain", r.status
            assert r.quality["hand_off_points"] == r.crossing["lost_hand"]["group"] >= 20
            assert "by the left arm" in r.uncertain_reason and "hand may be" in r.uncertain_reason, r.message
    assert "hand_off_fit" in flags[True] and "hand_off_fit" not in flags[False], flags
