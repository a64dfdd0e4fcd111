"""Placing a predicted body on the input cloud (translation).

The network sees only relative positions, so it predicts pose and shape, not where the body is. The
translation is found in closed form: the predicted mesh's surface centroid, with each part weighted
by the share of the cloud's points assigned to it, is put on the cloud's centroid. Part weighting
makes this insensitive to how many points each part received (occlusion, uneven sampling between
parts); what remains is the density variation within a part. It is differentiable, translation-
and rotation-equivariant, and costs one matrix product.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from arteq.models.precision import full_precision, upcast


def vertex_areas(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Per-vertex area (a third of each incident triangle's area).

    Args:
        vertices: ``[V, 3]``; faces: ``[F, 3]`` long.
    Returns:
        ``[V]``.
    """
    tri = vertices[faces]
    area = 0.5 * torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).norm(dim=-1)
    out = torch.zeros(vertices.shape[0], dtype=vertices.dtype, device=vertices.device)
    out.index_add_(0, faces.reshape(-1), (area / 3).repeat_interleave(3))
    return out


def part_centroid_matrix(areas: torch.Tensor, vertex_labels: torch.Tensor, num_parts: int) -> torch.Tensor:
    """``[V, K]`` matrix whose column k averages the part-k vertices by area (surface centroid)."""
    a = F.one_hot(vertex_labels, num_parts).to(areas.dtype) * areas[:, None]
    return a / a.sum(dim=0, keepdim=True).clamp_min(1e-12)


def body_centroid_matrix(body: torch.nn.Module, num_parts: int) -> torch.Tensor:
    """``[V, K]`` float32 :func:`part_centroid_matrix` of a body model's rest mesh (areas in float64)."""
    template = body.v_template.detach().double()
    areas = vertex_areas(template, body.faces)
    return part_centroid_matrix(areas, body.part_labels, num_parts).float()


def estimate_translation(
    vertices: torch.Tensor,
    centroid_matrix: torch.Tensor,
    points: torch.Tensor,
    part_weights: torch.Tensor,
) -> torch.Tensor:
    """Translation that puts the part-weighted mesh centroid on the cloud centroid.

    Args:
        vertices: ``[B, V, 3]`` predicted mesh before translation.
        centroid_matrix: ``[V, K]`` from :func:`part_centroid_matrix`.
        points: ``[B, N, 3]`` input cloud.
        part_weights: ``[B, N, K]`` part probabilities (or one-hot labels) of the points.
    Returns:
        ``[B, 3]`` translation to add to ``vertices``.
    """
    with full_precision(vertices):  # float32 at least, also under mixed precision (millimetres matter)
        vertices, points, part_weights = upcast(vertices), upcast(points), upcast(part_weights)
        dtype = torch.promote_types(vertices.dtype, points.dtype)
        mesh_centroids = torch.einsum("vk,bvc->bkc", centroid_matrix.to(dtype), vertices.to(dtype))
        share = part_weights.to(dtype).sum(dim=1)  # [B, K]
        share = share / share.sum(dim=-1, keepdim=True).clamp_min(1e-12)
        return points.to(dtype).mean(dim=1) - torch.einsum("bk,bkc->bc", share, mesh_centroids)
