"""Lost limbs: starts that place a whole limb on the scan points the fit leaves off.

A limb the network reads in the wrong place (a side bend's arm raised overhead, fitted hanging down; a
pike's leg folded the wrong way) leaves its points off the fit together, and the refinement, whose kernel
gives far points no pull, does not bring it back: the check sees the group (``off_fit_limb``,
:mod:`arteq.fit.quality`). Started from the truth's limb rotations the same refinement ends within 1-2 cm
(experiments/scan_model/spine/reach/README.md), and the surface score prefers it. What is missing is the
start.

For a fit the check doubts with such a group, each limb (:data:`LIMBS`) whose root joint lies within the
limb's reach of the group is placed as a two-segment chain (upper arm, then forearm and hand; thigh, then
shin) aimed to cover the group: every pair of directions of a sphere grid (then finer around the best) is
scored by how far the group's points lie from the chain's segments (less each segment's thickness) plus how
far the chain's own samples lie from any scan point (a chain through empty space or inside the trunk scores
badly); :func:`reach_starts` turns the best chain into local rotations (the segments turned about their
joints, what hangs from them following). The crossed-limb step (:func:`arteq.fit.crossing.try_swaps`)
refines these starts with its swaps and keeps one only when its surface score is clearly lower.
"""

from __future__ import annotations

import numpy as np
import roma
import torch

from arteq.body.skeleton import JOINT_NAMES, PARENTS
from arteq.geometry.rotations import rotation_between

_J = {n: i for i, n in enumerate(JOINT_NAMES)}
#: limb -> (root joint, middle joint, end joint); the parts named by the root and the middle joints are the
#: chain's two segments, the end joint's part (hand) extends the second segment for arms
LIMBS: dict[str, tuple[int, int, int]] = {
    "left_arm": (_J["left_shoulder"], _J["left_elbow"], _J["left_wrist"]),
    "right_arm": (_J["right_shoulder"], _J["right_elbow"], _J["right_wrist"]),
    "left_leg": (_J["left_hip"], _J["left_knee"], _J["left_ankle"]),
    "right_leg": (_J["right_hip"], _J["right_knee"], _J["right_ankle"]),
}
#: the prefix of a reach start's name in the crossed-limb step's records (``reach_left_arm``)
PREFIX = "reach_"


def _directions(count: int) -> np.ndarray:
    from arteq.fit.refine import sphere_directions

    return sphere_directions(count)


def _segment_dist(p: np.ndarray, a: np.ndarray, u: np.ndarray, length: float) -> torch.Tensor:
    """Distances ``[A, D, M]`` of points ``p [M, 3]`` to the segments from ``a [A, 3]`` along unit
    ``u [D, 3]``
    of ``length``."""
    w = torch.as_tensor(p, dtype=torch.float32)[None] - torch.as_tensor(a, dtype=torch.float32)[:, None]
    proj = torch.einsum("amk,dk->adm", w, torch.as_tensor(u, dtype=torch.float32))  # float32: 10x faster
    t = proj.clamp(0.0, length)
    d2 = (w * w).sum(-1)[:, None] - 2 * t * proj + t * t
    return d2.clamp_min(0.0).sqrt()


def off_group(points: np.ndarray, vertices: np.ndarray, far_m: float, link_m: float) -> np.ndarray:
    """The largest group of ``points`` farther than ``far_m`` from ``vertices``, linked within ``link_m``
    (as the check's :func:`arteq.fit.quality.off_fit_group`): ``[M, 3]``."""
    from scipy.spatial import cKDTree

    from arteq.fit.clean import linked_groups

    far = points[cKDTree(vertices).query(points)[0] > far_m]
    if len(far) < 2:
        return far
    labels = linked_groups(far, link_m)
    return far[labels == np.bincount(labels).argmax()]


def _thickness(vertices: np.ndarray, parts: np.ndarray, part: int, a: np.ndarray, b: np.ndarray) -> float:
    """Median distance (m) of ``part``'s vertices to the bone from ``a`` to ``b``."""
    v = vertices[parts == part]
    if not len(v):
        return 0.0
    u = b - a
    t = np.clip((v - a) @ u / max(float(u @ u), 1e-12), 0.0, 1.0)
    return float(np.median(np.linalg.norm(v - (a + t[:, None] * u), axis=1)))


