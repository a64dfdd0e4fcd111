"""Pose sources: ID upright motions with correct joint axes, OOD within limits and any orientation, gap."""

import math

import pytest
import roma
import torch

from arteq.body.skeleton import JOINT_NAMES
from arteq.body.toy import ToyBody
from arteq.data.poses import (
    ID_FAMILIES,
    SyntheticIDPoses,
    SyntheticOODPoses,
    _family_angles,
    euler_to_rotmat,
    measure_id_ood_gap,
    nearest_pose_distance,
)

J = {n: i for i, n in enumerate(JOINT_NAMES)}


def _draw(src, n, seed):
    g = torch.Generator().manual_seed(seed)
    return torch.stack([src.sample(i, g)["pose"] for i in range(n)])


def test_euler_matches_roma():
    a = torch.randn(50, 3, dtype=torch.float64) * 70
    assert torch.allclose(euler_to_rotmat(a), roma.euler_to_rotmat("XYZ", a, degrees=True), atol=1e-12)


def test_id_deterministic_and_upright():
    src = SyntheticIDPoses()
    a, b = _draw(src, 64, 3), _draw(src, 64, 3)
    assert torch.equal(a, b) and a.shape == (64, 22, 3) and a.dtype == torch.float64
    assert not torch.equal(a, _draw(src, 64, 4))
    root = roma.rotvec_to_rotmat(a[:, 0])
    up = root[:, :, 1]  # where the body's up axis points
    assert (up[:, 1] > math.cos(math.radians(30))).all()  # tilt (incl. squat pelvis tilt) < 30 degrees


def test_ood_any_orientation_and_within_limits():
    src = SyntheticOODPoses()
    g = torch.Generator().manual_seed(0)
    for _ in range(50):
        ang = src.euler(g)
        assert (ang >= src.lo - 1e-9).all() and (ang <= src.hi + 1e-9).all()
    poses = _draw(src, 200, 1)
    up = roma.rotvec_to_rotmat(poses[:, 0])[:, :, 1]
    assert up.mean(0).norm() < 0.2  # Haar root: up axis spread over the sphere
    assert (up[:, 1] < 0).float().mean() > 0.3  # many inverted / lying bodies


def _posed_joints(euler_deg):
    body = ToyBody()
    rot = euler_to_rotmat(euler_deg).float()[None]
    return body(pose=rot).joints[0]


def test_family_joint_axes_are_anatomical():
    """Wrong signs would bend limbs backwards: check where the joints end up on the toy body."""
    jj = _posed_joints(_family_angles("jumping_jacks", math.pi, 1.0, 1.0))  # arms up
    assert jj[J["left_wrist"], 1] > jj[J["head"], 1] and jj[J["right_wrist"], 1] > jj[J["head"], 1]
    rest = _posed_joints(_family_angles("jumping_jacks", 0.0, 1.0, 1.0))  # arms down
    assert rest[J["left_wrist"], 1] < rest[J["left_shoulder"], 1] - 0.3
    assert rest[J["left_wrist"], 0] > 0 and rest[J["right_wrist"], 0] < 0  # left is +x
    kr = _posed_joints(_family_angles("knee_raises", math.pi / 2, 1.0, 1.0))  # left knee up and forward
    assert kr[J["left_knee"], 2] > kr[J["left_hip"], 2] + 0.25
    assert kr[J["left_ankle"], 2] < kr[J["left_knee"], 2]  # shin hangs down/back, not forward
    assert kr[J["left_knee"], 1] > kr[J["right_knee"], 1] + 0.2
    sq = _posed_joints(_family_angles("squats", math.pi, 1.0, 1.0))  # bottom of a squat
    assert sq[J["left_knee"], 2] > sq[J["pelvis"], 2] + 0.2  # knees forward
    assert sq[J["left_ankle"], 2] < sq[J["left_knee"], 2]  # feet under/behind the knees
    assert sq[J["left_wrist"], 2] > sq[J["spine3"], 2] + 0.3  # arms forward
    pu = _posed_joints(_family_angles("punches", math.pi / 2, 1.0, 1.0))  # left punch extended
    assert pu[J["left_wrist"], 2] > pu[J["left_shoulder"], 2] + 0.4


def test_family_symmetry():
    """Symmetric families are mirror-symmetric: left and right wrists mirror in x."""
    for fam in ("jumping_jacks", "squats", "arm_circles"):
        jt = _posed_joints(_family_angles(fam, 1.0, 1.0, 1.0))
        l, r = jt[J["left_wrist"]], jt[J["right_wrist"]]
        assert torch.allclose(l * torch.tensor([-1.0, 1, 1]), r, atol=1e-5), fam
    assert len(ID_FAMILIES) >= 9


