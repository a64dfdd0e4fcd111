"""The ArtEq network: equivariant backbone -> invariant segmentation -> part pooling -> pose / shape."""

from __future__ import annotations

from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from arteq.body.skeleton import NUM_JOINTS, PARENTS, global_to_local
from arteq.equivariant import EquivariantBackbone, group_rotations
from arteq.models.heads import PartSegmenter, PoseHead, ShapeHead, part_geometry, pool_parts
from arteq.models.precision import full_precision, upcast
from arteq.models.sides import LEFT_PARTS, ROOTS, TORSO_PARTS, resolve_sides, side_mode, torso_frame


class ArtEqNet(nn.Module):
    """Part-based SE(3)-equivariant regressor of body pose and shape from a point cloud.

    Args:
        backbone: keyword arguments of :class:`arteq.equivariant.EquivariantBackbone`.
        num_betas: shape coefficients predicted.
        parent_conditioning: how the pose head sees each part's parent: ``"invariant"`` (the parent's
            group-mean feature; ``model=arteq_local``), ``"aligned"`` / ``True`` (the parent's feature at the
            same group element, the paper's form and what checkpoints from before the modes hold) or
            ``"none"`` / ``False`` (the "nc" ablation); see :func:`arteq.models.heads.parent_mode`.
        segmenter, pose_head, shape_head: keyword arguments of the heads.
        sides: how a point's side (left or right limb) is decided: ``"learned"`` (the segmenter's own
            22-way answer; what checkpoints from before the option hold) or ``"torso"`` (the segmenter's
            side-free answer split by the point's lateral coordinate in the predicted torso frame,
            :mod:`arteq.models.sides`; no parameters) or ``"roots"`` (the same in the frame of the torso
            part each limb hangs from: legs the pelvis's, arms spine3's). ``side_scale``: the width in
            metres of that split.

    All arguments are plain values so that the configuration round-trips through checkpoints.
    """

    #: ``forward`` takes precomputed FPS indices (``fps_idx``); ArtEqModule passes a batch's to such nets.
    accepts_fps_idx = True
    #: ``forward`` takes ``torso_shift`` (the fitter passes one-sided scans' through :class:`FitNetwork`).
    accepts_torso_shift = True

    def __init__(
        self,
        backbone: dict[str, Any] | None = None,
        num_betas: int = 10,
        parent_conditioning: bool | str = True,
        segmenter: dict[str, Any] | None = None,
        pose_head: dict[str, Any] | None = None,
        shape_head: dict[str, Any] | None = None,
        sides: str | None = "learned",
        side_scale: float = 0.02,
    ):
        super().__init__()
        self.sides = side_mode(sides)
        if not float(side_scale) > 0:
            raise ValueError(f"model.net.side_scale must be > 0 (metres), got {side_scale}")
        self.side_scale = float(side_scale)
        self.backbone = EquivariantBackbone(**(backbone or {}))
        c = self.backbone.out_channels
        self.num_parts = NUM_JOINTS
        self.segmenter = PartSegmenter(c, num_parts=NUM_JOINTS, **(segmenter or {}))
        self.pose_head = PoseHead(
            c,
            group_rotations(torch.float64),
            PARENTS,
            parent_conditioning=parent_conditioning,
            **(pose_head or {}),
        )
        self.shape_head = ShapeHead(c, num_parts=NUM_JOINTS, num_betas=num_betas, **(shape_head or {}))

    def forward(
        self,
        points: torch.Tensor,
        gt_labels: torch.Tensor | None = None,
        fps_idx: torch.Tensor | None = None,
        torso_shift: torch.Tensor | None = None,
        turn_torso: bool | torch.Tensor = False,
    ) -> dict[str, torch.Tensor]:
        """Predict parts, rotations and betas.

        Args:
            points: ``[B, N, 3]`` cloud in metres (any translation; the network sees relative positions).
            gt_labels: ``[B, N]`` part labels; when given (stage 1) they replace the predicted part
                probabilities in the part pooling.
            fps_idx: ``[B, >=M]`` long, the backbone's FPS order precomputed (e.g. by the data workers,
                ``data.fps_points``); ``None``: the backbone computes it (same indices, see
                :class:`arteq.equivariant.EquivariantBackbone`).
            torso_shift: ``[B, 3]`` metres (optional), added to the torso's centre that splits left from
                right in the part labels returned (``seg_logits``, ``part_probs``): a one-sided cloud's torso
                points lie on the side the camera saw, so their centroid is off the torso's middle toward
                the camera (:func:`arteq.fit.partial.torso_shift`). The pose and shape heads still pool with
                the split they were trained with (``pool_weights``, unchanged), so it changes the labels
                only. It turns with the cloud: the outputs stay equivariant. ``sides: learned`` has no
                centre and ignores it.
            turn_torso: read the torso turned round: each torso part's predicted rotation is turned half a
                turn about the part's own long axis (:data:`TORSO_TURN`, front read as back) before the
                sides are split in its frame, so every limb's side, pooling and rotation follow; the torso
                parts' returned ``global_rotmats`` are turned likewise (``rot_mean`` is not). Another
                reading of a cloud whose torso the network reads back to front (the lost back bends,
                experiments/scan_model/spine/README.md). A ``[B]`` bool tensor turns the clouds where it is
                true only. Only with ``sides`` ``torso`` or ``roots`` and predicted parts (no ``gt_labels``).
        Returns:
            dict with ``seg_logits [B,N,K]``, ``part_probs [B,N,K]``, ``pool_weights [B,N,K]`` (what was
            used for pooling), ``global_rotmats [B,K,3,3]``, ``rot_mean [B,K,3,3]`` (weighted chordal
            mean before projection), ``rot_weights [B,K,60]``, ``local_rotmats [B,K,3,3]``,
            ``betas [B,num_betas]``.
        """
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must be [B, N, 3], got {tuple(points.shape)}")
        if points.shape[1] == 0:
            raise ValueError("points: empty cloud (N = 0)")
        feats = self.backbone(points, fps_idx=fps_idx)  # [B, N, A, C]
        seg_logits = self.segmenter(self.segmenter.invariant(feats))
        # probabilities in float32 at least (under mixed precision the logits may be bfloat16)
        part_probs = torch.softmax(seg_logits, dim=-1, dtype=upcast(seg_logits).dtype)
        side_frame = self.sides in ("torso", "roots")
        turn = _torso_turns(turn_torso, points)  # None, or [B, 1, 3, 3]: TORSO_TURN or the identity
        if turn is not None and (not side_frame or gt_labels is not None):
            raise ValueError("turn_torso needs sides 'torso' or 'roots' and predicted parts (no gt_labels)")
        if gt_labels is not None:  # stage 1: pool the ground-truth parts
            pool_weights = F.one_hot(gt_labels, self.num_parts).to(feats.dtype)
            pose = self._pose(feats, points, pool_weights)
            if side_frame:
                seg_logits = self._resolve_sides(
                    seg_logits, points, pool_weights, pose["rotmats"][:, TORSO_PARTS], torso_shift
                )
                part_probs = seg_logits.exp()
        else:
            pool_weights = part_probs
            if side_frame:
                # The torso's frame from its parts pooled with the predicted probabilities. The torso has no
                # side and its parents are torso parts, so its rotations are the same before and after.
                torso = self._pose(feats, points, part_probs, parts=TORSO_PARTS)["rotmats"]
                if turn is not None:
                    torso = torso @ turn.to(torso)
                resolved = self._resolve_sides(seg_logits, points, part_probs, torso)
                pool_weights = resolved.exp()  # the split the pose head was trained to pool with
                if torso_shift is not None:
                    resolved = self._resolve_sides(seg_logits, points, part_probs, torso, torso_shift)
                seg_logits, part_probs = resolved, resolved.exp()
            pose = self._pose(feats, points, pool_weights)
            if turn is not None:  # the torso's own rotations as the sides were read: turned round
                rot = pose["rotmats"].clone()
                rot[:, TORSO_PARTS] = rot[:, TORSO_PARTS] @ turn.to(rot)
                pose = {**pose, "rotmats": rot}
        part_feats = pose["part_feats"]
        betas = self.shape_head(part_feats.mean(dim=2))
        with full_precision(points):  # relative rotations between parts: no bfloat16 products
            local_rotmats = global_to_local(pose["rotmats"])
        return {
            "seg_logits": seg_logits,
            "part_probs": part_probs,
            "pool_weights": pool_weights,
            "global_rotmats": pose["rotmats"],
            "rot_mean": pose["mean"],
            "rot_weights": pose["weights"],
            "local_rotmats": local_rotmats,
            "betas": betas,
        }

    def _pose(
        self,
        feats: torch.Tensor,
        points: torch.Tensor,
        weights: torch.Tensor,
        parts: tuple[int, ...] | None = None,
    ) -> dict[str, torch.Tensor]:
        """The pose head on the parts pooled with ``weights [B, N, K]``, with ``part_feats [B, K, A, C]``
        added to its outputs. ``parts``: only these parts' rotations; only they and their parents are
        pooled (the others' features stay zero and are not read)."""
        cols = (
            None
            if parts is None
            else sorted(set(parts) | {max(int(self.pose_head.parents[k]), 0) for k in parts})
        )
        w = weights if cols is None else weights[..., cols]
        part_feats = pool_parts(feats, w)
        geometry = None
        if self.pose_head.geometry:
            with full_precision(points):
                geometry = part_geometry(upcast(points), w, self.pose_head.group_rotations)
        if cols is not None:  # back to all K parts; the others stay zero and are not read
            part_feats = _scatter_parts(part_feats, cols, self.num_parts)
            geometry = None if geometry is None else _scatter_parts(geometry, cols, self.num_parts)
        return {**self.pose_head(part_feats, geometry, parts=parts), "part_feats": part_feats}

    def _resolve_sides(
        self,
        seg_logits: torch.Tensor,
        points: torch.Tensor,
        weights: torch.Tensor,
        torso: torch.Tensor,
        shift: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """:func:`arteq.models.sides.resolve_sides` in the torso frame of ``weights`` and the torso's
        predicted rotations ``torso [B, 4, 3, 3]`` (no gradient through the frame); ``sides: roots``: each
        limb in its root part's frame (:data:`arteq.models.sides.ROOTS`). ``shift [B, 3]``: added to the
        centre (``forward``'s ``torso_shift``)."""
        with full_precision(points):
            pts = upcast(points)
            if shift is not None:
                shift = shift.to(device=pts.device, dtype=pts.dtype)
            roots = {None: LEFT_PARTS} if self.sides == "torso" else ROOTS
            out = seg_logits
            for root, lefts in roots.items():
                parts = TORSO_PARTS if root is None else (root,)
                centre, left = torso_frame(pts.detach(), weights.detach(), torso.detach(), parts=parts)
                if shift is not None:
                    centre = centre + shift
                out = resolve_sides(out, pts, centre, left, self.side_scale, lefts=lefts)
            return out


#: Half a turn about a part's long (up, y) axis, on the right of its world rotation: the body's left (+x) and
#: front (+z) reversed (``forward``'s ``turn_torso``).
TORSO_TURN = torch.diag(torch.tensor([-1.0, 1.0, -1.0]))


def _torso_turns(turn_torso: bool | torch.Tensor, points: torch.Tensor) -> torch.Tensor | None:
    """``forward``'s ``turn_torso`` as ``[B, 1, 3, 3]`` rotations (:data:`TORSO_TURN` where turned, the
    identity elsewhere), or None where no cloud is turned."""
    if not torch.is_tensor(turn_torso):
        return TORSO_TURN.to(points.device)[None, None].expand(len(points), 1, 3, 3) if turn_torso else None
    if tuple(turn_torso.shape) != (len(points),):
        raise ValueError(f"turn_torso: one flag per cloud ({len(points)}), got {tuple(turn_torso.shape)}")
    mask = turn_torso.to(device=points.device, dtype=torch.bool)
    if not bool(mask.any()):
        return None
    eye = torch.eye(3, device=points.device)
    return torch.where(mask[:, None, None, None], TORSO_TURN.to(points.device), eye)


def _scatter_parts(x: torch.Tensor, cols: list[int], num_parts: int) -> torch.Tensor:
    """``[B, len(cols), ...]`` -> ``[B, num_parts, ...]`` with zeros outside ``cols``."""
    out = x.new_zeros(x.shape[0], num_parts, *x.shape[2:])
    out[:, cols] = x
    return out
