"""The paper's training objective (Sup. Mat.), each term separately weighted, plus one term of ours.

``L = w_pose L_pose + w_global_rot L_global_rot + w_betas L_betas + w_verts L_verts + w_joints L_joints
+ w_parts L_parts``. The paper's five terms and weights: pose, betas, vertices, joints, parts at
5 / 50 / 100 / 100 / 5.

``global_rot`` (weight 5) is not in the paper, and not the authors' either: their code adds an MSE
between the *projected* global rotations (after the SVD) and the ground truth, weight 5. Ours is a
chordal term on the weighted rotation mean ``M`` *before* its projection (``rot_mean``: no SVD in its
gradient), which gives the pose head smooth gradients even while ``M`` is far from SO(3)
(docs/training.md, "a chordal mean that cannot blow up").

``group_ce`` (weight 0 unless a config sets it; not in the paper, nor the authors' code): cross-entropy of the
pose head's 60 group weights against a soft target on the group elements nearest the ground-truth rotation
(:func:`group_targets`), the anchor classification of EPN. The chordal terms alone reward hedging: the
mean ``M`` of near-uniform weights is ~0, whose squared error (1/3 per entry) beats a confident wrong choice
(2/3), and a network whose features say little about a part's turn early on (the part-local backbone) sits
on that plateau for hundreds of steps. The cross-entropy's gradient (weights minus target) points to the
right elements from the first step.
"""

from __future__ import annotations

from collections.abc import Mapping

import torch
import torch.nn.functional as F

DEFAULT_WEIGHTS = {
    "pose": 5.0,
    "global_rot": 5.0,
    "betas": 50.0,
    "verts": 100.0,
    "joints": 100.0,
    "parts": 5.0,
    "group_ce": 0.0,
}

#: Width (radians) of the soft target of ``group_ce`` over the group elements (neighbouring elements of the
#: icosahedral group are 37-72 deg apart; the nearest one is ~30 deg from a random rotation on average).
GROUP_TARGET_SIGMA = 0.3


def group_targets(rotmats: torch.Tensor, group_rotations: torch.Tensor, sigma: float = GROUP_TARGET_SIGMA):
    """Soft target over the group elements for rotations ``[..., 3, 3]``: ``q_a ∝ exp(-θ_a² / (2 σ²))`` with
    ``θ_a`` the angle between ``R_a`` and the rotation; ``[..., A]``, summing to 1."""
    cos = (torch.einsum("...ij,aij->...a", rotmats, group_rotations.to(rotmats.dtype)) - 1.0) / 2.0
    theta = torch.arccos(cos.clamp(-1.0, 1.0))
    return torch.softmax(-theta.square() / (2.0 * sigma**2), dim=-1)


def group_cross_entropy(weights: torch.Tensor, rotmats: torch.Tensor) -> torch.Tensor:
    """Mean over parts of ``-sum_a q_a log p_a`` (weights ``p [..., A]``, targets from ``rotmats``)."""
    from arteq.equivariant import group_rotations

    q = group_targets(rotmats, group_rotations(torch.float64).to(weights.device))
    return -(q * torch.log(weights.clamp_min(1e-12))).sum(-1).mean()


def weighted_vertex_mse(pred: torch.Tensor, gt: torch.Tensor, vertex_weights: torch.Tensor) -> torch.Tensor:
    """Per-coordinate MSE over ``[B, V, 3]`` with per-vertex weights ``[V]`` (normalised to mean 1)."""
    w = vertex_weights / vertex_weights.mean()
    return ((pred - gt).square().mean(dim=-1) * w).mean()


def _need(pred: Mapping[str, torch.Tensor], key: str, term: str) -> torch.Tensor:
    if key not in pred:
        raise ValueError(f"loss term {term!r} needs the network output {key!r} (ArtEq's pose head)")
    return pred[key]


def arteq_losses(
    pred: Mapping[str, torch.Tensor],
    gt: Mapping[str, torch.Tensor],
    weights: Mapping[str, float],
    vertex_weights: torch.Tensor,
) -> dict[str, torch.Tensor]:
    """All loss terms and their weighted sum (``"loss"``).

    ``pred`` needs ``local_rotmats, rot_mean, betas, vertices, joints, seg_logits``; ``gt`` needs
    ``pose`` (local rotmats), ``global_rotmats, betas, vertices, joints, labels``.
    Terms with weight 0 are skipped.
    """
    unknown = set(weights) - set(DEFAULT_WEIGHTS)
    if unknown:
        raise ValueError(f"unknown loss weight(s) {sorted(unknown)}; known: {sorted(DEFAULT_WEIGHTS)}")
    terms = {
        "pose": lambda: F.mse_loss(pred["local_rotmats"], gt["pose"]),
        "global_rot": lambda: F.mse_loss(pred["rot_mean"], gt["global_rotmats"]),
        "betas": lambda: F.mse_loss(pred["betas"], gt["betas"]),
        "verts": lambda: weighted_vertex_mse(pred["vertices"], gt["vertices"], vertex_weights),
        "joints": lambda: F.mse_loss(pred["joints"], gt["joints"]),
        "parts": lambda: F.cross_entropy(pred["seg_logits"].flatten(0, 1), gt["labels"].flatten()),
        "group_ce": lambda: group_cross_entropy(_need(pred, "rot_weights", "group_ce"), gt["global_rotmats"]),
    }
    out: dict[str, torch.Tensor] = {}
    total = 0.0
    for name, fn in terms.items():
        w = float(weights.get(name, 0.0))
        if w == 0.0:
            continue
        out[name] = fn()
        total = total + w * out[name]
    out["loss"] = total
    return out
