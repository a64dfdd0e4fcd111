"""Left or right from the torso's frame: the part-local network's side resolution (``model.net.sides``).

Part-local rotation-invariant features describe a limb's own shape, and a left forearm is (nearly) the
mirror image of a right one: from part-sized neighbourhoods the segmenter cannot tell them apart. Measured
on the research run of ``model=arteq_local`` (experiments/articulated/README.md, section 3c): 58 % part
accuracy on the ID test set but 86 % when a point labelled with the mirror part counts as right; 67 % of its
errors are left/right swaps, and it labels nearly every limb "left" (right ankle and right wrist 0 %).

Which side a point lies on is a relation between the point and the torso, not a property of its
neighbourhood. :func:`resolve_sides` keeps the segmenter's side-free answer (the probability of the pair
``p(left_k) + p(right_k)``) and splits it by the point's lateral coordinate in the torso's frame:
``x = (p - c) . R_torso e_left`` with ``c`` the torso's centroid and ``R_torso`` the chordal mean of the
predicted global rotations of the pelvis and the three spine parts, ``p(left_k) = p_pair sigmoid(x / s)``.

- Exactly rotation-invariant: ``R_torso`` and ``p - c`` turn together, so ``x`` does not change.
- Articulated: turning a limb about its joint leaves the torso, and so ``x``'s sign, alone unless the limb
  crosses the body's midplane; the pose features stay part-local.
- No parameters: weights trained without it load as they are (``sides: learned`` is the segmenter's own
  22-way answer, what every checkpoint before the option holds).

``sides: roots`` reads each limb's side in the frame of the torso part it hangs from (:data:`ROOTS`: legs
from the pelvis's predicted rotation and points, arms from spine3's) instead of the chordal mean of the four:
a body folded at the waist (a bow, a backbend) has no single torso frame, and half of the wrong labels on the
user suite's lost bows and backbends are sides (experiments/fitting/sides.md).
"""

from __future__ import annotations

import roma
import torch
import torch.nn.functional as F

from arteq.body.skeleton import JOINT_NAMES
from arteq.models.precision import upcast

#: ``model.net.sides``: ``learned`` (the segmenter's 22-way answer; checkpoints before the option),
#: ``torso`` (:func:`resolve_sides` in the torso's frame) or ``roots`` (in each limb's root part's frame).
SIDE_MODES = ("learned", "torso", "roots")
#: The pelvis and the three spine parts: no side, and their rotations make the torso's frame.
TORSO_PARTS: tuple[int, ...] = tuple(JOINT_NAMES.index(n) for n in ("pelvis", "spine1", "spine2", "spine3"))
#: Mirror pairs ``(left, right)`` of part indices: hips, knees, ankles, feet, collars, shoulders, elbows,
#: wrists.
LEFT_PARTS: tuple[int, ...] = tuple(i for i, n in enumerate(JOINT_NAMES) if n.startswith("left_"))
RIGHT_PARTS: tuple[int, ...] = tuple(JOINT_NAMES.index("right_" + JOINT_NAMES[i][5:]) for i in LEFT_PARTS)
#: ``sides: roots``: torso part -> the left parts whose side its frame decides (legs: pelvis; arms: spine3,
#: the collars' parent).
ROOTS: dict[int, tuple[int, ...]] = {
    JOINT_NAMES.index(root): tuple(JOINT_NAMES.index("left_" + n) for n in names)
    for root, names in (
        ("pelvis", ("hip", "knee", "ankle", "foot")),
        ("spine3", ("collar", "shoulder", "elbow", "wrist")),
    )
}
#: The body's left in its canonical (rest) frame: +x for SMPL and for the Anny bodies (their left joints' rest
#: x is larger than the right ones': tests/test_sides.py checks anny22 and the toy body; anny_allages, whose
#: build is slow, measured +0.108 / -0.108 m at the hips).
LEFT_AXIS = (1.0, 0.0, 0.0)


def side_mode(value: str | None) -> str:
    """The side mode of a config value (``None``: ``learned``, what older checkpoints hold)."""
    if value is None:
        return "learned"
    if isinstance(value, str) and value.lower() in SIDE_MODES:
        return value.lower()
    raise ValueError(f"model.net.sides must be one of {', '.join(SIDE_MODES)}, got {value!r}")


def torso_frame(
    points: torch.Tensor,
    part_weights: torch.Tensor,
    torso_rotmats: torch.Tensor,
    eps: float = 1e-6,
    parts: tuple[int, ...] = TORSO_PARTS,
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(centre [B, 3], left axis [B, 3])`` of the torso in the world (of its ``parts`` only, a subset of
    :data:`TORSO_PARTS`: ``sides: roots``).

    Args:
        points: ``[B, N, 3]``.
        part_weights: ``[B, N, K]`` the part weights the network pools with (the torso's columns give
            its centroid; a cloud with no torso mass falls back to its own centroid).
        torso_rotmats: ``[B, T, 3, 3]`` predicted global rotations of :data:`TORSO_PARTS`.
    """
    w = part_weights[..., list(parts)].sum(-1, keepdim=True).to(points.dtype)  # [B, N, 1]
    centre = ((w * points).sum(1) + eps * points.mean(1)) / (w.sum(1) + eps)
    rows = [TORSO_PARTS.index(k) for k in parts]
    r = roma.special_procrustes(torso_rotmats[:, rows].sum(1).double())  # chordal mean of their rotations
    left = r @ torch.tensor(LEFT_AXIS, dtype=r.dtype, device=r.device)
    return centre, left.to(points.dtype)


def resolve_sides(
    seg_logits: torch.Tensor,
    points: torch.Tensor,
    centre: torch.Tensor,
    left: torch.Tensor,
    scale: float,
    lefts: tuple[int, ...] = LEFT_PARTS,
) -> torch.Tensor:
    """Log-probabilities ``[B, N, K]`` with each mirror pair's mass split by the lateral coordinate.

    ``log p'(left_k) = log(p(left_k) + p(right_k)) + log sigmoid(x / scale)`` (right: ``-x``), other parts
    unchanged; ``x = (points - centre) . left``. The result is a normalised log-distribution, so it serves as
    logits (cross-entropy, argmax, softmax) as it is. ``lefts``: only the pairs of these left parts.
    """
    logp = F.log_softmax(upcast(seg_logits), dim=-1)
    x = ((points - centre[:, None]) * left[:, None]).sum(-1).to(logp.dtype) / scale  # [B, N]
    ls = list(lefts)
    rs = [RIGHT_PARTS[LEFT_PARTS.index(k)] for k in ls]
    pair = torch.logaddexp(logp[..., ls], logp[..., rs])
    out = logp.clone()
    out[..., ls] = pair + F.logsigmoid(x)[..., None]
    out[..., rs] = pair + F.logsigmoid(-x)[..., None]
    return out
