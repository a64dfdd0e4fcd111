"""Pose sources: synthetic in-distribution (DFAUST-like) and out-of-distribution (PosePrior-like) poses.

Every source has the same interface (:class:`PoseSource`): ``len(source)`` (``None`` from
``source.num_poses`` when infinite) and ``sample(index, generator) -> dict`` with

- ``pose``: ``[22, 3]`` float64 local axis-angle (SMPL convention, root includes the global orientation),
- ``betas``: ``[nb]`` float64 or ``None`` (the dataset then samples betas from the body's shape space),
- ``transl``: ``[3]`` float64 or ``None``.

Axes follow SMPL: y up, the body faces +z, +x is the body's left; the rest pose is a T-pose, so a
local rotation is expressed in world axes at the joint. Joint angles below are intrinsic XYZ Euler
angles in degrees, ``R = Rx(a) Ry(b) Rz(c)``, given for the LEFT side; the right side is the mirror image
(x kept, y and z negated). Useful signs (left side): hip flexion (thigh forward) is -x, knee flexion +x,
ankle dorsiflexion -x, spine/neck forward bend +x, shoulder raise (arm up) +z, arm down -z, shoulder
forward -y, elbow flexion -y, hip abduction +z.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import roma
import torch

from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS
from arteq.geometry.rotations import euler_to_rotmat, random_rotmat

J = {name: i for i, name in enumerate(JOINT_NAMES)}
_LEFT_RIGHT = [(J[n], J["right_" + n[5:]]) for n in JOINT_NAMES if n.startswith("left_")]
_LI = [li for li, _ in _LEFT_RIGHT]
_RI = [ri for _, ri in _LEFT_RIGHT]
_MIRROR = torch.tensor([1.0, -1.0, -1.0])


# ----------------------------------------------------------------------------------------------
# Small helpers


def mirror_left_to_right(angles: torch.Tensor) -> torch.Tensor:
    """Fill right-side joints of ``[..., 22, 3]`` Euler angles as the mirror image of the left side.

    Reflection x -> -x maps a rotation with Euler angles (a, b, c) to (a, -b, -c).
    """
    out = angles.clone()
    out[..., _RI, :] = angles[..., _LI, :] * _MIRROR.to(angles)
    return out


def _u(g: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * torch.rand((), generator=g, dtype=torch.float64).item()


class PoseSource:
    """Interface: ``num_poses`` (``None`` = infinite), ``sample(index, generator)``, ``fingerprint()``."""

    num_poses: int | None = None

    def __len__(self) -> int:
        if self.num_poses is None:
            raise TypeError(f"{type(self).__name__} is infinite (num_poses is None)")
        return self.num_poses

    def sample(self, index: int, generator: torch.Generator) -> dict[str, torch.Tensor | None]:
        raise TypeError(f"{type(self).__name__} does not define sample()")

    def fingerprint(self) -> dict:
        """Plain values that identify the pose distribution (used in cache keys)."""
        return {"class": type(self).__name__}


# ----------------------------------------------------------------------------------------------
# In-distribution: everyday motions performed upright (DFAUST-like)

# Each family maps (phase in [0, 2pi), amplitude in ~[0.7, 1.15], side in {+1, -1}) to left-side Euler
# angles of the named joints (degrees); unnamed joints stay at the neutral standing pose.
Family = Callable[[float, float, float], dict[str, tuple[float, float, float]]]

_ARMS_DOWN = -65.0  # shoulder z of relaxed arms (A-pose-like)


def _jumping_jacks(ph: float, a: float, side: float) -> dict:
    t = 0.5 * (1 - math.cos(ph))
    return {
        "left_shoulder": (0, 0, _ARMS_DOWN + t * a * 140),
        "left_collar": (0, 0, 12 * t),
        "left_hip": (0, 0, t * a * 16),
        "left_knee": (12 * math.sin(ph) ** 2, 0, 0),
        "left_elbow": (0, -10 * t, 0),
    }


def _punches(ph: float, a: float, side: float) -> dict:
    # The left arm punches on the first half period; the right arm on the second (set by mirroring).
    t = max(0.0, math.sin(ph)) * a
    return {
        "left_shoulder": (0, -40 - 50 * t, -55 + 55 * t),
        "left_elbow": (0, -115 * (1 - min(t, 1.0)), 0),
        "spine2": (0, 12 * a * math.sin(ph), 0),
        "left_knee": (15, 0, 0),
        "left_hip": (-10, 0, 0),
    }


def _knee_raises(ph: float, a: float, side: float) -> dict:
    t = max(0.0, math.sin(ph))
    return {
        "left_hip": (-a * 95 * t, 0, 0),
        "left_knee": (a * 100 * t, 0, 0),
        "left_ankle": (15 * t, 0, 0),
        "left_shoulder": (0, 25 * a * math.sin(ph), _ARMS_DOWN - 5),
        "left_elbow": (0, -30, 0),
    }


def _running(ph: float, a: float, side: float) -> dict:
    return {
        "left_hip": (-a * (25 + 35 * math.sin(ph)), 0, 0),
        "left_knee": (a * (70 + 45 * math.sin(ph - 0.6)), 0, 0),
        "left_ankle": (10 * math.sin(ph), 0, 0),
        "left_shoulder": (0, 35 * a * math.sin(ph), -70),
        "left_elbow": (0, -85, 0),
        "spine1": (8, 0, 0),
    }


def _arm_circles(ph: float, a: float, side: float) -> dict:
    return {
        "left_shoulder": (0, 55 * a * math.cos(ph), -20 + 60 * a * math.sin(ph)),
        "left_elbow": (0, -10, 0),
    }


def _squats(ph: float, a: float, side: float) -> dict:
    t = 0.5 * (1 - math.cos(ph)) * a
    return {
        "pelvis": (20 * t, 0, 0),
        "left_hip": (-105 * t, 0, 8 * t),
        "left_knee": (120 * t, 0, 0),
        "left_ankle": (-25 * t, 0, 0),
        "spine1": (12 * t, 0, 0),
        "left_shoulder": (0, -85 * t, _ARMS_DOWN * (1 - t)),
    }


def _torso_twists(ph: float, a: float, side: float) -> dict:
    s = math.sin(ph) * a
    return {
        "spine1": (0, 12 * s, 0),
        "spine2": (0, 12 * s, 0),
        "spine3": (0, 12 * s, 0),
        "neck": (0, -8 * s, 0),
        "left_shoulder": (0, -20, -45),
        "left_elbow": (0, -95, 0),
    }


def _one_leg_balance(ph: float, a: float, side: float) -> dict:
    s = math.sin(ph)
    return {
        "left_hip": (-a * (30 + 30 * (1 + s) / 2), 0, 10),
        "left_knee": (60 + 40 * a, 0, 0),
        "left_shoulder": (0, 0, -25 + 15 * s),
        "spine2": (0, 0, 5 * s),
    }


def _hip_circles(ph: float, a: float, side: float) -> dict:
    s, c = math.sin(ph) * a, math.cos(ph) * a
    return {
        "pelvis": (10 * c, 0, 10 * s),
        "spine1": (-6 * c, 0, -6 * s),
        "spine2": (-3 * c, 0, -3 * s),
        "left_shoulder": (0, 15, -70),
        "left_elbow": (0, -100, 0),
    }


def _side_bends(ph: float, a: float, side: float) -> dict:
    s = math.sin(ph) * a
    return {
        "spine1": (0, 0, 10 * s),
        "spine2": (0, 0, 10 * s),
        "spine3": (0, 0, 8 * s),
        "left_shoulder": (0, 0, _ARMS_DOWN + 145 * max(0.0, -math.sin(ph))),
    }


#: name -> (family function, is_asymmetric: the right side runs half a period later)
ID_FAMILIES: dict[str, tuple[Family, bool]] = {
    "jumping_jacks": (_jumping_jacks, False),
    "punches": (_punches, True),
    "knee_raises": (_knee_raises, True),
    "running_on_spot": (_running, True),
    "arm_circles": (_arm_circles, False),
    "squats": (_squats, False),
    "torso_twists": (_torso_twists, False),
    "one_leg_balance": (_one_leg_balance, False),
    "hip_circles": (_hip_circles, False),
    "side_bends": (_side_bends, True),
}

_CENTRAL = {"pelvis", "spine1", "spine2", "spine3", "neck", "head"}


def _family_angles(name: str, phase: float, amp: float, side: float) -> torch.Tensor:
    """Euler angles ``[22, 3]`` (degrees) of one family at one phase; both sides filled."""
    fn, asym = ID_FAMILIES[name]
    base = torch.zeros(NUM_JOINTS, 3, dtype=torch.float64)
    base[J["left_shoulder"], 2] = _ARMS_DOWN
    left = base.clone()
    for jn, v in fn(phase, amp, side).items():
        left[J[jn]] = torch.tensor(v, dtype=torch.float64)
    out = mirror_left_to_right(left)
    if asym:  # right limbs: same motion half a period later, mirrored
        right_src = base.clone()
        for jn, v in fn(phase + math.pi, amp, side).items():
            if jn not in _CENTRAL:
                right_src[J[jn]] = torch.tensor(v, dtype=torch.float64)
        mirrored = mirror_left_to_right(right_src)
        for _, ri in _LEFT_RIGHT:
            out[ri] = mirrored[ri]
    if name == "one_leg_balance" and side < 0:  # lift the right leg instead: mirror the whole pose
        out = _swap_sides(out)
    return out


def _swap_sides(angles: torch.Tensor) -> torch.Tensor:
    """Mirror a whole pose ``[22, 3]`` (Euler degrees) through the body's sagittal plane."""
    out = angles.clone()
    for li, ri in _LEFT_RIGHT:
        out[li], out[ri] = angles[ri].clone(), angles[li].clone()
    out[..., :, 1:] *= -1
    return out