def place_limb(
    group: np.ndarray,
    scan_tree,
    vertices: np.ndarray,
    joints: np.ndarray,
    parts: np.ndarray,
    limb: str,
    dirs: int = 162,
    cap_m: float = 0.1,
    max_points: int = 256,
) -> tuple[np.ndarray, np.ndarray, float]:
    """The two directions ``(d1, d2, score m)`` that best place ``limb`` (of the fit ``vertices``, ``joints``,
    vertex ``parts``) on ``group [M, 3]``, scored as in the module docstring (``scan_tree``: a ``cKDTree`` of
    the whole scan)."""
    root, mid, end = LIMBS[limb]
    r = joints[root]
    l1 = float(np.linalg.norm(joints[mid] - r))
    l2 = float(np.linalg.norm(joints[end] - joints[mid]))
    rho1 = _thickness(vertices, parts, root, r, joints[mid])
    rho2 = _thickness(vertices, parts, mid, joints[mid], joints[end])
    if limb.endswith("arm"):  # the hand continues the forearm
        hand = vertices[parts == end]
        l2 += float(np.linalg.norm(hand - joints[end], axis=1).max()) if len(hand) else 0.0
    if len(group) > max_points:
        group = group[np.linspace(0, len(group) - 1, max_points).round().astype(int)]
    grid = _directions(dirs)
    t = np.array([0.25, 0.5, 0.75, 1.0])

    def gap(samples: np.ndarray) -> np.ndarray:  # distance to the scan, capped (past the cap: inf -> cap)
        far = max(rho1, rho2) + cap_m
        d = scan_tree.query(samples.reshape(-1, 3), distance_upper_bound=far)[0]
        return np.minimum(d, far).reshape(samples.shape[:-1])

    def scores(d1: np.ndarray, d2: np.ndarray) -> np.ndarray:
        """``[len(d1), len(d2)]``."""
        elbow = r + l1 * d1  # [A, 3]
        near1 = (_segment_dist(group, r[None], d1, l1)[0] - rho1).clamp_min(0.0)  # [A, M]
        near2 = (_segment_dist(group, elbow, d2, l2) - rho2).clamp_min(0.0)  # [A, D, M]
        cover = torch.minimum(near1[:, None], near2).clamp_max(cap_m).mean(-1)
        s1 = r + l1 * t[None, :, None] * d1[:, None]  # [A, 4, 3]
        s2 = elbow[:, None, None] + l2 * t[None, None, :, None] * d2[None, :, None]  # [A, D, 4, 3]
        g1 = np.clip(gap(s1) - rho1, 0.0, cap_m).mean(1)
        g2 = np.clip(gap(s2) - rho2, 0.0, cap_m).mean(2)
        support = (g1[:, None] + g2) / 2
        return cover.double().numpy() + support

    s = scores(grid, grid)
    i, j = np.unravel_index(int(s.argmin()), s.shape)
    best = (grid[i], grid[j], float(s[i, j]))
    for step in (8.0, 4.0):  # finer around the best
        c1, c2 = _tilts(best[0], step), _tilts(best[1], step)
        s = scores(c1, c2)
        i, j = np.unravel_index(int(s.argmin()), s.shape)
        if s[i, j] < best[2]:
            best = (c1[i], c2[j], float(s[i, j]))
    return best


def _tilts(d: np.ndarray, step_deg: float) -> np.ndarray:
    """``d`` and ``d`` tilted by ``step_deg`` four ways: ``[5, 3]``."""
    u = np.cross(d, np.eye(3)[np.argmin(np.abs(d))])
    u /= np.linalg.norm(u)
    tilt = np.stack([u, -u, np.cross(d, u), -np.cross(d, u)]) * np.radians(step_deg)
    return np.concatenate([d[None], roma.rotvec_to_rotmat(torch.as_tensor(tilt)).numpy() @ d])


#: the rest pose faces +z (its feet point there); elbows bend toward the front, knees toward the back
FORWARD = np.array([0.0, 0.0, 1.0])
#: below this angle (degrees) between the two directions a chain is straight: its roll is not read from them
STRAIGHT_DEG = 15.0


