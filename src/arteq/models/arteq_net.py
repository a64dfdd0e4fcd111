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

    All arguments are plain values so that the configuration round-trips through checkpoints.
    """

    #: ``forward`` takes precomputed FPS indices (``fps_idx``); ArtEqModule passes a batch's to such nets.
    accepts_fps_idx = True

    def __init__(
        self,
        backbone: dict[str, Any] | None = None,
        num_betas: int = 10,
        parent_conditioning: bool | str = True,
        segmenter: dict[str, Any] | None = None,
        pose_head: dict[str, Any] | None = None,
        shape_head: dict[str, Any] | None = None,
    ):
        super().__init__()
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
    ) -> dict[str, torch.Tensor]:
        """Predict parts, rotations and betas.

        Args:
            points: ``[B, N, 3]`` cloud in metres (any translation; the network sees relative positions).
            gt_labels: ``[B, N]`` part labels; when given (stage 1) they replace the predicted part
                probabilities in the part pooling.
            fps_idx: ``[B, >=M]`` long, the backbone's FPS order precomputed (e.g. by the data workers,
                ``data.fps_points``); ``None``: the backbone computes it (same indices, see
                :class:`arteq.equivariant.EquivariantBackbone`).
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
        if gt_labels is not None:
            pool_weights = F.one_hot(gt_labels, self.num_parts).to(feats.dtype)
        else:
            pool_weights = part_probs
        part_feats = pool_parts(feats, pool_weights)  # [B, K, A, C]
        geometry = None
        if self.pose_head.geometry:
            with full_precision(points):
                geometry = part_geometry(upcast(points), pool_weights, self.pose_head.group_rotations)
        pose = self.pose_head(part_feats, geometry)
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
