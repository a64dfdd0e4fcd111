"""Placing a predicted body on the input cloud (translation).

The network sees only relative positions, so it predicts pose and shape, not where the body is. The
translation is found in closed form: the predicted mesh's surface centroid, with each part weighted
by the share of the cloud's points assigned to it, is put on the cloud's centroid. Part weighting
makes this insensitive to how many points each part received (occlusion, uneven sampling between
parts) and to parts with no points at all (their weight is 0): no full-body centroid is assumed; what
remains is the density variation within a part. It is differentiable, translation- and rotation-equivariant,
and costs one matrix product.

A part seen from one side only (a single depth camera) still has its points' centroid off its surface
centroid, toward the camera (by 2/pi of the radius for a cylinder seen side-on: 6-9 cm on a torso 10-15 cm
in radius; the whole body's placement is 4-6 cm off, tests/test_single_view_parts.py).
:func:`align_translation` then moves the translation by translation-only ICP of the points to the posed
mesh (each point to the nearest vertex of its own part), which uses only the surface that was seen.
"""

from __future__ import annotations

import numpy as np
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


def align_translation(
    vertices: torch.Tensor,
    vertex_parts: torch.Tensor,
    points: torch.Tensor,
    part_weights: torch.Tensor,
    transl: torch.Tensor,
    iters: int = 20,
    max_points: int = 1024,
    keep: float = 0.8,
) -> torch.Tensor:
    """A translation refined by translation-only ICP of the cloud to the mesh (for partial clouds).

    Each iteration matches every point (up to ``max_points`` of them, evenly strided) to the nearest vertex
    of the point's most probable part on the mesh moved by the current translation, and adds the mean
    residual of the ``keep`` fraction of closest matches (flying pixels and stray points do not pull). Only
    where the points are counts, so a cloud of one side of a body is put on that side. Not differentiable
    (the matches are discrete); one k-d tree per cloud (scipy, on the CPU), the parts kept apart by a
    fourth coordinate.

    Args:
        vertices: ``[B, V, 3]`` predicted mesh before translation; vertex_parts: ``[V]`` long part per vertex.
        points: ``[B, N, 3]``; part_weights: ``[B, N, K]`` part probabilities (or one-hot labels).
        transl: ``[B, 3]`` starting translation (e.g. :func:`estimate_translation`).
    Returns:
        ``[B, 3]`` translation to add to ``vertices`` (``transl``'s dtype and device).
    """
    from scipy.spatial import cKDTree

    step = max(1, points.shape[1] // max_points)
    pts = points[:, ::step].detach().double().cpu().numpy()
    parts = part_weights[:, ::step].detach().argmax(-1).double().cpu().numpy() * 1e3  # parts 1 km apart
    verts = vertices.detach().double().cpu().numpy()
    vparts = vertex_parts.detach().double().cpu().numpy() * 1e3
    t = transl.detach().double().cpu().numpy().copy()
    n_keep = max(1, int(round(keep * pts.shape[1])))
    for b in range(len(pts)):
        tree = cKDTree(np.concatenate([verts[b], vparts[:, None]], 1))
        for _ in range(max(0, int(iters))):
            moved = pts[b] - t[b]
            dist, nn = tree.query(np.concatenate([moved, parts[b][:, None]], 1))
            best = np.argsort(dist, kind="stable")[:n_keep]
            t[b] += (moved[best] - verts[b, nn[best]]).mean(0)
    return torch.as_tensor(t, dtype=transl.dtype, device=transl.device)