def test_nearest_pose_distance_basic():
    a = roma.rotvec_to_rotmat(_draw(SyntheticIDPoses(), 20, 5))
    d = nearest_pose_distance(a, a)
    assert torch.allclose(d, torch.zeros(20, dtype=torch.float64), atol=1e-6)
    rot = a.clone()
    rot[:, 1:] = rot[:, 1:] @ roma.rotvec_to_rotmat(torch.tensor([0.0, 0.0, 0.1], dtype=torch.float64))
    d = nearest_pose_distance(rot, a)
    assert torch.allclose(d, torch.full((20,), 0.1, dtype=torch.float64), atol=1e-5)
    with pytest.raises(ValueError, match="22, 3, 3"):
        nearest_pose_distance(a[:, :21], a)


def test_id_ood_gap_positive_and_large():
    """OOD poses are far from every ID pose, much farther than held-out ID poses are (see docs/data.md)."""
    gap = measure_id_ood_gap(n_ref=800, n_query=60, seed=11)
    assert gap["ood_mean_deg"] > 3 * gap["id_mean_deg"]
    assert gap["ood_min_deg"] > gap["id_p95_deg"]
    assert gap["ood_mean_deg"] > 25


def test_athletic_source_reaches_past_the_clinical_limits_and_stays_in_its_own():
    from arteq.data.poses import ATHLETIC_LIMITS_DEG, JOINT_LIMITS_DEG, joint_limit_bounds

    clinical = SyntheticOODPoses()
    athletic = SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG)
    assert SyntheticOODPoses(limits=JOINT_LIMITS_DEG).fingerprint() == clinical.fingerprint()
    assert athletic.fingerprint() != clinical.fingerprint()
    lo, hi = joint_limit_bounds()
    alo, ahi = joint_limit_bounds(ATHLETIC_LIMITS_DEG)
    assert (alo <= lo).all() and (ahi >= hi).all()  # a superset, mirrored on the right side alike
    g = torch.Generator().manual_seed(3)
    angles = torch.stack([athletic.euler(g) for _ in range(400)])
    assert (angles >= alo - 1e-9).all() and (angles <= ahi + 1e-9).all()
    up = JOINT_NAMES.index("left_shoulder"), JOINT_NAMES.index("right_shoulder")
    elevation = angles[:, up[0], 2], -angles[:, up[1], 2]  # right side mirrored: y / z negated
    for e in elevation:  # arms overhead beyond the clinical 95 degrees in a fair share of draws
        assert 0.1 < (e > hi[up[0], 2] + 10).float().mean() < 0.5
    hip = JOINT_NAMES.index("left_hip")
    assert ((angles[:, hip, 2] > hi[hip, 2] + 10).float().mean()) > 0.1  # splits


def test_spine_chain_bends_the_spine_together_within_its_limits():
    from arteq.data.poses import ATHLETIC_LIMITS_DEG, SPINE_CHAIN, joint_limit_bounds

    plain = SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG)
    off = SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG, spine_chain_prob=0.0)
    chain = SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG, spine_chain_prob=1.0)
    assert off.fingerprint() == plain.fingerprint()  # the sets drawn before the option keep their keys
    assert chain.fingerprint() != plain.fingerprint()

    def draw(src, n=600):
        g = torch.Generator().manual_seed(7)
        return torch.stack([src.euler(g) for _ in range(n)])

    assert torch.equal(draw(off, 50), draw(plain, 50))  # off: the same draws, random number for number
    lo, hi = joint_limit_bounds(ATHLETIC_LIMITS_DEG)
    spine = [JOINT_NAMES.index(n) for n in SPINE_CHAIN]
    for angles, together in ((draw(plain), False), (draw(chain), True)):
        assert (angles >= lo - 1e-9).all() and (angles <= hi + 1e-9).all()
        for ax in range(3):  # flexion, twist, side bend
            c = torch.corrcoef(angles[:, spine, ax].T)
            assert (c[0, 1:] > 0.7).all() if together else (c[0, 1:] < 0.3).all()
        # all three segments in the last 20 % of their extension (a back bend): rare when independent
        frac = (angles[:, spine, 0] - lo[spine, 0]) / (hi[spine, 0] - lo[spine, 0])
        share = (frac < 0.2).all(dim=1).float().mean()
        assert share > 0.04 if together else share < 0.01
    with pytest.raises(ValueError, match="spine_chain_prob"):
        SyntheticOODPoses(spine_chain_prob=1.5)