def _turned(v: np.ndarray, axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """``v`` turned about unit ``axis`` by ``angle`` (radians; ``[K, 1]`` gives ``[K, 3]``), Rodrigues."""
    c, s = np.cos(angle), np.sin(angle)
    return v * c + np.cross(axis, v) * s + axis * (axis @ v) * (1 - c)


def _frame(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The orthonormal frame ``[3, 3]`` (columns) of unit ``a`` and the part of ``b`` normal to it."""
    e2 = b - (b @ a) * a
    norm = np.linalg.norm(e2)
    e2 = e2 / norm if norm > 1e-9 else np.cross(a, np.eye(3)[np.argmin(np.abs(a))])  # folded back: any plane
    e2 /= np.linalg.norm(e2)
    return np.stack([a, e2, np.cross(a, e2)], axis=1)


def aim_limb(
    local: np.ndarray, global_rot: np.ndarray, joints: np.ndarray, limb: str, d1: np.ndarray, d2: np.ndarray
) -> np.ndarray:
    """Local rotations ``[22, 3, 3]`` with ``limb``'s first segment pointing along ``d1`` and its second along
    ``d2`` (what hangs from them following). The middle joint bends as a hinge the natural way (an elbow
    toward the front, a knee toward the back of its rest pose), as far as opens the segments to the angle
    between ``d1`` and ``d2``; the first segment is rolled about ``d1`` so that the bend lies in their plane.
    A chain nearly straight (:data:`STRAIGHT_DEG`) keeps its roll: each segment turned the least way."""
    from arteq.fit.refine import branch_parts

    root, mid, end = LIMBS[limb]
    g = np.array(global_rot, dtype=np.float64, copy=True)
    out = np.array(local, dtype=np.float64, copy=True)
    d1, d2 = d1 / np.linalg.norm(d1), d2 / np.linalg.norm(d2)
    normal = np.cross(d1, d2)
    angle = float(np.arctan2(np.linalg.norm(normal), d1 @ d2))
    if np.degrees(angle) < STRAIGHT_DEG:  # straight: the least turns
        pos = np.array(joints, dtype=np.float64, copy=True)
        for j, child, aim in ((root, mid, d1), (mid, end, d2)):
            turn = rotation_between(torch.as_tensor(pos[child] - pos[j]), torch.as_tensor(aim)).numpy()
            moved = branch_parts(j)
            g[moved] = turn @ g[moved]
            pos[moved] = pos[j] + (pos[moved] - pos[j]) @ turn.T
        for j in (root, mid):
            out[j] = g[PARENTS[j]].T @ g[j]
        return out
    # bone directions in the segments' own rest frames (posed bone = the parent part's rotation times rest)
    a1 = g[root].T @ (joints[mid] - joints[root])
    a1 /= np.linalg.norm(a1)
    a2 = g[mid].T @ (joints[end] - joints[mid])
    a2 /= np.linalg.norm(a2)
    hinge = np.cross(a2, FORWARD if limb.endswith("arm") else -FORWARD)
    hinge -= (hinge @ a1) * a1
    hinge /= np.linalg.norm(hinge)
    # the bend about the hinge that opens the rest segments to the asked angle (the rest limb is not quite
    # straight): the second segment's rest direction turned by each candidate angle (Rodrigues)
    turns = np.linspace(-0.3, np.pi, 1321)[:, None]
    opened = np.arccos(np.clip(_turned(a2, hinge, turns) @ a1, -1.0, 1.0))
    bend = float(turns[np.argmin(np.abs(opened - angle)), 0])
    b = _turned(a2, hinge, np.array(bend))
    g_root = _frame(d1, d2) @ _frame(a1, b).T  # the rest pair of segments onto the asked pair
    out[root] = g[PARENTS[root]].T @ g_root
    out[mid] = roma.rotvec_to_rotmat(torch.as_tensor(hinge * bend)).numpy()
    return out


def reach_starts(
    points: np.ndarray,
    vertices: np.ndarray,
    joints: np.ndarray,
    local: np.ndarray,
    global_rot: np.ndarray,
    parts: np.ndarray,
    far_m: float = 0.04,
    link_m: float = 0.04,
    min_points: int = 30,
    dirs: int = 162,
) -> dict[str, np.ndarray]:
    """Per limb that reaches half the largest group of ``points`` off the fit (at least ``min_points``), the
    local rotations ``[22, 3, 3]`` with the limb placed on it (:func:`place_limb`, :func:`aim_limb`), named
    ``reach_<limb>``; ``{}`` when there is no such group. Arrays of one posed fit, metres. (Which limb
    belongs there is left to the refinement and the surface score: a limb half right, a pike's thigh on its
    points and its shin elsewhere, explains many points where it is and still belongs on the group.)"""
    from scipy.spatial import cKDTree

    group = off_group(points, vertices, far_m, link_m)
    if len(group) < min_points:
        return {}
    tree = cKDTree(points)
    out = {}
    for limb, (root, mid, end) in LIMBS.items():
        # the limb stretched out: both segments and the end part's reach beyond its joint
        reach = np.linalg.norm(joints[mid] - joints[root]) + np.linalg.norm(joints[end] - joints[mid])
        reach += np.linalg.norm(vertices[parts == end] - joints[end], axis=1).max(initial=0.0)
        if np.median(np.linalg.norm(group - joints[root], axis=1)) > reach:  # it could cover half at most
            continue
        d1, d2, _ = place_limb(group, tree, vertices, joints, parts, limb, dirs)
        out[PREFIX + limb] = aim_limb(local, global_rot, joints, limb, d1, d2)
    return out
