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
  plane. It needs no fit, so a poor first fit does not confuse it. :func:`facing_direction` refines that
  direction from the surface normals (what a camera sees faces it): median 15 -> 8 degrees on side views.
* :func:`visible_vertices`: the body's vertices a camera sees, from a position (perspective, e.g. a depth
  image's camera at its origin) or a direction (far away): turned toward the camera and not hidden, by a
  z-buffer of the vertices splatted on cells ``cell_m`` wide at the body (the nearest depth per cell; a
  vertex more than ``depth_tol_m`` behind it is hidden).

* :func:`visibility_function`: :func:`visible_vertices` for a batch of posed bodies, as the refinement's
  ``m2s_visible``.
* Refinement starts (:func:`pick_starts`, the fitter's hook for partial scans): :func:`untwist` turns back
  the parts a network turned the wrong way round (from one side a front and a back look alike),
  :func:`start_hypotheses` builds the starts (:class:`HypothesisConfig`), and where there is more than one
  each is refined briefly and scored by :func:`hypothesis_score` (the partial objective plus
  :func:`free_space`, the share of the body where the camera saw past or through the surface).

numpy, one scan at a time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: One-sidedness above which a scan is taken as one camera's view (see :func:`one_sidedness`).
PARTIAL_SCORE = 0.74
#: :func:`torso_shift`'s depth (metres): how far behind the centroid of a one-sided view's torso points its
#: middle lies. A camera sees half of a torso's cross-section; for an ellipse seen along a half-axis ``a`` the
#: seen points (even in the image) lie ``pi / 4 * a`` toward the camera on average: 9 cm for ``a`` = 11.5 cm.
#: Chosen on the first 16 scans of each view set (experiments/single_view/README.md, "The torso's middle").
TORSO_DEPTH_M = 0.09


def torso_shift(view_dir: np.ndarray, depth_m: float = TORSO_DEPTH_M) -> np.ndarray:
    """``[3]``: the move from a one-sided scan's torso-point centroid to the torso's middle, away from the
    camera (``view_dir``: unit, from the body toward the camera), for the network's left / right split
    (``torso_shift`` of :class:`arteq.models.ArtEqNet`). Seen from the side, the torso's visible points lie
    on the near flank, so without it the near limbs sit on the torso's middle line and half their points
    take the far side's labels."""
    d = np.asarray(view_dir, dtype=np.float64)
    n = np.linalg.norm(d)
    if d.shape != (3,) or not np.isfinite(n) or n == 0:
        raise ValueError(f"view_dir must be a finite non-zero 3-vector, got {d!r}")
    return -depth_m * d / n


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
    frames = [_image_axes(d) for d in axes]
    e1, e2 = np.stack([f[0] for f in frames]), np.stack([f[1] for f in frames])
    u, v, height = p @ e1.T, p @ e2.T, p @ axes.T  # [N, axes]; seen from far along +d: the largest height
    cu = np.floor((u - u.min(0)) / cell_m).astype(np.int64)
    cv = np.floor((v - v.min(0)) / cell_m).astype(np.int64)
    key = cu * (cv.max(0) + 1) + cv  # each axis's image cells (as _cells)
    size = key.max(0) + 1
    key += np.concatenate([[0], np.cumsum(size)[:-1]])  # a range of cells per axis: one pass for all axes
    top = np.full(size.sum(), -np.inf)
    np.maximum.at(top, key.ravel(), height.ravel())
    bottom = np.full(size.sum(), np.inf)
    np.minimum.at(bottom, key.ravel(), height.ravel())
    scores = np.maximum((height >= top[key] - tol_m).mean(0), (height <= bottom[key] + tol_m).mean(0))
    best = int(scores.argmax())
    # a sheet looks one-sided from a cone of directions: its centre is the mean of the near-best axes
    near = axes[scores >= scores[best] - near_best]
    direction = (near * np.sign(near @ axes[best])[:, None]).sum(0)
    direction /= np.linalg.norm(direction)
    return float(scores[best]), (direction if bulge(p, direction) <= 0 else -direction)


def facing_direction(
    points: np.ndarray,
    direction: np.ndarray,
    quantile: float = 0.05,
    span_deg: float = 45.0,
    max_points: int = 1500,
    k: int = 16,
) -> np.ndarray:
    """A one-sided cloud's camera direction refined from its surface normals: what a camera sees faces it,
    so the direction is the one within ``span_deg`` of ``direction`` (a first estimate, e.g.
    :func:`one_sidedness`'s, which also orients the normals) whose ``quantile`` of ``normal . d`` over up to
    ``max_points`` evenly strided points is the largest (the centre of the cone of directions every point
    faces, robust to a few bad normals); a coarse search on about 600 directions, then a fine one within
    4 degrees. Against the simulator's cameras (32 scans per view) the median error goes from 6.6 / 14.9 / 8.5
    / 20.5 degrees (front / side / back / top, the first estimate) to 5.2 / 8.1 / 5.7 / 10.6
    (experiments/single_view/facing/direction_probe.md); about 0.03 s."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    p = p[:: max(1, len(p) // max_points)]
    d0 = np.asarray(direction, dtype=np.float64)
    d0 = d0 / np.linalg.norm(d0)
    if len(p) < k:
        return d0
    _, nn = cKDTree(p).query(p, k=k)
    local = p[nn] - p[nn].mean(1, keepdims=True)
    normals = np.linalg.eigh(np.einsum("nki,nkj->nij", local, local))[1][:, :, 0]
    normals *= np.where(normals @ d0 < 0, -1.0, 1.0)[:, None]
    best = d0
    for count, span in ((4000, span_deg), (40000, 4.0)):
        dirs = sphere_directions(count)
        dirs = dirs[dirs @ best > np.cos(np.radians(span))]
        if len(dirs) == 0:
            break
        best = dirs[int(np.argmax(np.quantile(normals @ dirs.T, quantile, axis=0)))]
    return best


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
    (torch) and optionally their unit normals (``[B, V, 3]``; ``None``: computed here) giving ``[B, V]``
    bool, per scan the vertices its camera sees (:func:`visible_vertices`).
    ``views[b]``: ``(camera, direction)`` with one of them given (the camera wins), or ``None`` for a full
    scan (every vertex). ``incidence``: the body's sparse vertex-face matrix (faster normals, see
    :func:`arteq.geometry.normals.vertex_normals`)."""
    import torch

    from arteq.geometry.normals import vertex_normals

    def visible(verts: torch.Tensor, normals: torch.Tensor | None = None) -> torch.Tensor:
        if normals is None:
            normals = vertex_normals(verts.detach(), faces, incidence)
        normals = normals.detach().double().cpu().numpy()
        v = verts.detach().double().cpu()
        out = np.ones(v.shape[:2], dtype=bool)
        for b, view in enumerate(views):
            if view is not None:
                camera, direction = view
                out[b] = visible_vertices(v[b].numpy(), normals[b], camera=camera,
                                          direction=None if camera is not None else direction)  # fmt: skip
        return torch.from_numpy(out).to(verts.device)

    return visible


def _flip_y() -> np.ndarray:
    return np.diag([-1.0, 1.0, -1.0])  # 180 degrees about the part's own y (up) axis


#: The shoulders, elbows and wrists: an arm's own ``y`` is not its bone, so turning one swings it, and
#: :func:`untwist` charges them more (at 0.3 a depth image's forearm was turned: 3.8 -> 13.4 cm V2V).
ARM_PARTS = (16, 17, 18, 19, 20, 21)


def untwist(
    global_rotmats: np.ndarray, parents=None, flip_cost: float = 0.3, arm_cost: float = 0.6
) -> np.ndarray:
    """``[22]`` bool: which parts to turn by 180 degrees about their own up (``y``) axis so that the pose is
    the most plausible: the fewest and smallest parent-relative rotations. From one side a body's front and
    back look alike part by part, and a network trained on full surfaces turns single parts or chains (the
    upper body above the waist, the head, the pelvis) the wrong way round: a local rotation of 150-180
    degrees no body makes. Exact minimum over the tree (dynamic programming, two states per part) of
    ``flip_cost`` per turned part (``arm_cost`` for :data:`ARM_PARTS`) plus the angle (radians) of every
    local rotation. Turning every part
    leaves every local angle as it was (a conjugation): the body's overall heading is not decided here."""
    from arteq.body.skeleton import PARENTS

    parents = PARENTS if parents is None else parents
    g = np.asarray(global_rotmats, dtype=np.float64)
    k = len(g)
    states = np.stack([g, g @ _flip_y()])  # [2, K, 3, 3]

    def angle(a: np.ndarray, b: np.ndarray) -> float:
        return float(np.arccos(np.clip((np.trace(a.T @ b) - 1) / 2, -1.0, 1.0)))

    children = [[c for c in range(k) if parents[c] == j] for j in range(k)]
    cost = np.zeros((k, 2))  # best cost of the subtree of j given j's state
    choice = np.zeros((k, 2, k), dtype=np.int64)  # child's best state given j's state (per child index)
    for j in reversed(range(k)):  # parents precede children
        for s in (0, 1):
            total = (arm_cost if j in ARM_PARTS else flip_cost) * s
            for c in children[j]:
                opts = [cost[c, t] + angle(states[s, j], states[t, c]) for t in (0, 1)]
                choice[j, s, c] = int(np.argmin(opts))
                total += min(opts)
            cost[j, s] = total
    root_cost = [cost[0, s] + (angle(np.eye(3), states[s, 0]) * 0) for s in (0, 1)]
    out = np.zeros(k, dtype=bool)
    out[0] = bool(np.argmin(root_cost))
    for j in range(k):  # top-down
        for c in children[j]:
            out[c] = bool(choice[j, int(out[j]), c])
    return out


def _project(x: np.ndarray, camera: np.ndarray | None, direction: np.ndarray | None, ref: np.ndarray):
    """``(uv [N, 2], depth [N])`` of points ``x`` seen from a camera at ``camera`` (perspective, the image
    scaled to metres at the distance of ``ref``, a point of the body) or from far along ``direction``."""
    if camera is not None:
        c = np.asarray(camera, dtype=np.float64)
        axis = ref - c
        axis /= np.linalg.norm(axis)
        e1, e2 = _image_axes(axis)
        rel = x - c
        depth = rel @ axis
        scale = float((ref - c) @ axis)
        return np.stack([rel @ e1, rel @ e2], 1) / np.maximum(depth, 1e-6)[:, None] * scale, depth
    d = np.asarray(direction, dtype=np.float64)
    axis = -d / np.linalg.norm(d)
    e1, e2 = _image_axes(axis)
    return np.stack([x @ e1, x @ e2], 1), x @ axis


def free_space(
    vertices: np.ndarray,
    points: np.ndarray,
    camera: np.ndarray | None = None,
    direction: np.ndarray | None = None,
    cell_m: float = 0.03,
    depth_tol_m: float = 0.04,
) -> float:
    """Share of a fitted body's ``vertices [V, 3]`` where the camera saw free space: in an image cell
    (``cell_m`` wide at the body) with no scan point in it or its 8 neighbours (the camera saw past the
    body there), or more than ``depth_tol_m`` in front of the nearest scan point of their cell (it saw
    through). A body fitted the right way round is inside the scan's silhouette and behind its surface."""
    v = np.asarray(vertices, dtype=np.float64)
    p = np.asarray(points, dtype=np.float64)
    ref = p.mean(0)
    uv_p, dp = _project(p, camera, direction, ref)
    uv_v, dv = _project(v, camera, direction, ref)
    lo = np.minimum(uv_p.min(0), uv_v.min(0))
    ip = np.floor((uv_p - lo) / cell_m).astype(np.int64) + 1
    iv = np.floor((uv_v - lo) / cell_m).astype(np.int64) + 1
    shape = np.maximum(ip.max(0), iv.max(0)) + 2
    near = np.full(tuple(shape), np.inf)
    np.minimum.at(near, (ip[:, 0], ip[:, 1]), dp)
    seen = np.isfinite(near)
    grown = seen.copy()
    for du in (-1, 0, 1):
        for dv_ in (-1, 0, 1):
            grown[1:-1, 1:-1] |= seen[1 + du : shape[0] - 1 + du, 1 + dv_ : shape[1] - 1 + dv_]
    outside = ~grown[iv[:, 0], iv[:, 1]]
    through = dv < near[iv[:, 0], iv[:, 1]] - depth_tol_m
    return float((outside | through).mean())


@dataclass
class HypothesisConfig:
    """Start hypotheses of a partial scan (:func:`start_hypotheses`, :func:`pick_starts`)."""

    # the (untwisted) start turned about the body's up axis; (0, 180) adds the whole body turned round,
    # the best start in none of 48 front, side and back view scans (experiments/single_view/README.md)
    turns_deg: tuple[float, ...] = (0.0,)
    untwist: bool = True
    # whether the network's own start competes with the untwisted one (scored after the brief refinement);
    # off: the untwisted start replaces it (nearer the truth in 33 of 48 view scans, the score's pick in 29)
    keep_network: bool = False
    brief_iters: int = 12  # refinement iterations of each hypothesis before one is picked
    brief_points: int = 2000  # of the scan's points, evenly strided, for those brief refinements
    w_free: float = 10.0  # score per unit share of vertices in free space (cm^2-like units)
    sigma_cm: float = 2.0  # Geman-McClure scale of the score's distances


def turn_about(axis: np.ndarray, deg: float) -> np.ndarray:
    """Rotation matrix of ``deg`` degrees about the unit ``axis``."""
    a = np.asarray(axis, dtype=np.float64)
    a = a / np.linalg.norm(a)
    t = np.deg2rad(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + np.sin(t) * k + (1 - np.cos(t)) * (k @ k)


def start_hypotheses(body, local_rotmats, betas, transl, config: HypothesisConfig | None = None):
    """Starts of one partial scan's refinement: the prediction as it is (``network``) when :func:`untwist`
    changes it and ``config.keep_network``, and the prediction with its implausibly turned parts turned
    back, turned about its own up axis (the pelvis's ``y``) by each of ``config.turns_deg`` about its
    vertices' centroid (``untwisted`` / ``turned <deg>``; without an untwist the first of them is the
    prediction itself, ``network``). ``local_rotmats [22, 3, 3]``, ``betas [nb]``, ``transl [3]`` (torch) ->
    ``(local_rotmats [H, 22, 3, 3], betas [H, nb], transl [H, 3], names [H], untwisted [22] bool)``."""
    import torch

    from arteq.body.skeleton import global_to_local

    cfg = config or HypothesisConfig()
    dtype = body.v_template.dtype
    local = local_rotmats.detach().to(dtype)[None]
    b = betas.detach().to(dtype)[None]
    t = transl.detach().to(dtype)[None]
    with torch.no_grad():
        out = body(betas=b, pose=local, transl=t)
    g = out.global_rotmats[0].double().cpu().numpy()
    flips = untwist(g) if cfg.untwist else np.zeros(len(g), dtype=bool)
    locs, ts, names = [], [], []
    if flips.any():
        if cfg.keep_network:
            locs.append(local[0])
            ts.append(t[0])
            names.append("network")
        g = np.where(flips[:, None, None], g @ _flip_y(), g)
        local = global_to_local(torch.as_tensor(g, dtype=dtype, device=local.device))[None]
        with torch.no_grad():
            out = body(betas=b, pose=local, transl=t)
    centre = out.vertices[0].double().mean(0).cpu().numpy()
    up = g[0][:, 1]
    for deg in cfg.turns_deg:
        r = torch.as_tensor(turn_about(up, deg), dtype=dtype, device=local.device)
        lh = local.clone()
        lh[0, 0] = r @ lh[0, 0]
        with torch.no_grad():
            c0 = body(betas=b, pose=lh).vertices[0].double().mean(0).cpu().numpy()
        locs.append(lh[0])
        ts.append(torch.as_tensor(centre - c0, dtype=dtype, device=local.device))
        names.append(("untwisted" if flips.any() else "network") if deg == 0 else f"turned {deg:g}")
    h = len(locs)
    return torch.stack(locs), b.expand(h, -1).clone(), torch.stack(ts), names, flips


def hypothesis_score(
    vertices: np.ndarray,
    points: np.ndarray,
    subset: np.ndarray,
    visible: np.ndarray,
    camera: np.ndarray | None,
    direction: np.ndarray | None,
    config: HypothesisConfig | None = None,
) -> dict[str, float]:
    """The partial objective of a fitted body ``vertices [V, 3]`` against its one-sided scan ``points``
    (lower is better): scan -> body (every point to its nearest vertex) plus body -> scan (the ``subset``
    vertices the camera sees, ``visible [V]``, the worst 15 % dropped), each a mean Geman-McClure of the
    distances in cm, plus ``w_free`` times :func:`free_space`."""
    from scipy.spatial import cKDTree

    cfg = config or HypothesisConfig()
    s2 = cfg.sigma_cm**2
    p = np.asarray(points, dtype=np.float64)
    v = np.asarray(vertices, dtype=np.float64)
    d_sv = cKDTree(v).query(p[::2])[0] * 100
    sub = subset[visible[subset]]
    d_vs = np.sort(cKDTree(p).query(v[sub])[0] * 100)[: max(1, int(0.85 * len(sub)))]

    def gm(d):
        return float((s2 * d**2 / (s2 + d**2)).mean())

    fs = free_space(v, p, camera, direction)
    s2m, m2s = gm(d_sv), gm(d_vs)
    return {"s2m": s2m, "m2s": m2s, "free": fs, "score": s2m + m2s + cfg.w_free * fs}


def pick_starts(
    body,
    points: list[np.ndarray],
    probs: list[np.ndarray],
    init: dict,
    views: list[tuple[np.ndarray | None, np.ndarray | None]],
    refine_config=None,
    config: HypothesisConfig | None = None,
    subset: np.ndarray | None = None,
) -> dict:
    """The refinement starts of partial scans, each picked among its :func:`start_hypotheses`: every
    hypothesis of every scan is refined ``config.brief_iters`` iterations with the partial objective (one
    batch, on ``config.brief_points`` of each scan's points), and the start with the lowest
    :func:`hypothesis_score` after it is kept (its start: the refinement then runs from it as from the
    network's; a pick of the network's own start is the path without hypotheses, to the bit).

    Args:
        body: the body model; points: per scan ``[N, 3]`` (centred metres); probs: per scan ``[N, K]``, the
            network's part probabilities (used for the network's own body; a turned or untwisted start
            labels each point by its nearest vertex: 0.7 one-hot + 0.3 uniform).
        init: ``local_rotmats [B, 22, 3, 3]``, ``betas [B, nb]``, ``transl [B, 3]``, the network's starts.
        views: per scan ``(camera, direction)`` as for :func:`visibility_function`.
        refine_config: :class:`arteq.fit.refine.RefineConfig` (its ``iters`` replaced by
            ``config.brief_iters``); subset: the model -> scan vertex subset (default: the refinement's).
    Returns:
        ``{"init": {...} (B rows), "probs": [B] arrays [N, K], "info": [B] dicts}`` (the info: the picked
        hypothesis's name, parts untwisted, every hypothesis's name, score and free-space share).
    """
    from dataclasses import replace

    import torch
    from scipy.spatial import cKDTree

    from arteq.fit.refine import RefineConfig, body_tables, refine

    cfg = config or HypothesisConfig()
    rcfg = refine_config or RefineConfig()
    tables = body_tables(body, rcfg.m2s_vertices)
    subset = tables.m2s_subset.cpu().numpy() if subset is None else subset
    vertex_parts = body.part_labels.cpu().numpy()
    dtype, dev = body.v_template.dtype, body.v_template.device
    k = probs[0].shape[-1]

    def labelled(verts: np.ndarray, pts: np.ndarray) -> np.ndarray:
        lab = vertex_parts[cKDTree(verts).query(pts)[1]]
        return (np.eye(k)[lab] * 0.7 + 0.3 / k).astype(probs[0].dtype)

    starts, owner = [], []
    for i in range(len(points)):
        loc, bet, tr, names, flips = start_hypotheses(
            body, init["local_rotmats"][i], init["betas"][i], init["transl"][i], cfg
        )
        with torch.no_grad():
            v0 = body(betas=bet, pose=loc, transl=tr).vertices.double().cpu().numpy()
        for h, name in enumerate(names):
            own = name == "network"  # the network's own body: its own labels
            pr = probs[i] if own else labelled(v0[h], points[i])
            starts.append({"pose": loc[h], "betas": bet[h], "transl": tr[h], "probs": pr, "name": name,
                           "untwisted_parts": 0 if own else int(flips.sum())})  # fmt: skip
            owner.append(i)
    alone = {o: starts[j] for j, o in enumerate(owner) if owner.count(o) == 1}  # one start: nothing to pick
    keep = [j for j, o in enumerate(owner) if o not in alone]
    starts, owner = [starts[j] for j in keep], [owner[j] for j in keep]
    picked = {"init": {"local_rotmats": [], "betas": [], "transl": []}, "probs": [], "info": []}
    if not starts:
        for i in range(len(points)):
            _take(picked, alone[i])
        picked["init"] = {key: torch.stack(v) for key, v in picked["init"].items()}
        return picked
    hviews = [views[i] for i in owner]
    visible = visibility_function(body.faces, hviews, tables.incidence)
    stride = [slice(None, None, max(1, len(points[i]) // cfg.brief_points)) for i in owner]
    out = refine(
        body,
        torch.as_tensor(np.stack([points[i][st] for i, st in zip(owner, stride)]), dtype=dtype, device=dev),
        torch.as_tensor(np.stack([s["probs"][st] for s, st in zip(starts, stride)]), dtype=dtype, device=dev),
        {
            "local_rotmats": torch.stack([s["pose"] for s in starts]),
            "betas": torch.stack([s["betas"] for s in starts]),
            "transl": torch.stack([s["transl"] for s in starts]),
        },  # fmt: skip
        replace(rcfg, iters=cfg.brief_iters),
        m2s_visible=visible,
    )
    verts = out.vertices.double().cpu().numpy()
    vis = visible(out.vertices).cpu().numpy()
    for i in range(len(points)):
        if i in alone:
            _take(picked, alone[i])
            continue
        hs = [j for j, o in enumerate(owner) if o == i]
        scores = [hypothesis_score(verts[j], points[i], subset, vis[j], *views[i], cfg) for j in hs]
        best = hs[int(np.argmin([s["score"] for s in scores]))]
        picked["init"]["local_rotmats"].append(starts[best]["pose"])  # the start, not its brief refinement
        picked["init"]["betas"].append(starts[best]["betas"])
        picked["init"]["transl"].append(starts[best]["transl"])
        own = starts[best]["name"] == "network"
        picked["probs"].append(probs[i] if own else labelled(verts[best], points[i]))
        picked["info"].append({
            "picked": starts[best]["name"], "untwisted_parts": starts[best]["untwisted_parts"],
            "names": [starts[j]["name"] for j in hs],
            "scores": [round(s["score"], 3) for s in scores], "free": [round(s["free"], 3) for s in scores],
        })  # fmt: skip
    picked["init"] = {key: torch.stack(v) for key, v in picked["init"].items()}
    return picked


def _take(picked: dict, start: dict) -> None:
    """Append a scan's only start to ``picked`` (no brief refinement: nothing to choose between)."""
    picked["init"]["local_rotmats"].append(start["pose"])
    picked["init"]["betas"].append(start["betas"])
    picked["init"]["transl"].append(start["transl"])
    picked["probs"].append(start["probs"])
    picked["info"].append({"picked": start["name"], "untwisted_parts": start["untwisted_parts"],
                           "names": [start["name"]], "scores": [], "free": []})  # fmt: skip