#: Extra range of the widened everyday poses (``SyntheticIDPoses(wide_prob=...)``, training only), left side
#: and central joints, intrinsic XYZ Euler degrees ``(x, y, z)``: a widened draw adds ``U(-r, r)`` per axis
#: (each side on its own), clipped to :data:`JOINT_LIMITS_DEG`. Where the narrow motions barely move and
#: OOD accuracy collapsed (collars, shoulders, elbows, wrists, neck, head; docs/data.md).
WIDE_ID_RANGES_DEG: dict[str, tuple[float, float, float]] = {
    "left_collar": (10.0, 15.0, 15.0),
    "left_shoulder": (40.0, 35.0, 35.0),
    "left_elbow": (50.0, 40.0, 0.0),
    "left_wrist": (25.0, 25.0, 50.0),
    "neck": (25.0, 30.0, 20.0),
    "head": (15.0, 20.0, 10.0),
}


class SyntheticIDPoses(PoseSource):
    """In-distribution poses: upright everyday motions with a continuous phase (DFAUST-like).

    A sample picks a family (uniformly), a phase ``U(0, 2pi)``, an amplitude ``U(0.7, 1.15)`` and a side,
    adds ``N(0, joint_noise_deg^2)`` to every non-root Euler angle, and orients the root upright with a
    yaw ``U(-max_yaw_deg, max_yaw_deg)`` and a tilt ``N(0, tilt_deg^2)`` about x and z. Infinite.

    ``wide_prob``: the probability that a draw is widened by :data:`WIDE_ID_RANGES_DEG` (training poses
    only: validation and test_id keep the narrow motions, so the ID test stays what it was). With 0 the
    random stream and the fingerprint are those of the narrow source.
    """

    def __init__(
        self,
        families: list[str] | None = None,
        joint_noise_deg: float = 3.0,
        max_yaw_deg: float = 30.0,
        tilt_deg: float = 3.0,
        wide_prob: float = 0.0,
    ) -> None:
        self.families = list(families) if families else list(ID_FAMILIES)
        unknown = [f for f in self.families if f not in ID_FAMILIES]
        if unknown:
            raise ValueError(f"unknown ID motion families {unknown}; known: {sorted(ID_FAMILIES)}")
        if not 0.0 <= float(wide_prob) <= 1.0:
            raise ValueError(f"SyntheticIDPoses: wide_prob must be in [0, 1], got {wide_prob}")
        self.joint_noise_deg = joint_noise_deg
        self.max_yaw_deg = max_yaw_deg
        self.tilt_deg = tilt_deg
        self.wide_prob = float(wide_prob)
        self.num_poses = None

    def fingerprint(self) -> dict:
        fp = {
            "class": "SyntheticIDPoses",
            "families": self.families,
            "joint_noise_deg": self.joint_noise_deg,
            "max_yaw_deg": self.max_yaw_deg,
            "tilt_deg": self.tilt_deg,
            "version": 1,
        }
        if self.wide_prob > 0:
            fp |= {"wide_prob": self.wide_prob, "wide_ranges": WIDE_ID_RANGES_DEG}
        return fp

    def euler(self, generator: torch.Generator) -> torch.Tensor:
        """One pose as Euler angles ``[22, 3]`` (degrees); the root entry holds the family's root bend."""
        fam = self.families[int(torch.randint(len(self.families), (), generator=generator))]
        phase = _u(generator, 0, 2 * math.pi)
        amp = _u(generator, 0.7, 1.15)
        side = 1.0 if torch.rand((), generator=generator) < 0.5 else -1.0
        ang = _family_angles(fam, phase, amp, side)
        noise = torch.randn(NUM_JOINTS, 3, generator=generator, dtype=torch.float64) * self.joint_noise_deg
        noise[0] = 0
        ang = ang + noise
        if self.wide_prob > 0 and torch.rand((), generator=generator) < self.wide_prob:
            ang = _widen(ang, generator)
        return ang

    def sample(self, index: int, generator: torch.Generator) -> dict:
        ang = self.euler(generator)
        rot = euler_to_rotmat(ang)
        yaw = _u(generator, -self.max_yaw_deg, self.max_yaw_deg)
        tilt = torch.randn(2, generator=generator, dtype=torch.float64) * self.tilt_deg
        upright = euler_to_rotmat(torch.tensor([0.0, yaw, 0.0], dtype=torch.float64)) @ euler_to_rotmat(
            torch.tensor([tilt[0].item(), 0.0, tilt[1].item()], dtype=torch.float64)
        )
        rot[0] = upright @ rot[0]
        return {"pose": roma.rotmat_to_rotvec(rot), "betas": None, "transl": None}


