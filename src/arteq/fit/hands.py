"""The hands' last pass: each fitted hand's finger curl and wrist fitted to the scan points it explains.

A fit's hands are one rigid part each, flat as Anny's template hand; a scanned hand is often curled or
closed, and then the flat hand's fingers stick out of it and its wrist turns to split the difference
(experiments/fitting/native_anny/README.md). After every other step, :func:`fit_hands` bends each hand's
fingers with :class:`arteq.body.hands.HandCurl` (one curl in [0, 1] per hand) and turns its wrist, the rest
of the fit held, on a local objective:

* the scan points the hand explains: those whose nearest vertex of the whole fitted body is one of that
  hand's and lies within ``radius_m`` of them (points of a thigh the hand rests on stay with the thigh);
* each such point to its nearest hand vertex, and each hand vertex to its nearest such point (the farthest
  ``trim`` of them left out: the palm of a hand on a thigh is not seen), both Geman-McClure at ``sigma_cm``;
* a hand with fewer than ``min_points`` such points is left as it is (curl 0).

A hand's pass is kept only where its objective ends lower than it started (on a flat scanned hand the curl
stays near 0).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import roma
import torch

from arteq.body.lbs import skin
from arteq.body.skeleton import JOINT_NAMES, PARENTS

HAND_JOINTS = (JOINT_NAMES.index("left_wrist"), JOINT_NAMES.index("right_wrist"))


@dataclass
class HandsConfig:
    """:func:`fit_hands`' settings (module docstring)."""

    iters: int = 15
    lr_curl: float = 0.12
    lr_wrist: float = 0.05
    radius_m: float = 0.04
    sigma_cm: float = 2.0
    trim: float = 0.2
    m2s_stride: int = 3  # every this many of a hand's vertices in the hand -> scan term
    min_points: int = 15
    w_wrist: float = 0.1  # prior on the wrist's turn (per rad^2)
    per_finger: bool = False  # one curl per finger (curl [B, 10]) instead of one per hand

    def to_dict(self) -> dict:
        return asdict(self)


def _gm(r2: torch.Tensor, sigma: float) -> torch.Tensor:
    s2 = sigma * sigma
    return r2 / (r2 + s2)


