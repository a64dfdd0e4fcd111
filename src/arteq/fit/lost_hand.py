"""Lost hands: an arm placed on a hand-sized group of scan points that the fit leaves off.

A closed hand resting near the knees in a squat is one of the shapes the network reads worst: it gives the
fist none of the hand's points (they go to the thigh and shin nearby), the refinement then lays the fitted
hand on the thigh, and the forearm follows it. The fit covers the scan everywhere but at the fist, whose
points are 1-3 % of the scan: too few for the surface score that picks between whole-body refits
(:func:`arteq.fit.crossing.surface_score`, where a hand is within its noise), too compact for the limb
placement of :mod:`arteq.fit.reach`, which aims a whole two-segment chain along a group (a fist is covered
by the middle of a forearm there). Measured on scans of the stock Anny model with curled fingers:
experiments/fitting/lost_hand/README.md.

:func:`fit_lost_hand` works on one fit, after every whole-body step (the fitter runs it where the fit scores
at most ``CrossingConfig.reach_max_score_cm``: above, the fit is lost as a whole), on a local objective that
a hand changes by its whole weight:

* the group: the largest group of scan points farther than ``far_m`` from the fit, linked within
  ``link_m`` (:func:`arteq.fit.reach.off_group`), of at least ``min_points``;
* per arm that can reach the group's centre and whose hand the network gave under ``max_hand_share`` of
  the points (a hand it saw is not lost: a group by it is something else, a pike's leg), a start with the
  hand on it: the hand's centre put on the group's far end from the shoulder (the mean of its
  ``far_share`` farthest points: all of a fist, the end of a whole arm), the elbow on its circle where the
  two segments lie nearest the scan (two starts: the best supported elbow and the best of the circle's
  other half; :func:`place_hand`);
* from there the arm's three joints (shoulder, elbow, wrist) alone are fitted, ``iters`` Adam steps, on the
  scan points within the arm's reach: each to its nearest vertex of the whole body (the rest of the body
  held; the points' term), and each of the arm's vertices to its nearest scan point (the farthest ``trim``
  left out: the palm on the thigh is not seen; ``part_vertices`` of each of its three parts, so that the
  hand, half of the arm's vertices, does not outweigh the rest; the arm's term), both Geman-McClure at
  ``sigma_cm``;
* an arm is kept where it lowers the sum of both terms by ``min_gain`` (relative) or more and the points'
  term does not rise by more than ``points_slack`` (relative): an arm laid on the other hand's points
  leaves its own points unexplained. Of two such arms, the larger gain; otherwise the fit stays as it was.
  (The points' term alone hardly moves where a fist is put back: the misplaced forearm had explained
  points of a thigh fitted a little off, about as many as the fist has.)
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import roma
import torch

from arteq.body.lbs import skin
from arteq.body.skeleton import PARENTS
from arteq.fit.reach import LIMBS, _thickness, aim_limb, off_group

ARMS = ("left_arm", "right_arm")


@dataclass
class LostHandConfig:
    """:func:`fit_lost_hand`'s settings (module docstring)."""

    min_points: int = 20
    far_m: float = 0.04
    link_m: float = 0.04
    iters: int = 30
    lr: float = 0.03
    sigma_cm: float = 2.0
    trim: float = 0.2
    part_vertices: int = 200  # the arm's vertices in the objective: this many of each part, evenly spread
    elbow_steps: int = 36
    starts: int = 2  # elbow placements per arm (:func:`place_hand`), the lower objective kept
    far_share: float = 0.25  # the hand goes to the mean of this share of the group farthest from the shoulder
    min_gain: float = 0.1
    points_slack: float = 0.03
    rest_cm: float = 1.0  # points the rest of the body explains this well stay its (a constant term)
    max_hand_share: float = 0.01  # an arm whose hand the network gave this share of the points is not tried

    def to_dict(self) -> dict:
        return asdict(self)


