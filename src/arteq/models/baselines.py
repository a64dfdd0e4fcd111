"""Non-equivariant learned baseline: a PointNet++ regressor with the same outputs as ArtEq.

It stands in for the paper's non-equivariant learned competitors (IP-Net / PTF / LoopReg): raw xyz in,
no equivariance, rotations regressed as 6D vectors (Gram-Schmidt). Trained through the same
:class:`arteq.training.module.ArtEqModule` (losses, stages, metrics, placement) as ArtEq.
"""

from __future__ import annotations

from collections.abc import Sequence

import roma
import torch
import torch.nn.functional as F
from torch import nn

from arteq.body.skeleton import NUM_JOINTS, PARENTS, global_to_local
from arteq.geometry.pointops import ball_query, farthest_point_sample, gather, three_nn_interpolate
from arteq.models.heads import pool_parts


def _mlp(d_in: int, widths: Sequence[int], last_act: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, w in enumerate(widths):
        layers.append(nn.Linear(d_in, w))
        if last_act or i < len(widths) - 1:
            layers += [nn.LayerNorm(w), nn.ReLU()]
        d_in = w
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    """PointNet++ set abstraction: FPS centres, ball-query groups, shared MLP, masked max.

    ``xyz [B, N, 3], feats [B, N, C] | None -> centres [B, M, 3], feats [B, M, C']`` with
    ``M = min(npoint, N)``. Neighbour offsets are divided by the radius.
    """

    def __init__(self, npoint: int, radius: float, neighbours: int, in_channels: int, widths: Sequence[int]):
        super().__init__()
        self.npoint, self.radius, self.neighbours = int(npoint), float(radius), int(neighbours)
        self.mlp = _mlp(in_channels + 3, widths)
        self.out_channels = int(widths[-1])

    def forward(self, xyz: torch.Tensor, feats: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor]:
        m = min(self.npoint, xyz.shape[1])
        with torch.no_grad():
            centre_idx = farthest_point_sample(xyz, m)
        centres = gather(xyz, centre_idx)  # [B, M, 3]
        idx, mask = ball_query(centres, xyz, self.radius, self.neighbours)  # [B, M, k]
        mask[..., 0] = True  # the nearest point always counts (the centre itself)
        rel = (gather(xyz, idx) - centres[:, :, None]) / self.radius  # [B, M, k, 3]
        x = rel if feats is None else torch.cat([rel, gather(feats, idx)], dim=-1)
        x = self.mlp(x)
        x = x.masked_fill(~mask[..., None], float("-inf")).max(dim=2).values
        return centres, x


class FeaturePropagation(nn.Module):
    """PointNet++ feature propagation: 3-NN interpolation onto the finer level, concat skip, MLP."""

    def __init__(self, in_channels: int, skip_channels: int, widths: Sequence[int]):
        super().__init__()
        self.mlp = _mlp(in_channels + skip_channels, widths)
        self.out_channels = int(widths[-1])

    def forward(self, xyz_fine, xyz_coarse, feats_fine, feats_coarse) -> torch.Tensor:
        up = three_nn_interpolate(xyz_fine, xyz_coarse, feats_coarse)
        x = up if feats_fine is None else torch.cat([up, feats_fine], dim=-1)
        return self.mlp(x)


class PointNet2Regressor(nn.Module):
    """PointNet++ segmentation + per-part 6D rotation + betas; output contract of ``ArtEqNet``.

    Args:
        num_betas: shape coefficients predicted.
        npoints, radii, neighbours: per set-abstraction level (centres kept, ball radius in metres,
            neighbours per ball).
        sa_channels: MLP widths per set-abstraction level.
        global_channels: MLP widths of the global (all centres -> one vector) level.
        fp_channels: output width of each feature-propagation level (coarse to fine).
        head_hidden: hidden width of the per-part rotation / shape MLPs.
        seg_hidden: hidden width of the per-point segmentation MLP.

    The point features are not rotation-invariant: the network learns the rotation from data (and
    augmentation), which is what the baseline is meant to show.
    """

    def __init__(
        self,
        num_betas: int = 10,
        npoints: Sequence[int] = (512, 128),
        radii: Sequence[float] = (0.1, 0.2),
        neighbours: Sequence[int] = (32, 32),
        sa_channels: Sequence[Sequence[int]] = ((64, 64, 128), (128, 128, 256)),
        global_channels: Sequence[int] = (256, 512),
        fp_channels: Sequence[int] = (256, 128),
        head_hidden: int = 256,
        seg_hidden: int = 128,
    ):
        super().__init__()
        levels = len(npoints)
        if not (len(radii) == len(neighbours) == len(sa_channels) == len(fp_channels) == levels):
            raise ValueError(
                "PointNet2Regressor: npoints, radii, neighbours, sa_channels and fp_channels need one entry "
                f"per level, got lengths {[len(x) for x in (npoints, radii, neighbours, sa_channels)]} "
                f"and {len(fp_channels)}"
            )
        self.num_parts = NUM_JOINTS
        self.num_betas = int(num_betas)
        self.sa = nn.ModuleList()
        c = 0
        skip = [0]
        for npt, r, k, widths in zip(npoints, radii, neighbours, sa_channels):
            self.sa.append(SetAbstraction(npt, r, k, c, list(widths)))
            c = self.sa[-1].out_channels
            skip.append(c)
        self.global_mlp = _mlp(c + 3, list(global_channels))
        c_glob = self.global_mlp[-3].out_features
        # Feature propagation, coarse to fine: level L gets the global vector broadcast, then up.
        self.fp = nn.ModuleList()
        c_in = c + c_glob
        for i, width in enumerate(fp_channels):
            skip_c = skip[levels - 1 - i]
            self.fp.append(FeaturePropagation(c_in, skip_c + (3 if i == levels - 1 else 0), [width, width]))
            c_in = width
        self.point_channels = c_in
        self.segmenter = nn.Sequential(
            nn.Linear(c_in, seg_hidden), nn.ReLU(), nn.Linear(seg_hidden, NUM_JOINTS)
        )
        self.part_embedding = nn.Parameter(torch.randn(NUM_JOINTS, c_in) * 0.02)
        self.register_buffer("parents", torch.tensor([max(p, 0) for p in PARENTS]), persistent=False)
        d_part = 2 * c_in + c_glob
        self.rot_head = nn.Sequential(
            nn.Linear(d_part, head_hidden), nn.ReLU(), nn.Linear(head_hidden, head_hidden), nn.ReLU(),
            nn.Linear(head_hidden, 6),
        )  # fmt: skip
        self.shape_head = nn.Sequential(
            nn.Linear(NUM_JOINTS * c_in + c_glob, head_hidden), nn.ReLU(), nn.Linear(head_hidden, num_betas)
        )
        # Start every part at the identity rotation (6D = first two columns of I, as [3, 2]).
        nn.init.zeros_(self.rot_head[-1].weight)
        with torch.no_grad():
            self.rot_head[-1].bias.copy_(torch.eye(3)[:, :2].reshape(6))

    def forward(self, points: torch.Tensor, gt_labels: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Same contract as :meth:`arteq.models.ArtEqNet.forward`.

        Args:
            points: ``[B, N, 3]`` in metres; gt_labels: ``[B, N]`` part labels used for pooling (stage 1).
        Returns:
            ``seg_logits, part_probs, pool_weights [B,N,22]``, ``global_rotmats, rot_mean, local_rotmats
            [B,22,3,3]`` (``rot_mean`` = the Gram-Schmidt rotation: there is no separate mean), ``betas``.
        """
        if points.ndim != 3 or points.shape[-1] != 3:
            raise ValueError(f"points must be [B, N, 3], got {tuple(points.shape)}")
        if points.shape[1] == 0:
            raise ValueError("points: empty cloud (N = 0)")
        if not torch.isfinite(points).all():
            raise ValueError("points: contains NaN or Inf")
        b = points.shape[0]
        # Centred input: translation is handled by placement, not learned.
        xyz = points - points.mean(dim=1, keepdim=True)
        levels_xyz, levels_feats = [xyz], [None]
        x, f = xyz, None
        for sa in self.sa:
            x, f = sa(x, f)
            levels_xyz.append(x)
            levels_feats.append(f)
        g = self.global_mlp(torch.cat([x, f], dim=-1)).max(dim=1).values  # [B, Cg]
        feats = torch.cat([f, g[:, None].expand(-1, f.shape[1], -1)], dim=-1)
        n_lev = len(self.sa)
        for i, fp in enumerate(self.fp):
            fine = n_lev - 1 - i
            skip = levels_feats[fine]
            if fine == 0:
                skip = xyz
            feats = fp(levels_xyz[fine], levels_xyz[fine + 1], skip, feats)
        seg_logits = self.segmenter(feats)  # [B, N, K]
        part_probs = torch.softmax(seg_logits, dim=-1)
        if gt_labels is not None:
            pool_weights = F.one_hot(gt_labels, self.num_parts).to(feats.dtype)
        else:
            pool_weights = part_probs
        part = pool_parts(feats[:, :, None], pool_weights)[:, :, 0] + self.part_embedding  # [B, K, C]
        part_in = torch.cat([part, part[:, self.parents], g[:, None].expand(-1, self.num_parts, -1)], dim=-1)
        six = self.rot_head(part_in).reshape(b, self.num_parts, 3, 2)
        rotmats = roma.special_gramschmidt(six)
        betas = self.shape_head(torch.cat([part.flatten(1), g], dim=-1))
        return {
            "seg_logits": seg_logits,
            "part_probs": part_probs,
            "pool_weights": pool_weights,
            "global_rotmats": rotmats,
            "rot_mean": rotmats,
            "local_rotmats": global_to_local(rotmats),
            "betas": betas,
        }