def fit_hands(
    body: torch.nn.Module,
    hands,
    points: list[np.ndarray],
    init: dict[str, torch.Tensor],
    config: HandsConfig | None = None,
) -> dict[str, torch.Tensor]:
    """Fit the finger curl and wrist of each hand of ``B`` fits (module docstring).

    Args:
        body: the fitted body (:class:`arteq.body.BodyModel`, no pose correctives).
        hands: its :class:`arteq.body.hands.HandCurl`.
        points: ``B`` clouds ``[N_b, 3]`` in the fits' frame (metres).
        init: ``local_rotmats [B, 22, 3, 3]``, ``betas [B, nb]``, ``transl [B, 3]`` of the fits.
    Returns:
        ``curl [B, 2]`` (left, right), ``local_rotmats``, ``vertices [B, V, 3]``, ``joints``,
        ``global_rotmats`` and ``kept [B, 2]`` (bool: the hand's pass lowered its objective), ``points
        [B, 2]`` (how many scan points each hand explains).
    """
    from scipy.spatial import cKDTree

    cfg = config or HandsConfig()
    dtype, device = body.v_template.dtype, body.v_template.device
    rot0 = init["local_rotmats"].detach().to(device=device, dtype=dtype)
    betas = init["betas"].detach().to(device=device, dtype=dtype)
    transl = init["transl"].detach().to(device=device, dtype=dtype)
    b = rot0.shape[0]
    with torch.no_grad():
        rest, rest_joints = body.shape(betas)
        verts0 = skin(rest, rest_joints, rot0, body.lbs_weights, PARENTS, None, transl)[0]
    part = body.part_labels
    part_np = part.cpu().numpy()
    hand_v = [torch.nonzero(part == j)[:, 0] for j in HAND_JOINTS]
    # the points each hand explains, per fit and hand (device tensors; None: too few)
    near: list[list[torch.Tensor | None]] = []
    counts = torch.zeros(b, 2, dtype=torch.long)
    for i in range(b):
        v = verts0[i].cpu().double().numpy()
        pts = np.asarray(points[i], dtype=np.float64)
        d, vi = cKDTree(v).query(pts)
        row = []
        for h, j in enumerate(HAND_JOINTS):
            sel = (part_np[vi] == j) & (d < cfg.radius_m)
            counts[i, h] = int(sel.sum())
            row.append(
                torch.as_tensor(pts[sel], dtype=dtype, device=device) if sel.sum() >= cfg.min_points else None
            )
        near.append(row)
    active = torch.tensor([[p is not None for p in row] for row in near], device=device)  # [B, 2]

    per = 5 if cfg.per_finger else 1
    curl = torch.zeros(b, 2 * per, dtype=dtype, device=device, requires_grad=True)
    dw = torch.zeros(b, 2, 3, dtype=dtype, device=device, requires_grad=True)
    opt = torch.optim.Adam([{"params": [curl], "lr": cfg.lr_curl}, {"params": [dw], "lr": cfg.lr_wrist}])
    wrists = list(HAND_JOINTS)

    both = torch.cat(hand_v)  # the hands' vertices, left then right: only they move
    split = len(hand_v[0])
    weights = body.lbs_weights[both]
    # the finger weights on those vertices, as rows of ``rest[:, both]``; the heads of the (fixed) rest mesh
    row_of = torch.full((rest.shape[1],), -1, dtype=torch.long, device=device)
    row_of[both] = torch.arange(len(both), device=device)
    on = row_of[hands.vert] >= 0  # (every finger weight lies on a hand: all of them, in practice)
    rows = row_of[hands.vert][on]
    heads = hands.heads(rest)
    rest_h = rest[:, both]

    def posed(c: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
        """The hands' vertices ``[B, Vl + Vr, 3]`` with curls ``c`` and wrist turns ``d``."""
        rot = rot0.clone()
        rot[:, wrists] = rot0[:, wrists] @ roma.rotvec_to_rotmat(d * active[..., None])
        curled = hands.deform(
            rest_h, heads, c.clamp(0.0, 1.0) * active.repeat_interleave(per, dim=1), rows, on
        )
        return skin(curled, rest_joints, rot, weights, PARENTS, None, transl)[0]

    def objective(verts: torch.Tensor) -> torch.Tensor:
        """``[B, 2]`` each hand's local objective (0 for a hand left as it is) from the hands' vertices."""
        out = torch.zeros(b, 2, dtype=dtype, device=device)
        for i in range(b):
            for h in range(2):
                p = near[i][h]
                if p is None:
                    continue
                hv = verts[i, :split] if h == 0 else verts[i, split:]
                hs = hv[:: cfg.m2s_stride]
                with torch.no_grad():  # nearest pairs found without gradients, their distances with
                    to_v = torch.cdist(p, hv.detach()).argmin(1)
                    to_p = torch.cdist(hs.detach(), p).argmin(1)
                s2m = _gm(((p - hv[to_v]) * 100).square().sum(-1), cfg.sigma_cm).mean()
                m2s_all = ((hs - p[to_p]) * 100).square().sum(-1)
                keep = max(1, int(round((1 - cfg.trim) * len(m2s_all))))
                kept_v = torch.topk(m2s_all.detach(), keep, largest=False).indices
                m2s = _gm(m2s_all[kept_v], cfg.sigma_cm).mean()
                out[i, h] = s2m + m2s
        return out

    with torch.no_grad():
        start = objective(verts0[:, both])
    for _ in range(max(0, int(cfg.iters)) if bool(active.any()) else 0):
        verts = posed(curl, dw)
        loss = objective(verts) + cfg.w_wrist * dw.square().sum(-1)
        opt.zero_grad(set_to_none=True)
        loss.sum().backward()
        opt.step()
        with torch.no_grad():
            curl.clamp_(0.0, 1.0)
    with torch.no_grad():
        end = objective(posed(curl, dw))
        kept = active & (end < start)
        c = curl.detach().clamp(0.0, 1.0) * kept.repeat_interleave(per, dim=1)
        rot = rot0.clone()
        rot[:, wrists] = rot0[:, wrists] @ roma.rotvec_to_rotmat(dw.detach() * kept[..., None])
        verts, joints, glob = skin(
            hands.deform(rest, heads, c, hands.vert),
            rest_joints,
            rot,
            body.lbs_weights,
            PARENTS,
            None,
            transl,
        )
    return {"curl": c, "local_rotmats": rot, "vertices": verts, "joints": joints, "global_rotmats": glob,
            "kept": kept.cpu(), "points": counts}  # fmt: skip
