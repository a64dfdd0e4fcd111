"""Vertex normals of triangle meshes (torch, batched; numpy arrays through ``torch.from_numpy``)."""

from __future__ import annotations

import torch


def vertex_normals(
    vertices: torch.Tensor, faces: torch.Tensor, incidence: torch.Tensor | None = None
) -> torch.Tensor:
    """Area-weighted unit vertex normals. ``vertices [B, V, 3]``, ``faces [F, 3]`` -> ``[B, V, 3]``;
    ``incidence``: optional sparse ``[V, F]`` vertex-face matrix (faster on CPU). A vertex in no face
    (or only in degenerate ones) gets the zero vector."""
    # three row selects: the same face normals as ``vertices[:, faces]``, without its [B, F, 3, 3] gather
    v0, v1, v2 = (vertices.index_select(1, faces[:, k]) for k in range(3))
    fn = torch.linalg.cross(v1 - v0, v2 - v0)
    if incidence is not None:
        b, f, _ = fn.shape
        vn = (incidence @ fn.permute(1, 0, 2).reshape(f, b * 3)).reshape(-1, b, 3).permute(1, 0, 2)
    else:
        vn = torch.zeros_like(vertices)
        for c in range(3):
            vn.index_add_(1, faces[:, c], fn)
    return torch.nn.functional.normalize(vn, dim=-1)
