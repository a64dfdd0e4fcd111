"""Partial scans (one depth camera): is a scan one-sided, from where was it seen, what could the camera see.

* :func:`one_sidedness`: a scan from one camera is a height field seen from that camera: looked at from the
  right direction, nearly every point is the nearest one in its image cell. For each of ``num_dirs``
  directions spread over the sphere the points are splatted (orthographically) on cells ``cell_m`` wide and
  a point counts as seen when it is within ``tol_m`` of its cell's nearest depth; the score is the best
  direction's seen fraction. Full surfaces score 0.54-0.70, single views 0.81-1.0 (16 synthetic scans of
  each kind, 4000 points: experiments/single_view/README.md); :data:`PARTIAL_SCORE` is between. The mean
  of the near-best directions is the estimated camera direction (8-19 degrees off, median per view), up
  to its sign: a one-sided sheet looks the same from both sides. The sign is where the surface bulges
  (:func:`bulge`): a body is convex, so seen from the camera a point's neighbours lie behind its tangent
  plane. It needs no fit, so a poor first fit does not confuse it.
* :func:`visible_vertices`: the body's vertices a camera sees, from a position (perspective, e.g. a depth
  image's camera at its origin) or a direction (far away): turned toward the camera and not hidden, by a
  z-buffer of the vertices splatted on cells ``cell_m`` wide at the body (the nearest depth per cell; a
  vertex more than ``depth_tol_m`` behind it is hidden).

* :func:`visibility_function`: :func:`visible_vertices` for a batch of posed bodies, as the refinement's
  ``m2s_visible``.

numpy, one scan at a time.
"""

from __future__ import annotations

import numpy as np

#: One-sidedness above which a scan is taken as one camera's view (see :func:`one_sidedness`).
PARTIAL_SCORE = 0.74


def sphere_directions(n: int) -> np.ndarray:
    """``[n, 3]`` unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(n) + 0.5
    polar = np.arccos(1 - 2 * i / n)
    azim = np.pi * (1 + 5**0.5) * i
    return np.stack([np.cos(azim) * np.sin(polar), np.sin(azim) * np.sin(polar), np.cos(polar)], 1)


def _image_axes(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([1.0, 0.0, 0.0]) if abs(axis[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def _cells(uv: np.ndarray, cell_m: float) -> np.ndarray:
    """Cell index of each point of the plane ``uv [N, 2]`` on a grid of ``cell_m`` squares."""
    cells = np.floor((uv - uv.min(0)) / cell_m).astype(np.int64)
    return cells[:, 0] * (cells[:, 1].max() + 1) + cells[:, 1]


def one_sidedness(
    points: np.ndarray,
    num_dirs: int = 100,
    cell_m: float = 0.03,
    tol_m: float = 0.05,
    near_best: float = 0.02,
) -> tuple[float, np.ndarray]:
    """``(score, direction)`` of a cloud ``[N, 3]`` (metres): the largest fraction of points seen from one
    of ``num_dirs`` directions (``num_dirs // 2`` axes, both ways along each), and the camera direction
    (unit, from the body toward the camera): the mean of the axes scoring within ``near_best`` of the best,
    its sign from :func:`bulge`."""
    p = np.asarray(points, dtype=np.float64)
    axes = sphere_directions(2 * (num_dirs // 2))[: num_dirs // 2]  # one hemisphere of axes
    scores = []
    for d in axes:
        e1, e2 = _image_axes(d)
        key = _cells(np.stack([p @ e1, p @ e2], 1), cell_m)
        height = p @ d  # seen from far along +d: the largest height; from -d: the smallest
        top = np.full(key.max() + 1, -np.inf)
        np.maximum.at(top, key, height)
        bottom = np.full(key.max() + 1, np.inf)
        np.minimum.at(bottom, key, height)
        scores.append(max((height >= top[key] - tol_m).mean(), (height <= bottom[key] + tol_m).mean()))
    scores = np.asarray(scores)
    best = int(scores.argmax())
    # a sheet looks one-sided from a cone of directions: its centre is the mean of the near-best axes
    near = axes[scores >= scores[best] - near_best]
    direction = (near * np.sign(near @ axes[best])[:, None]).sum(0)
    direction /= np.linalg.norm(direction)
    return float(scores[best]), (direction if bulge(p, direction) <= 0 else -direction)


def bulge(points: np.ndarray, direction: np.ndarray, k: int = 16, max_points: int = 1000) -> float:
    """Mean offset (metres) of a point's ``k - 1`` nearest neighbours along its normal turned toward
    ``direction`` (the normal of the plane fitted to its ``k`` nearest points), over up to ``max_points``
    evenly strided points: negative when the surface bulges toward ``direction`` (convex seen from there),
    positive when it is hollow."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    q = p[:: max(1, len(p) // max_points)]
    _, nn = cKDTree(p).query(q, k=k)
    local = p[nn] - p[nn].mean(1, keepdims=True)
    normals = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))[1][:, :, 0]
    normals *= np.where(normals @ direction < 0, -1.0, 1.0)[:, None]
    return float(np.einsum("nkc,nc->nk", p[nn[:, 1:]] - q[:, None], normals).mean())