def _branch(limb: str) -> list[int]:
    """The parts that move with ``limb``'s root joint (upper arm, forearm, hand)."""
    from arteq.fit.refine import branch_parts

    return branch_parts(LIMBS[limb][0])


def place_hand(
    tree, vertices: np.ndarray, joints: np.ndarray, parts: np.ndarray, limb: str, target: np.ndarray,
    steps: int = 36, starts: int = 1,
) -> list[tuple[np.ndarray, np.ndarray]]:  # fmt: skip
    """Directions ``(d1, d2)`` of ``limb``'s upper arm and forearm that put its hand's centre on ``target``
    (as near as the arm reaches), the elbow on its circle where the segments' samples lie nearest the scan
    (``tree``: a ``cKDTree`` of it; less each segment's thickness). ``starts=2`` adds the best elbow of the
    circle's other half: a bend in the mirrored plane, the arm rolled by a half turn (which the scan of a
    nearly straight arm hardly tells apart, and a local fit does not undo)."""
    root, mid, end = LIMBS[limb]
    s, e, w = joints[root], joints[mid], joints[end]
    hand = vertices[parts == end]
    l1 = float(np.linalg.norm(e - s))
    l2 = float(np.linalg.norm(w - e) + np.linalg.norm(hand.mean(0) - w))
    rho1 = _thickness(vertices, parts, root, s, e)
    rho2 = _thickness(vertices, parts, mid, e, w)
    dist = float(np.linalg.norm(target - s))
    axis = (target - s) / max(dist, 1e-9)
    dist = min(max(dist, abs(l1 - l2) + 1e-3), 0.99 * (l1 + l2))
    target = s + axis * dist
    x = (l1 * l1 - l2 * l2 + dist * dist) / (2 * dist)  # the elbow's circle: centre s + x axis, radius rho
    rho = float(np.sqrt(max(l1 * l1 - x * x, 0.0)))
    u = np.cross(axis, np.eye(3)[np.argmin(np.abs(axis))])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    th = np.linspace(0.0, 2 * np.pi, steps, endpoint=False)[:, None]
    elbows = s + x * axis + rho * (np.cos(th) * u + np.sin(th) * v)  # [T, 3]
    t = np.array([0.25, 0.5, 0.75])[None, :, None]
    s1 = s + t * (elbows[:, None] - s)
    s2 = elbows[:, None] + t * (target - elbows[:, None])
    gap1 = np.clip(tree.query(s1.reshape(-1, 3))[0] - rho1, 0.0, 0.1).reshape(len(th), -1).mean(1)
    gap2 = np.clip(tree.query(s2.reshape(-1, 3))[0] - rho2, 0.0, 0.1).reshape(len(th), -1).mean(1)
    score = gap1 + gap2
    best = int(np.argmin(score))
    picks = [best]
    if starts > 1:  # the other half of the circle
        other = np.abs((np.arange(steps) - best + steps // 2) % steps - steps // 2) >= steps // 4
        picks.append(int(np.flatnonzero(other)[np.argmin(score[other])]))
    out = []
    for k in picks:
        d1 = (elbows[k] - s) / np.linalg.norm(elbows[k] - s)
        d2 = (target - elbows[k]) / max(float(np.linalg.norm(target - elbows[k])), 1e-9)
        out.append((d1, d2))
    return out


def _spread(parts: np.ndarray, which: list[int], count: int) -> np.ndarray:
    """Up to ``count`` vertex indices of each part of ``which``, evenly spread over its vertices (a hand has
    more vertices than an upper arm and forearm together: it would outweigh them)."""
    out = []
    for k in which:
        idx = np.nonzero(parts == k)[0]
        if len(idx) > count:
            idx = idx[np.linspace(0, len(idx) - 1, count).round().astype(int)]
        out.append(idx)
    return np.concatenate(out)


def _gm(r2: torch.Tensor, sigma: float) -> torch.Tensor:
    return r2 / (r2 + sigma * sigma)


def fit_lost_hand(
    body: torch.nn.Module,
    points: np.ndarray,
    fit: dict[str, np.ndarray],
    parts: np.ndarray,
    config: LostHandConfig | None = None,
    seen: np.ndarray | None = None,
    subset: np.ndarray | None = None,
    max_score_cm: float = float("inf"),
) -> dict | None:
    """One fit's lost-hand step (module docstring).

    Args:
        body: the fitted body (:class:`arteq.body.BodyModel`).
        points: the scan ``[N, 3]`` in the fit's frame (metres).
        fit: ``local_rotmats [22, 3, 3]``, ``global_rotmats``, ``joints [22, 3]``, ``vertices [V, 3]``,
            ``betas [nb]``, ``transl [3]`` of one fit.
        parts: each vertex's part ``[V]``.
        seen: the share of the scan's points the network gives each part ``[22]``; an arm whose hand has
            ``max_hand_share`` or more of them is not tried (its hand was seen: the group is something
            else, a pike's leg); None: every arm.
        subset, max_score_cm: with a group found, nothing is tried where the fit's surface score
            (:func:`arteq.fit.crossing.surface_score` over the ``subset`` vertices) is above ``max_score_cm``
            (a fit lost as a whole); the score is computed only then, and only with ``subset``.
    Returns:
        None where nothing was tried (no such group, a fit scoring above ``max_score_cm``, or no arm in
        reach); else ``{"arm": the arm kept or "", "group": its points, "score_cm": the fit's surface score
        (None without ``subset``), "tried": {arm: {"before": [points' term, arm's term] of the fit, "after":
        the same of the arm placed}}}`` and, where an arm is kept, ``"local_rotmats"`` (``[22, 3, 3]``
        numpy).
    """
    from scipy.spatial import cKDTree

    cfg = config or LostHandConfig()
    pts = np.asarray(points, dtype=np.float64)
    verts = np.asarray(fit["vertices"], dtype=np.float64)
    joints = np.asarray(fit["joints"], dtype=np.float64)
    group = off_group(pts, verts, cfg.far_m, cfg.link_m)
    if len(group) < cfg.min_points:
        return None
    score = None
    if subset is not None:  # only now: most fits have no such group
        from arteq.fit.crossing import surface_score

        score = surface_score(pts, verts, subset)
        if score > max_score_cm:
            return None
    centre = group.mean(0)
    tree = cKDTree(pts)
    local = np.asarray(fit["local_rotmats"], dtype=np.float64)
    grot = np.asarray(fit["global_rotmats"], dtype=np.float64)
    dtype, device = body.v_template.dtype, body.v_template.device
    betas = torch.as_tensor(np.asarray(fit["betas"])[None], dtype=dtype, device=device)
    transl = torch.as_tensor(np.asarray(fit["transl"])[None], dtype=dtype, device=device)
    with torch.no_grad():
        rest, rest_joints = body.shape(betas)
    record: dict = {"arm": "", "group": int(len(group)), "score_cm": score, "tried": {}}
    best = None
    for limb in ARMS:
        root, mid, end = LIMBS[limb]
        if seen is not None and seen[end] >= cfg.max_hand_share:
            continue
        moving = np.isin(parts, _branch(limb))
        reach = np.linalg.norm(joints[mid] - joints[root]) + np.linalg.norm(joints[end] - joints[mid])
        reach += np.linalg.norm(verts[parts == end] - joints[end], axis=1).max(initial=0.0)  # stretched out
        if np.linalg.norm(centre - joints[root]) > reach:
            continue
        # the hand goes to the group's far end from the shoulder: all of a fist, the end of a whole arm
        far = np.linalg.norm(group - joints[root], axis=1)
        target = group[far >= np.quantile(far, 1.0 - cfg.far_share)].mean(0)
        near = pts[np.linalg.norm(pts - joints[root], axis=1) <= reach + cfg.far_m]
        if len(near) < cfg.min_points:  # (a group whose centre is in reach but whose points are not)
            continue
        near_tree = cKDTree(near)
        d_rest = cKDTree(verts[~moving]).query(near)[0] * 100
        # points the rest of the body explains within rest_cm count as explained by it (a constant): the
        # arm's term is computed on the others, a few hundred of the thousands in its reach
        free = d_rest > cfg.rest_cm
        fixed = float(_gm(torch.as_tensor(d_rest[~free]).square(), cfg.sigma_cm).sum())
        p_all = torch.as_tensor(near, dtype=dtype, device=device)
        p = p_all[torch.as_tensor(free, device=device)]
        d_free = torch.as_tensor(d_rest[free], dtype=dtype, device=device)
        sub = torch.as_tensor(_spread(parts, _branch(limb), cfg.part_vertices), device=device)
        weights = body.lbs_weights[sub]
        rest_sub = rest[:, sub]

        def posed(rot: torch.Tensor, rest_sub=rest_sub, weights=weights) -> torch.Tensor:
            return skin(rest_sub, rest_joints, rot, weights, PARENTS, None, transl)[0][0]

        count = len(near)

        def objective(v: torch.Tensor, p=p, d_free=d_free, fixed=fixed, count=count, p_all=p_all,
                      near_tree=near_tree) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
            with torch.no_grad():
                to_v = torch.cdist(p, v.detach()).argmin(1) if len(p) else None
                to_p = torch.as_tensor(near_tree.query(v.detach().cpu().double().numpy())[1], device=device)
            s2m = torch.zeros((), dtype=dtype, device=device) + fixed
            if len(p):
                d_arm = ((p - v[to_v]) * 100).square().sum(-1)
                s2m = s2m + _gm(torch.minimum(d_arm, d_free.square()), cfg.sigma_cm).sum()
            m2s = ((v - p_all[to_p]) * 100).square().sum(-1)
            kept = max(1, int(round((1 - cfg.trim) * len(m2s))))
            keep = torch.topk(m2s.detach(), kept, largest=False).indices
            return s2m / count, _gm(m2s[keep], cfg.sigma_cm).mean()

        rot0 = torch.as_tensor(local[None], dtype=dtype, device=device)
        with torch.no_grad():
            before = [float(x) for x in objective(posed(rot0))]
        after, rot = None, None
        for d1, d2 in place_hand(tree, verts, joints, parts, limb, target, cfg.elbow_steps, cfg.starts):
            start = aim_limb(local, grot, joints, limb, d1, d2)
            start = torch.as_tensor(start[None], dtype=dtype, device=device)
            free = [root, mid, end]
            delta = torch.zeros(len(free), 3, dtype=dtype, device=device, requires_grad=True)
            opt = torch.optim.Adam([delta], lr=cfg.lr)

            def turned(d: torch.Tensor, start=start, free=free) -> torch.Tensor:
                r = start.clone()
                r[0, free] = start[0, free] @ roma.rotvec_to_rotmat(d)
                return r

            for _ in range(cfg.iters):
                loss = sum(objective(posed(turned(delta))))
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
            with torch.no_grad():
                r = turned(delta)
                end_terms = [float(x) for x in objective(posed(r))]
            if after is None or sum(end_terms) < sum(after):
                after, rot = end_terms, r
        record["tried"][limb] = {"before": [round(x, 4) for x in before],
                                 "after": [round(x, 4) for x in after]}  # fmt: skip
        gain = (sum(before) - sum(after)) / max(sum(before), 1e-9)
        explains = after[0] <= (1 + cfg.points_slack) * before[0]  # no point left that the fit explained
        if gain >= cfg.min_gain and explains and (best is None or gain > best[0]):
            best = (gain, limb, rot[0].cpu().numpy())
    if not record["tried"]:
        return None
    if best is not None:
        record["arm"] = best[1]
        record["local_rotmats"] = best[2]
    return record