def _widen(ang: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
    """``ang [22, 3]`` plus ``U(-r, r)`` of :data:`WIDE_ID_RANGES_DEG` (both sides, independently), clipped
    to the joint limits."""
    r = torch.zeros(NUM_JOINTS, 3, dtype=torch.float64)
    for name, v in WIDE_ID_RANGES_DEG.items():
        r[J[name]] = torch.tensor(v, dtype=torch.float64)
    r = mirror_left_to_right(r).abs()
    u = torch.rand(NUM_JOINTS, 3, generator=generator, dtype=torch.float64) * 2 - 1
    lo, hi = joint_limit_bounds()
    out = ang + r * u
    moved = r > 0
    out[moved] = torch.minimum(torch.maximum(out, lo), hi)[moved]
    return out


# ----------------------------------------------------------------------------------------------
# Out-of-distribution: extreme poses within joint limits, any root orientation (PosePrior-like)

#: Joint limits, intrinsic XYZ Euler degrees (x, y, z) as (lo, hi), LEFT side and central joints; the right
#: side is mirrored. Loosely after clinical range-of-motion tables (AAOS), split over SMPL's joints.
JOINT_LIMITS_DEG: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    "spine1": ((-15, 35), (-15, 15), (-15, 15)),
    "spine2": ((-10, 30), (-15, 15), (-12, 12)),
    "spine3": ((-10, 25), (-15, 15), (-12, 12)),
    "neck": ((-40, 45), (-45, 45), (-30, 30)),
    "head": ((-25, 30), (-30, 30), (-15, 15)),
    "left_hip": ((-125, 25), (-40, 45), (-30, 50)),  # flexion -x (to 125), abduction +z
    "left_knee": ((0, 150), (-10, 10), (-5, 5)),  # flexion +x
    "left_ankle": ((-25, 50), (-20, 20), (-25, 25)),  # dorsiflexion -x, plantarflexion +x
    "left_foot": ((-35, 30), (-5, 5), (-5, 5)),  # toes
    "left_collar": ((-15, 15), (-20, 20), (-15, 30)),
    "left_shoulder": ((-90, 90), (-130, 45), (-85, 95)),  # twist x, forward -y (crosses body), up +z
    "left_elbow": ((-80, 80), (-150, 0), (-5, 5)),  # pronation/supination x, flexion -y
    "left_wrist": ((-30, 30), (-30, 30), (-75, 75)),
}