def visible_vertices(
    vertices: np.ndarray,
    normals: np.ndarray,
    camera: np.ndarray | None = None,
    direction: np.ndarray | None = None,
    cell_m: float = 0.02,
    depth_tol_m: float = 0.03,
) -> np.ndarray:
    """``[V]`` bool: the vertices a camera at ``camera [3]`` (or far away along ``direction [3]``, from the
    body toward the camera) sees: facing it and within ``depth_tol_m`` of the nearest vertex in their
    ``cell_m`` image cell."""
    if (camera is None) == (direction is None):
        raise ValueError("visible_vertices: give exactly one of camera and direction")
    v = np.asarray(vertices, dtype=np.float64)
    if camera is not None:
        to_cam = np.asarray(camera, dtype=np.float64) - v
        axis = v.mean(0) - np.asarray(camera, dtype=np.float64)
        axis /= np.linalg.norm(axis)
    else:
        d = np.asarray(direction, dtype=np.float64)
        d = d / np.linalg.norm(d)
        to_cam = np.broadcast_to(d, v.shape)
        axis = -d
    facing = (normals * to_cam).sum(-1) > 0
    e1, e2 = _image_axes(axis)
    if camera is not None:
        rel = v - np.asarray(camera, dtype=np.float64)
        depth = rel @ axis
        scale = float(np.median(depth))  # cells of cell_m at the body's distance
        uv = np.stack([rel @ e1, rel @ e2], 1) / depth[:, None] * scale
    else:
        depth = v @ axis
        uv = np.stack([v @ e1, v @ e2], 1)
    key = _cells(uv, cell_m)
    nearest = np.full(key.max() + 1, np.inf)
    np.minimum.at(nearest, key, depth)
    return facing & (depth <= nearest[key] + depth_tol_m)


def visibility_function(
    faces, views: list[tuple[np.ndarray | None, np.ndarray | None] | None], incidence=None
):
    """For :func:`arteq.fit.refine.refine` (``m2s_visible``): a function of posed vertices ``[B, V, 3]``
    (torch) giving ``[B, V]`` bool, per scan the vertices its camera sees (:func:`visible_vertices`).
    ``views[b]``: ``(camera, direction)`` with one of them given (the camera wins), or ``None`` for a full
    scan (every vertex). ``incidence``: the body's sparse vertex-face matrix (faster normals, see
    :func:`arteq.geometry.normals.vertex_normals`)."""
    import torch

    from arteq.geometry.normals import vertex_normals

    def visible(verts: torch.Tensor) -> torch.Tensor:
        normals = vertex_normals(verts.detach(), faces, incidence).double().cpu().numpy()
        v = verts.detach().double().cpu()
        out = np.ones(v.shape[:2], dtype=bool)
        for b, view in enumerate(views):
            if view is not None:
                camera, direction = view
                out[b] = visible_vertices(v[b].numpy(), normals[b], camera=camera,
                                          direction=None if camera is not None else direction)  # fmt: skip
        return torch.from_numpy(out).to(verts.device)

    return visible
