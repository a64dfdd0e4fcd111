"""Lost limbs (arteq.fit.reach): a limb placed on the points the fit leaves off, and the fitter keeping it."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from arteq.body.skeleton import PARENTS
from arteq.fit.reach import FORWARD, LIMBS, PREFIX, aim_limb, off_group, reach_starts
from arteq.fit.refine import RefineConfig, body_tables, branch_parts
from fit_helpers import posed as _posed


@pytest.fixture(scope="module")
def body(anny22):
    return anny22


def _unit(v):
    v = np.asarray(v, dtype=np.float64)
    return v / np.linalg.norm(v)


@pytest.fixture(scope="module")
def scene(body):
    from arteq.fit.demo import synthetic_scan

    s = synthetic_scan(body, "test_id", 2, 5000, offset=0.0, rotate=True)
    return s, _posed(body, s["pose"], s["betas"], s["transl"])


def test_the_rest_pose_faces_forward(body):
    """:data:`FORWARD` is where the rest pose faces: the feet point there (the hinge sides rest on it)."""
    rest = _posed(body, np.tile(np.eye(3), (22, 1, 1)), np.zeros(body.num_betas), np.zeros(3))
    parts = body.part_labels.numpy()
    for foot, ankle in ((10, 7), (11, 8)):
        toe = rest["vertices"][parts == foot].mean(0) - rest["joints"][ankle]
        assert toe @ FORWARD > 0.5 * np.linalg.norm(toe), toe


@pytest.mark.parametrize("limb", list(LIMBS))
@pytest.mark.parametrize("bend_deg", [5.0, 40.0, 100.0, 160.0])
def test_aim_limb_points_both_segments_and_bends_the_natural_way(body, scene, limb, bend_deg):
    """The segments point along the asked directions, the root joint stays, nothing outside the limb turns,
    and a bent limb bends at its middle joint about one axis (normal to the bone), the natural way (an
    elbow forward, a knee back, in the rest pose's frame)."""
    s, fit = scene
    root, mid, end = LIMBS[limb]
    rng = np.random.default_rng(int(bend_deg) + root)
    d1 = _unit(rng.normal(size=3))
    side = _unit(np.cross(d1, rng.normal(size=3)))
    a = np.radians(bend_deg)
    d2 = np.cos(a) * d1 + np.sin(a) * side
    local = aim_limb(s["pose"], fit["global_rotmats"], fit["joints"], limb, d1, d2)
    new = _posed(body, local, s["betas"], s["transl"])
    np.testing.assert_allclose(new["joints"][root], fit["joints"][root], atol=1e-5)
    assert _unit(new["joints"][mid] - new["joints"][root]) @ d1 > np.cos(np.radians(1.0))
    assert _unit(new["joints"][end] - new["joints"][mid]) @ d2 > np.cos(np.radians(1.0))
    moved = set(branch_parts(root))
    for k in range(22):
        if k not in moved:
            np.testing.assert_allclose(new["global_rotmats"][k], fit["global_rotmats"][k], atol=1e-5)
    if bend_deg > 15.0:  # the hinge: one axis, normal to the rest bone, turning it toward the right side
        import roma

        rotvec = roma.rotmat_to_rotvec(torch.as_tensor(local[mid])).numpy()
        # as far as opens the segments to the angle asked (the rest limb is bent by a few degrees)
        assert np.degrees(np.linalg.norm(rotvec)) == pytest.approx(bend_deg, abs=12.0)
        rest = _posed(body, np.tile(np.eye(3), (22, 1, 1)), s["betas"], np.zeros(3))["joints"]
        bone = _unit(rest[end] - rest[mid])
        assert abs(_unit(rotvec) @ bone) < 0.2
        toward = np.cross(rotvec, bone)  # where the bend starts to take the bone
        sign = 1.0 if limb.endswith("arm") else -1.0
        assert sign * (toward @ FORWARD) > 0.3 * np.linalg.norm(toward), (limb, toward)


def _lost_arm(body, s, fit):
    """The scene's pose with the left arm raised overhead and bent (the truth), and its scan."""
    from arteq.geometry.sampling import sample_surface

    up = _unit(fit["joints"][12] - fit["joints"][0])  # pelvis -> neck
    out = _unit(fit["joints"][16] - fit["joints"][17])  # right -> left shoulder
    d1 = _unit(up + 0.3 * out)
    d2 = _unit(up - 0.5 * out)
    pose = aim_limb(s["pose"], fit["global_rotmats"], fit["joints"], "left_arm", d1, d2)
    truth = _posed(body, pose, s["betas"], s["transl"])
    g = torch.Generator().manual_seed(3)
    pts, _, _ = sample_surface(
        torch.as_tensor(truth["vertices"], dtype=torch.float32), body.faces, 5000, g, noise_std=0.003
    )
    return pose, truth, pts.double().numpy()


def test_reach_starts_place_the_lost_arm_on_its_points(body, scene):
    """A fit whose left arm hangs where the scan's is raised: the off-fit group is the raised arm; the left
    arm's start points both segments within a few degrees of the truth; a fit that explains the scan gets
    none."""
    s, fit = scene
    _, truth, pts = _lost_arm(body, s, fit)
    parts = body.part_labels.numpy()
    group = off_group(pts, fit["vertices"], 0.04, 0.04)
    arm = np.isin(parts, branch_parts(16))
    from scipy.spatial import cKDTree

    on_arm = arm[cKDTree(truth["vertices"]).query(group)[1]]
    assert len(group) > 100 and on_arm.mean() > 0.9, (len(group), on_arm.mean())
    starts = reach_starts(pts, fit["vertices"], fit["joints"], s["pose"], fit["global_rotmats"], parts)
    assert PREFIX + "left_arm" in starts, list(starts)
    placed = _posed(body, starts[PREFIX + "left_arm"], s["betas"], s["transl"])["joints"]
    for a, b in ((16, 18), (18, 20)):
        cos = _unit(placed[b] - placed[a]) @ _unit(truth["joints"][b] - truth["joints"][a])
        assert cos > np.cos(np.radians(12.0)), (a, b, np.degrees(np.arccos(cos)))
    own = reach_starts(pts, truth["vertices"], truth["joints"], s["pose"], truth["global_rotmats"], parts)
    assert own == {}


def test_try_swaps_keeps_the_placed_arm(body, scene):
    """Refined with the crossed-limb step's swaps, the reach start is kept (its surface score clearly lower)
    and lands on the truth; without it the lost arm stays lost."""
    from arteq.fit.crossing import try_swaps

    s, fit = scene
    _, truth, pts = _lost_arm(body, s, fit)
    parts = body.part_labels.numpy()
    subset = body_tables(body, 2000).m2s_subset.numpy()
    fit_t = {
        "local_rotmats": torch.as_tensor(s["pose"], dtype=torch.float32)[None],
        "betas": torch.as_tensor(s["betas"], dtype=torch.float32)[None],
        "transl": torch.as_tensor(s["transl"], dtype=torch.float32)[None],
        **{k: torch.as_tensor(fit[k])[None] for k in ("vertices", "joints", "global_rotmats")},
    }
    starts = reach_starts(pts, fit["vertices"], fit["joints"], s["pose"], fit["global_rotmats"], parts)
    out = try_swaps(body, [pts], fit_t, subset, [[]], RefineConfig(), extra=[starts])[0]
    assert out["taken"] == PREFIX + "left_arm", out["tried"]
    after = np.linalg.norm(out["vertices"].double().numpy() - truth["vertices"], axis=1).mean() * 100
    before = np.linalg.norm(fit["vertices"] - truth["vertices"], axis=1).mean() * 100
    assert before > 3.0 and after < 1.0, (before, after)
    alone = try_swaps(body, [pts], fit_t, subset, [[]], RefineConfig(), extra=[{}])[0]
    assert alone["taken"] == "" and alone["tried"] == {}


def test_the_fitter_places_a_lost_arm_and_says_so(body, scene, tmp_path, tiny_net):
    """Through ``Fitter``: a "network" that reads the raised arm hanging down (its pose and labels) is fitted
    with the arm raised when the reach starts are on, and keeps it lost when off; the record names it."""
    from arteq.fit.crossing import CrossingConfig
    from fit_helpers import reading_of, write_tiny_checkpoint

    s, fit = scene
    _, truth, pts = _lost_arm(body, s, fit)
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", tiny_net)

    ArmDown = reading_of(fit["vertices"], s["pose"], s["betas"], s["transl"])  # reads the arm hanging down

    v2v, taken = {}, {}
    for on in (True, False):
        # the lost-hand step off: it puts this arm back too (tests/test_fit_lost_hand.py)
        cross = CrossingConfig(reach=on, lost_hand=False)
        f = ArmDown(ckpt=ckpt, device="cpu", anny=False, retries=0, crossing=cross)
        r = f.fit_points(pts)
        v2v[on] = float(np.linalg.norm(r.vertices - truth["vertices"], axis=1).mean() * 100)
        taken[on] = (r.crossing or {}).get("taken", "")
    assert taken[True].startswith(PREFIX + "left_arm") and not taken[False].startswith(PREFIX), taken
    assert v2v[True] < 1.5 < 3.0 < v2v[False], v2v
    assert PARENTS[16] == 13  # the arm hangs from the collar: the chain the limb table names