#: A trained athlete's range (gymnasts, dancers): :data:`JOINT_LIMITS_DEG` with the spine, neck, hips, knees
#: and shoulders opened up: a back bend through the spine, splits (hip abduction to 90, extension to 60),
#: the arms overhead (elevation to 170) and behind the body. Chosen by hand from those poses' descriptions,
#: not fitted to any test set; ``data.train_pose_mix``'s ``athletic`` source (docs/data.md).
ATHLETIC_LIMITS_DEG: dict[str, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]] = {
    **JOINT_LIMITS_DEG,
    "spine1": ((-35, 45), (-25, 25), (-25, 25)),
    "spine2": ((-30, 40), (-25, 25), (-20, 20)),
    "spine3": ((-30, 35), (-25, 25), (-20, 20)),
    "neck": ((-60, 50), (-60, 60), (-40, 40)),
    "left_hip": ((-150, 60), (-50, 50), (-35, 90)),
    "left_knee": ((0, 160), (-10, 10), (-5, 5)),
    "left_shoulder": ((-90, 90), (-135, 90), (-90, 170)),
}

#: The joints :class:`SyntheticOODPoses` bends together with its ``spine_chain_prob``.
SPINE_CHAIN = ("spine1", "spine2", "spine3")

#: Extreme templates mixed into the OOD draw (left side / central, degrees); the rest uniform in limits.
OOD_TEMPLATES: dict[str, dict[str, tuple[float, float, float]]] = {
    "sit_on_floor": {"left_hip": (-95, 0, 15), "left_knee": (5, 0, 0), "spine1": (20, 0, 0)},
    "deep_squat": {"left_hip": (-120, 0, 25), "left_knee": (145, 0, 0), "left_ankle": (-25, 0, 0)},
    "arms_overhead": {"left_shoulder": (0, -10, 90), "left_elbow": (0, -20, 0)},
    "crossed_arms": {"left_shoulder": (0, -125, -40), "left_elbow": (0, -120, 0)},
    "crossed_legs": {"left_hip": (-40, 30, -28), "left_knee": (60, 0, 0)},
    "toe_touch": {"spine1": (35, 0, 0), "spine2": (30, 0, 0), "spine3": (25, 0, 0), "left_hip": (-110, 0, 0)},
}


def joint_limit_bounds(limits: Mapping[str, Any] | None = None) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-joint Euler bounds ``lo, hi [22, 3]`` (degrees) of ``limits`` (default
    :data:`JOINT_LIMITS_DEG`; left side and central joints), the right side mirrored; the root's are 0
    (it has none)."""
    lo = torch.zeros(NUM_JOINTS, 3, dtype=torch.float64)
    hi = torch.zeros(NUM_JOINTS, 3, dtype=torch.float64)
    for name, lims in (JOINT_LIMITS_DEG if limits is None else limits).items():
        for ax, (a, b) in enumerate(lims):
            lo[J[name], ax], hi[J[name], ax] = a, b
    # mirror: x kept, y/z negated (bounds swap)
    for li, ri in _LEFT_RIGHT:
        lo[ri, 0], hi[ri, 0] = lo[li, 0], hi[li, 0]
        lo[ri, 1:], hi[ri, 1:] = -hi[li, 1:], -lo[li, 1:]
    return lo, hi


class SyntheticOODPoses(PoseSource):
    """Out-of-distribution poses: per-joint Euler angles across ``limits`` (default :data:`JOINT_LIMITS_DEG`;
    :data:`ATHLETIC_LIMITS_DEG` for the ``athletic`` training source), Haar-uniform root.

    With probability ``template_prob`` one or two of :data:`OOD_TEMPLATES` (each applied to a random side
    or both) set their joints, jittered by ``U(-15, 15)`` degrees and clipped to the limits; all other
    non-root joints are uniform within their limits. The root orientation is Haar-uniform (lying,
    inverted, ...). Disjoint from ID by construction: a draw whose mean non-root geodesic distance to
    every pose of a fixed bank of ``id_bank_size`` ID poses is below ``min_gap_deg`` is rejected and
    redrawn (with the default 15 degrees this practically never happens; see docs/data.md for the
    measured gap). Infinite.

    With probability ``spine_chain_prob`` (default 0: the draw is the same as without it, random number for
    random number) the spine's joints (:data:`SPINE_CHAIN`) bend together: per axis (flexion, twist,
    side bend) one shared fraction ``f ~ U(0, 1)`` of the range, each joint at ``f`` plus ``N(0, 0.1)``
    of its own range, clipped. A spine bends through all its segments at once (a back bend, a pike, a
    side bend); independent uniform draws almost never put all three segments near the same end of their
    ranges (about 1 draw in 1000 within the last 10 %).
    """

    def __init__(
        self,
        template_prob: float = 0.4,
        min_gap_deg: float = 15.0,
        id_bank_size: int = 512,
        id_source: SyntheticIDPoses | None = None,
        limits: Mapping[str, Any] | None = None,
        spine_chain_prob: float = 0.0,
    ) -> None:
        if not 0.0 <= spine_chain_prob <= 1.0:
            raise ValueError(f"SyntheticOODPoses: spine_chain_prob must be in [0, 1], got {spine_chain_prob}")
        self.template_prob = template_prob
        self.spine_chain_prob = float(spine_chain_prob)
        self.min_gap_deg = min_gap_deg
        self.id_bank_size = id_bank_size
        self.id_source = SyntheticIDPoses() if id_source is None else id_source
        self.limits = JOINT_LIMITS_DEG if limits is None else dict(limits)
        self.lo, self.hi = joint_limit_bounds(self.limits)
        self.num_poses = None
        self._bank: torch.Tensor | None = None

    def fingerprint(self) -> dict:
        fp = {
            "class": "SyntheticOODPoses",
            "template_prob": self.template_prob,
            "min_gap_deg": self.min_gap_deg,
            "id_bank_size": self.id_bank_size,
            "id": self.id_source.fingerprint(),
            "limits": self.limits,
            "version": 1,
        }
        if self.spine_chain_prob > 0:  # only then: the sets drawn before it keep their fingerprints
            fp["spine_chain_prob"] = self.spine_chain_prob
        return fp

    def _id_bank(self) -> torch.Tensor:
        if self._bank is None:
            g = torch.Generator().manual_seed(987654321)
            poses = torch.stack([self.id_source.sample(i, g)["pose"] for i in range(self.id_bank_size)])
            self._bank = roma.rotvec_to_rotmat(poses)
        return self._bank

    def euler(self, generator: torch.Generator) -> torch.Tensor:
        """Non-root Euler angles ``[22, 3]`` (degrees, root entry zero)."""
        u = torch.rand(NUM_JOINTS, 3, generator=generator, dtype=torch.float64)
        if self.spine_chain_prob > 0 and torch.rand((), generator=generator) < self.spine_chain_prob:
            idx = torch.tensor([J[n] for n in SPINE_CHAIN])
            shared = torch.rand(1, 3, generator=generator, dtype=torch.float64)
            own = torch.randn(len(SPINE_CHAIN), 3, generator=generator, dtype=torch.float64) * 0.1
            u[idx] = (shared + own).clamp(0.0, 1.0)
        ang = self.lo + (self.hi - self.lo) * u
        if torch.rand((), generator=generator) < self.template_prob:
            names = list(OOD_TEMPLATES)
            k = 1 + int(torch.rand((), generator=generator) < 0.5)
            for _ in range(k):
                tmpl = OOD_TEMPLATES[names[int(torch.randint(len(names), (), generator=generator))]]
                which = int(torch.randint(3, (), generator=generator))  # 0 left, 1 right, 2 both
                left = torch.zeros(NUM_JOINTS, 3, dtype=torch.float64)
                mask = torch.zeros(NUM_JOINTS, dtype=torch.bool)
                for jn, v in tmpl.items():
                    left[J[jn]] = torch.tensor(v, dtype=torch.float64)
                    mask[J[jn]] = True
                both = mirror_left_to_right(left)
                mboth = mask.clone()
                for li, ri in _LEFT_RIGHT:
                    mboth[ri] = mask[li]
                jitter = (torch.rand(NUM_JOINTS, 3, generator=generator, dtype=torch.float64) - 0.5) * 30
                for idx in torch.nonzero(mboth).flatten().tolist():
                    name = JOINT_NAMES[idx]
                    if (which == 0 and name.startswith("right_")) or (
                        which == 1 and name.startswith("left_")
                    ):
                        continue
                    ang[idx] = both[idx] + jitter[idx]
            ang = torch.minimum(torch.maximum(ang, self.lo), self.hi)
        ang[0] = 0
        return ang

    def sample(self, index: int, generator: torch.Generator) -> dict:
        bank = self._id_bank() if self.min_gap_deg > 0 else None
        for _ in range(100):
            rot = euler_to_rotmat(self.euler(generator))
            if bank is None or nearest_pose_distance(rot[None], bank)[0] >= math.radians(self.min_gap_deg):
                break
        else:
            raise RuntimeError("SyntheticOODPoses: 100 draws in a row were too close to the ID bank")
        rot[0] = random_rotmat(1, generator)[0]
        return {"pose": roma.rotmat_to_rotvec(rot), "betas": None, "transl": None}


# ----------------------------------------------------------------------------------------------
# Graded out-of-distribution sets: how far generalisation reaches

#: Limbs of the graded OOD sets (joints drawn from the OOD sampler together).
LIMBS: dict[str, tuple[str, ...]] = {
    "left_arm": ("left_collar", "left_shoulder", "left_elbow", "left_wrist"),
    "right_arm": ("right_collar", "right_shoulder", "right_elbow", "right_wrist"),
    "left_leg": ("left_hip", "left_knee", "left_ankle", "left_foot"),
    "right_leg": ("right_hip", "right_knee", "right_ankle", "right_foot"),
}


class LimbOODPoses(PoseSource):
    """An everyday pose with ``num_limbs`` of its four limbs (:data:`LIMBS`, chosen uniformly) taken from
    the OOD sampler, and a Haar-uniform root orientation: the graded scale between the ID and the hard
    OOD set (one limb out of distribution, then two). Infinite."""

    def __init__(
        self,
        num_limbs: int = 1,
        id_source: SyntheticIDPoses | None = None,
        ood_source: SyntheticOODPoses | None = None,
    ) -> None:
        if not 1 <= int(num_limbs) <= len(LIMBS):
            raise ValueError(f"LimbOODPoses: num_limbs must be in [1, {len(LIMBS)}], got {num_limbs}")
        self.num_limbs = int(num_limbs)
        self.id_source = SyntheticIDPoses() if id_source is None else id_source
        self.ood_source = SyntheticOODPoses(id_source=self.id_source) if ood_source is None else ood_source
        self.num_poses = None

    def fingerprint(self) -> dict:
        return {
            "class": "LimbOODPoses",
            "num_limbs": self.num_limbs,
            "limbs": LIMBS,
            "id": self.id_source.fingerprint(),
            "ood": self.ood_source.fingerprint(),
            "version": 1,
        }

    def euler(self, generator: torch.Generator) -> tuple[torch.Tensor, list[str]]:
        """Euler angles ``[22, 3]`` (degrees: an ID draw, then an OOD draw for the chosen limbs) and the
        names of the limbs taken from the OOD draw."""
        ang = self.id_source.euler(generator)
        ood = self.ood_source.euler(generator)
        names = list(LIMBS)
        chosen = [
            names[i] for i in torch.randperm(len(names), generator=generator)[: self.num_limbs].tolist()
        ]
        for limb in chosen:
            idx = [J[n] for n in LIMBS[limb]]
            ang[idx] = ood[idx]
        return ang, chosen

    def sample(self, index: int, generator: torch.Generator) -> dict:
        ang, _ = self.euler(generator)
        rot = euler_to_rotmat(ang)
        rot[0] = random_rotmat(1, generator)[0] @ rot[0]
        return {"pose": roma.rotmat_to_rotvec(rot), "betas": None, "transl": None}


def _tree_distance() -> torch.Tensor:
    """Edges between parts of the 22-part tree ``[22, 22]`` (0 on the diagonal)."""
    from arteq.body.skeleton import PARENTS

    d = torch.full((NUM_JOINTS, NUM_JOINTS), NUM_JOINTS, dtype=torch.long)
    d.fill_diagonal_(0)
    for j, p in enumerate(PARENTS):
        if p >= 0:
            d[j, p] = d[p, j] = 1
    for k in range(NUM_JOINTS):  # Floyd-Warshall on 22 nodes
        d = torch.minimum(d, d[:, k : k + 1] + d[k : k + 1, :])
    return d


def contact_fraction(
    vertices: torch.Tensor, part: torch.Tensor, clearance: float = 0.04, max_tree_distance: int = 2
) -> float:
    """Fraction of ``vertices [V, 3]`` within ``clearance`` metres of a vertex of a part more than
    ``max_tree_distance`` edges away in the body tree (``part [V]``: each vertex's part): self-contact
    and interpenetration of parts that are not neighbours (siblings such as the two thighs, and
    grandparents, count as neighbours)."""
    far = _tree_distance()[part][:, part] > max_tree_distance  # [V, V]
    d = torch.cdist(vertices.double(), vertices.double())
    return float(((d < clearance) & far).any(-1).double().mean())


class ContactRejectedPoses(PoseSource):
    """A pose source whose draws with self-contact are redrawn: PosePrior-like (extreme but physically
    plausible) poses from :class:`SyntheticOODPoses`.

    A draw is kept when, on ``body`` (mean shape) in that pose, at most ``max_fraction`` of a fixed
    subset of ``vertices`` vertices lie within ``clearance`` metres of a non-neighbouring part
    (:func:`contact_fraction`); everyday ID poses have about 1 % (docs/data.md). Infinite.
    """

    def __init__(
        self,
        body: torch.nn.Module,
        base: PoseSource | None = None,
        clearance: float = 0.04,
        max_fraction: float = 0.01,
        vertices: int = 1500,
        max_tries: int = 200,
    ) -> None:
        self.base = SyntheticOODPoses() if base is None else base
        self.body = body
        self.clearance, self.max_fraction = float(clearance), float(max_fraction)
        nv = int(body.lbs_weights.shape[0])
        self.subset = torch.linspace(0, nv - 1, min(int(vertices), nv)).round().long()
        self.part = body.lbs_weights.argmax(-1)[self.subset]
        self.max_tries = int(max_tries)
        self.num_poses = None

    def fingerprint(self) -> dict:
        return {
            "class": "ContactRejectedPoses",
            "base": self.base.fingerprint(),
            "clearance": self.clearance,
            "max_fraction": self.max_fraction,
            "vertices": int(self.subset.numel()),
            "version": 1,
        }

    def contact(self, pose: torch.Tensor) -> float:
        """:func:`contact_fraction` of a pose ``[22, 3]`` (axis-angle) on the body's mean shape."""
        with torch.no_grad():
            verts = self.body(pose=pose[None].to(self.body.lbs_weights.dtype)).vertices[0]
        return contact_fraction(verts[self.subset], self.part, self.clearance)

    def sample(self, index: int, generator: torch.Generator) -> dict:
        for _ in range(self.max_tries):
            s = self.base.sample(index, generator)
            if self.contact(s["pose"]) <= self.max_fraction:
                return s
        raise RuntimeError(
            f"ContactRejectedPoses: {self.max_tries} draws in a row had more than {self.max_fraction:.1%} of "
            f"the body within {self.clearance} m of a non-neighbouring part"
        )


class MixedPoses(PoseSource):
    """Each draw from one of several pose sources, picked with fixed probabilities: training on a broad
    pose distribution (``data.train_pose_mix``, e.g. everyday motions mixed with the OOD sampler).

    ``sources`` and ``weights`` are keyed alike; weights are non-negative and normalised. The pick uses
    the sample's own generator, so a draw is reproducible from its seed. When ``sources`` holds ``id``
    with a finite length (AMASS frames), the mixture has that length and an ``id`` pick returns frame
    ``index``; otherwise it is infinite.
    """

    def __init__(self, sources: dict[str, PoseSource], weights: dict[str, float]) -> None:
        if set(sources) != set(weights):
            raise ValueError(f"MixedPoses: sources {sorted(sources)} and weights {sorted(weights)} differ")
        bad = {k: w for k, w in weights.items() if not (float(w) >= 0 and math.isfinite(float(w)))}
        if bad or not sources or sum(float(w) for w in weights.values()) <= 0:
            raise ValueError(f"MixedPoses: weights must be finite, >= 0 and not all 0, got {dict(weights)}")
        self.names = [k for k in sources if float(weights[k]) > 0]
        self.sources = {k: sources[k] for k in self.names}
        total = sum(float(weights[k]) for k in self.names)
        self.weights = {k: float(weights[k]) / total for k in self.names}
        self._cum = torch.tensor([self.weights[k] for k in self.names], dtype=torch.float64).cumsum(0)
        self.num_poses = self.sources["id"].num_poses if "id" in self.sources else None

    def fingerprint(self) -> dict:
        return {
            "class": "MixedPoses",
            "weights": self.weights,
            "sources": {k: s.fingerprint() for k, s in self.sources.items()},
            "version": 1,
        }

    def pick(self, generator: torch.Generator) -> str:
        u = float(torch.rand((), generator=generator, dtype=torch.float64))
        i = int(torch.searchsorted(self._cum, torch.tensor(u, dtype=torch.float64), right=True))
        return self.names[min(i, len(self.names) - 1)]

    def sample(self, index: int, generator: torch.Generator) -> dict:
        return self.sources[self.pick(generator)].sample(index, generator)


# ----------------------------------------------------------------------------------------------
# Distances between pose sets


def nearest_pose_distance(
    query: torch.Tensor, ref: torch.Tensor, include_root: bool = False, chunk: int = 256
) -> torch.Tensor:
    """Mean per-joint geodesic distance (radians) from each query pose to its nearest reference pose.

    Nearest = smallest mean over joints of the geodesic angle between local rotations.

    Args:
        query: ``[M, 22, 3, 3]`` local rotation matrices.
        ref: ``[K, 22, 3, 3]``.
        include_root: average over all 22 joints (else the 21 non-root joints).
    Returns:
        ``[M]`` radians.
    """
    if query.shape[-3:] != (NUM_JOINTS, 3, 3) or ref.shape[-3:] != (NUM_JOINTS, 3, 3):
        raise ValueError(f"expected [*, 22, 3, 3] poses, got {tuple(query.shape)} and {tuple(ref.shape)}")
    sl = slice(0, NUM_JOINTS) if include_root else slice(1, NUM_JOINTS)
    q = query[:, sl].reshape(query.shape[0], -1, 9).double()
    r = ref[:, sl].reshape(ref.shape[0], -1, 9).double()
    out = []
    for s in range(0, q.shape[0], chunk):
        qc = q[s : s + chunk]  # [m, J, 9]
        tr = torch.einsum("mjc,kjc->mkj", qc, r)  # trace(Rq^T Rr)
        ang = torch.acos(((tr - 1) / 2).clamp(-1, 1)).mean(-1)  # [m, K]
        out.append(ang.min(-1).values)
    return torch.cat(out)


def draw_poses(source: PoseSource, n: int, seed: int) -> torch.Tensor:
    """``n`` local rotation matrices ``[n, 22, 3, 3]`` from ``source`` (one generator seeded ``seed``)."""
    g = torch.Generator().manual_seed(seed)
    return roma.rotvec_to_rotmat(torch.stack([source.sample(i, g)["pose"] for i in range(n)]).double())


def pose_set_gaps(
    reference: PoseSource,
    queries: dict[str, PoseSource],
    n_ref: int = 5000,
    n_query: int = 500,
    seed: int = 0,
    include_root: bool = False,
) -> dict[str, dict[str, float]]:
    """Mean (and 5th percentile) nearest-reference distance in degrees of each query set: how far each
    test set lies from the poses a model trains on. The reference draw uses seed ``seed``, query ``i``
    (in order) seed ``seed + 1 + i``."""
    ref = draw_poses(reference, n_ref, seed)
    out = {}
    for i, (name, src) in enumerate(queries.items()):
        d = np.degrees(
            nearest_pose_distance(draw_poses(src, n_query, seed + 1 + i), ref, include_root).numpy()
        )
        out[name] = {"mean_deg": float(d.mean()), "p5_deg": float(np.percentile(d, 5))}
    return out


def measure_id_ood_gap(
    n_ref: int = 5000, n_query: int = 500, seed: int = 0, include_root: bool = False
) -> dict[str, float]:
    """Mean nearest-ID distance (degrees) of OOD poses vs of held-out ID poses, synthetic sources.

    The ID reference set uses seed ``seed``; held-out ID and OOD queries use other seeds.
    """
    ref = draw_poses(SyntheticIDPoses(), n_ref, seed)
    held = draw_poses(SyntheticIDPoses(), n_query, seed + 1)
    ood = draw_poses(SyntheticOODPoses(), n_query, seed + 2)
    d_id = np.degrees(nearest_pose_distance(held, ref, include_root).numpy())
    d_ood = np.degrees(nearest_pose_distance(ood, ref, include_root).numpy())
    return {
        "id_mean_deg": float(d_id.mean()),
        "id_p95_deg": float(np.percentile(d_id, 95)),
        "ood_mean_deg": float(d_ood.mean()),
        "ood_min_deg": float(d_ood.min()),
        "gap_ratio": float(d_ood.mean() / d_id.mean()),
    }
