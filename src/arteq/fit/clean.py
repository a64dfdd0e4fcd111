"""Clutter removal before the network: floors and walls, stray points, separate small objects.

A scan of a person rarely holds only the person. :func:`clean_scan` removes, in this order and with
standard means (metres, any orientation: nothing assumes an up axis):

1. **dominant planes** (``plane``): RANSAC planes (random point triplets, inliers within a band around
   the plane, the best refitted by least squares, the band then set from the inliers' own spread). A plane
   is removed only if it looks like a floor or a wall, not like a flat piece of a body or a slice through
   it: its residuals are peaked (robust spread below ``plane_max_sigma_frac`` of the search band; a slice
   through a body spreads them over the band), its inliers span at
   least ``plane_min_extent_m`` along both of their in-plane principal axes and fill at least
   ``plane_min_fill`` of their convex hull (occupied 5 cm cells, larger for sparse clouds). Up to
   ``max_planes``.

   **Noisy planes** (``plane_adaptive``): depth cameras' noise grows with distance (1 mm + 1 mm/m^2 z^2:
   2 cm at 4.5 m), and a far wall's residuals then fill the 2 cm search band. When the camera is known
   (``viewpoint``: a depth image), and for any plane whose residuals are too spread for the fixed bands,
   the band is the plane's own: refit on the inliers, band = ``plane_noise_k`` robust standard deviations
   of their residuals, repeated until it settles (at most ``plane_band_max_m``); with the camera known the
   spread is measured in ``plane_range_bins`` equal-count bins of distance from it and interpolated, so
   the band is narrow by the feet and wide on the far wall. A surface's noise settles there; a slice
   through a volume grows the band and still fails the peakedness test (its residuals over the band).
   The floor takes of the feet only what lies within its band there (the soles). A body seen from the
   front is nearly planar in depth too, and a band fitted to its spread (9.6 cm) can take in most of it:
   a plane with an adaptive band is kept only if its spread is sensor noise, independent from point to
   point (``plane_min_noise_ratio``: each residual less its 8 in-plane neighbours' median spreads about
   as much as the residuals, 1.03-1.10 on measured floors and walls), not a surface's smooth relief
   (0.14-0.66 on candidates in bodies seen from one camera). Full scans without a camera whose planes the
   fixed bands hold are cleaned exactly as without this.
2. **statistical outliers** (``outlier``): mean distance to the ``sor_k`` nearest neighbours above the
   median by more than ``sor_sigmas`` robust standard deviations (1.4826 MAD) and more than
   ``sor_min_ratio`` times the median (scans are sampled unevenly: sparse patches of a body are not
   outliers).
3. **separate clusters** (``cluster``): connected components of the points within ``cluster_radius`` of
   each other (``cluster_factor`` x the median 4-neighbour spacing, clipped to ``cluster_radius_m``); the
   largest is the body. Other components are removed unless they come within ``keep_near_m`` of it (a
   hand or limb sampled sparsely, or cut off by a hole in the scan: 30 cm, so that a 10-13 cm hole across a
   shin leaves the lower leg with the body). A second component that is itself
   body-sized (at least ``second_body_frac`` of the largest's points and ``second_body_extent_m``
   across) is *not* clutter: the scan is flagged ``second_body`` (two people, or a person next to a
   large object), which the fit turns into the status ``not_single_body`` unless the check is off.
   In one camera's view (``viewpoint`` given) the body's own parts can lie beyond occlusion edges (a
   bent-over torso hides the waist; a leg behind the other, and its foot beyond it): components within
   ``occlusion_gap_m`` of the body, or bordering it in the image (directions from the camera within
   ``occlusion_angle_factor`` angular point spacings) across a depth jump of at most ``occlusion_jump_m``,
   and so on from those, are the body. A scan without its camera's position whose largest component is one
   camera's view (``one_sided_views``; :func:`arteq.fit.partial.one_sidedness`) is grown the same way from
   the estimated camera direction (a far camera: the image is the plane across it); there body-sized
   pieces within ``one_sided_never_m`` are joined too (a torso and the legs cut from it), and the fit's
   check refuses two people fitted as one. On held-out single views given as bare points (32 per view) the
   cluster step had removed body parts from 24 side, 8 front, 4 back and 30 top-down scans (hands, lower
   legs, whole legs) and split 5 of the 128 bodies in two; with the rule 274 of 7625 side-view points are
   still removed (experiments/single_view/readings/clusters_probe.md); full surfaces are not one-sided and
   are cleaned as before.

4. **flat objects touching the body** (``object``; :func:`touching_planes`, run by the fitter after a fit
   the check doubts): a chair, a stool or a box touches the body, so the cluster step keeps it. Among all
   the points, then among those far off that fit, planes whose patch spans ``object_min_extent_m`` both
   ways with peaked residuals are objects; their points are removed and the scan fitted again
   (:meth:`arteq.fit.Fitter.fit_prepared`; experiments/fitting/contact_clutter.md).

Clouds larger than ``max_points`` are cleaned on a random subset of that size and every point takes the
label of its nearest subset point. Every input point gets a code (:data:`CODES`); counts and planes go to
the ``.npz`` and the summary. Measured on generated cluttered scans: experiments/fitting/README.md; on
noisy depth images of a person in a room: experiments/single_view/README.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

#: Per-point codes of :attr:`CleanResult.codes`.
CODES = {"kept": 0, "plane": 1, "outlier": 2, "cluster": 3, "object": 4}


@dataclass
class CleanConfig:
    """Knobs of :func:`clean_scan` (defaults measured in experiments/fitting/README.md)."""

    planes: bool = True
    max_planes: int = 3
    plane_trials: int = 600
    plane_search_band_m: float = 0.02
    plane_band_range_m: tuple[float, float] = (0.008, 0.025)
    plane_max_sigma_frac: float = 0.45
    plane_adaptive: bool = True
    plane_noise_k: float = 3.0
    plane_band_max_m: float = 0.12
    plane_range_bins: int = 8
    plane_adapt_iters: int = 8
    plane_min_noise_ratio: float = 0.8
    plane_noise_points: int = 2000
    plane_min_points_frac: float = 0.03
    plane_min_extent_m: float = 0.8
    plane_min_fill: float = 0.7
    outliers: bool = True
    sor_k: int = 8
    sor_sigmas: float = 6.0
    sor_min_ratio: float = 4.0
    clusters: bool = True
    cluster_factor: float = 4.0
    cluster_radius_m: tuple[float, float] = (0.02, 0.10)
    #: components nearer the body are kept (0.2 before 2026-12-06: a 10 cm hole across a shin left the
    #: lower leg 20-22 cm away and it was removed; experiments/fitting/holes.md)
    keep_near_m: float = 0.3
    #: one camera's view (:func:`_one_sided_parts`): body-sized components farther are never joined
    one_sided_never_m: float = 0.2
    second_body_frac: float = 0.25
    second_body_extent_m: float = 0.8
    occlusion_gap_m: float = 0.25
    occlusion_angle_factor: float = 4.0
    occlusion_angle_rad: tuple[float, float] = (0.005, 0.03)
    occlusion_jump_m: float = 0.6
    #: no camera position given: where components would be removed and the body is one camera's view, grow it
    #: as in a view from the estimated camera direction (:func:`_one_sided_parts`)
    one_sided_views: bool = True
    max_points: int = 30000
    seed: int = 0
    #: flat objects touching the body (a chair, a stool, a scanner's turntable): no cluster step can cut them
    #: off. Where the check doubts a full scan's fit, :func:`touching_planes` looks for them among the points
    #: the fit leaves more than ``object_far_m`` away, and the scan is fitted again without them
    #: (:meth:`arteq.fit.Fitter.fit_prepared`; experiments/fitting/contact_clutter.md)
    objects: bool = True
    object_far_m: float = 0.03
    object_band_m: float = 0.012
    object_min_points: int = 50
    object_min_extent_m: float = 0.15
    object_link_m: float = 0.04
    object_margin_m: float = 0.03
    object_max_planes: int = 8
    object_trials: int = 1000
    object_hypotheses: int = 30
    object_rounds: int = 2
    #: the refit is kept only if at most this share of the removed points lies within ``object_on_fit_m`` of
    #: it (points the body explains are not an object's) and it explains the points left better
    object_max_on_fit: float = 0.3
    object_on_fit_m: float = 0.015

    @classmethod
    def from_strings(cls, items: list[str] | tuple[str, ...], **base) -> CleanConfig:
        """A config from ``KEY=VALUE`` strings over ``base`` (:func:`arteq.config.dataclass_from_strings`)."""
        from arteq.config import dataclass_from_strings

        return dataclass_from_strings(cls, items, "clean", **base)


@dataclass
class CleanResult:
    """What :func:`clean_scan` removed. ``keep [N]`` bool, ``codes [N]`` int8 (:data:`CODES`)."""

    keep: np.ndarray
    codes: np.ndarray
    planes: list[dict] = field(default_factory=list)  # normal [3], offset (n.p + d = 0), points, band_m
    flags: list[str] = field(default_factory=list)
    second_cluster: dict = field(default_factory=dict)  # points, extent_m, gap_m of the largest other one
    #: flat objects touching the body, removed after a doubted fit (:func:`touching_planes`): points, extent_m
    objects: list[dict] = field(default_factory=list)
    seconds: float = 0.0

    @property
    def counts(self) -> dict[str, int]:
        """Points removed per reason (``plane``, ``outlier``, ``cluster``) and ``kept``."""
        return {name: int((self.codes == c).sum()) for name, c in CODES.items()}

    def describe(self) -> str:
        """One clause for the summary message, e.g. ``removed 9012 points on 2 planes, 498 stray points``."""
        c = self.counts
        parts = []
        if c["plane"]:
            parts.append(
                f"{c['plane']} points on {len(self.planes)} plane{'s' if len(self.planes) > 1 else ''}"
            )
        if c["outlier"]:
            parts.append(f"{c['outlier']} stray points")
        if c["cluster"]:
            parts.append(f"{c['cluster']} points in separate clusters")
        if c["object"]:
            k = len(self.objects)
            parts.append(f"{c['object']} points on {k} flat object{'s' if k > 1 else ''} touching the body")
        return ("removed " + ", ".join(parts)) if parts else ""


def linked_groups(points: np.ndarray, radius: float, tree=None) -> np.ndarray:
    """``[N]`` group labels of ``points [N, 3]``: two points share a group when a chain of points links them
    with steps shorter than ``radius`` (``tree``: a ``cKDTree`` of ``points`` already built)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    pairs = (tree or cKDTree(points)).query_pairs(radius, output_type="ndarray")
    graph = coo_matrix(
        (np.ones(len(pairs), dtype=np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(points),) * 2
    )
    return connected_components(graph, directed=False)[1]


def touching_planes(
    points: np.ndarray, dist: np.ndarray, cfg: CleanConfig | None = None, noise_m: float | None = None
) -> tuple[np.ndarray, list[dict]]:
    """Flat objects touching a body: ``(removed [N] bool, planes)`` of ``points [N, 3]`` (metres) given each
    point's distance ``dist [N]`` to a fit of the body.

    Up to ``object_max_planes`` times: a RANSAC plane among the points farther than ``object_far_m`` from
    the fit and not yet removed (band: ``plane_noise_k`` times the scan's noise ``noise_m``, at least
    ``object_band_m``; failing that, ``object_band_m``: an object's edges inflate the noise measured on the
    scan); its inliers' largest group linked by steps under ``object_link_m`` must hold
    ``object_min_points`` points, span ``object_min_extent_m`` along both of its in-plane principal axes
    (2-98 percentiles) and have peaked residuals (robust spread at most ``plane_max_sigma_frac`` of the band):
    a chair's seat or back, a platform, a box's side; not a limb, whose slice through a plane is a strip a
    few centimetres wide, nor a slice through a curved body, whose residuals fill the band. Removed are all
    points within the band over that patch's rectangle grown by ``object_margin_m``, those where the object
    touches the body included. Planes: each one's ``points`` (removed), ``extent_m`` and ``band_m``."""
    cfg = cfg or CleanConfig()
    pts = np.asarray(points, dtype=np.float64)
    rng = np.random.default_rng(cfg.seed)
    removed = np.zeros(len(pts), dtype=bool)
    planes: list[dict] = []
    kept: list[tuple] = []  # each plane's normal, offset and patch
    # the band from the scan's noise, and the narrowest band too: an object's edges and corners inflate the
    # noise measured on a scan, and a band that takes in both faces of a chair's back is not peaked
    bands = sorted({cfg.object_band_m, max(cfg.object_band_m, cfg.plane_noise_k * (noise_m or 0.0))})[::-1]
    for _ in range(cfg.object_max_planes):
        P = pts[(np.asarray(dist) > cfg.object_far_m) & ~removed]
        if len(P) < max(3, cfg.object_min_points):
            break
        normals, offsets = _plane_hypotheses(P, cfg.object_trials, rng)
        found = None
        for band in bands:
            found = _object_plane(P, normals, offsets, band, cfg)
            if found is not None:
                break
        if found is None:
            break
        n, d, patch = found
        for k, (n0, d0, patch0) in enumerate(kept):  # the same plane, cut in two where the body touches it
            if abs(n @ n0) > np.cos(np.radians(5)) and np.abs(patch @ n0 + d0).mean() < band:
                n, d, patch = n0, d0, np.concatenate([patch0, patch])
                del kept[k], planes[k]
                break
        kept.append((n, d, patch))
        basis, centre, axes, extent, lo = _rectangle(patch, n)
        w = (pts @ basis - centre) @ axes.T - lo + cfg.object_margin_m
        inside = np.all((w > 0) & (w < extent + 2 * cfg.object_margin_m), axis=1)
        region = (np.abs(pts @ n + d) < band) & inside
        removed |= region
        planes.append({"points": int(region.sum()), "extent_m": [round(float(x), 3) for x in extent],
                       "band_m": round(float(band), 4)})  # fmt: skip
    return removed, planes


def _plane_hypotheses(
    pts: np.ndarray, trials: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray]:
    """RANSAC hypotheses: the planes ``normals [M, 3]``, ``offsets [M]`` (``n.p + d = 0``) through ``trials``
    random triplets of ``pts``, degenerate ones left out."""
    tri = pts[rng.integers(0, len(pts), (trials, 3))]
    normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    norm = np.linalg.norm(normals, axis=1)
    ok = norm > 1e-9
    normals = normals[ok] / norm[ok, None]
    return normals, -(normals * tri[ok, 0]).sum(1)


def _object_plane(
    P: np.ndarray, normals: np.ndarray, offsets: np.ndarray, band: float, cfg: CleanConfig
) -> tuple[np.ndarray, float, np.ndarray] | None:
    """The first of the RANSAC planes ``normals``, ``offsets`` (most inliers of ``P`` within ``band`` first)
    whose refitted patch is an object's (:func:`touching_planes`): ``(normal, offset, patch points)``."""
    counts = (np.abs(P @ normals.T + offsets) < band).sum(0)
    for best in np.argsort(counts)[::-1][: cfg.object_hypotheses]:
        if counts[best] < cfg.object_min_points:
            return None
        n, d = normals[best], offsets[best]
        for _ in range(2):
            n, d = _refit(P, np.abs(P @ n + d) < band)
        inl = np.flatnonzero(np.abs(P @ n + d) < band)
        if len(inl) < cfg.object_min_points:
            continue
        groups = linked_groups(P[inl], cfg.object_link_m)
        patch = P[inl[groups == np.bincount(groups).argmax()]]
        if len(patch) < cfg.object_min_points:
            continue
        # peaked residuals: a surface's noise, not a slice through a curved body filling the band
        sigma = _robust_sigma(patch @ n + d)
        if (
            _rectangle(patch, n)[3].min() >= cfg.object_min_extent_m
            and sigma <= cfg.plane_max_sigma_frac * band
        ):
            return n, d, patch
    return None


def _rectangle(patch: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, ...]:
    """A plane patch's rectangle (normal ``n``): ``(basis [3, 2], centre [2], axes [2, 2], extent [2], lo
    [2])``: in-plane coordinates ``(p @ basis - centre) @ axes.T`` span ``lo`` to ``lo + extent`` (the
    patch's 2-98 percentiles along its principal axes)."""
    basis = np.stack(_plane_basis(n), 1)
    uv = patch @ basis
    centre = uv.mean(0)
    _, _, axes = np.linalg.svd(uv - centre, full_matrices=False)
    w = (uv - centre) @ axes.T
    lo, hi = np.percentile(w, 2, axis=0), np.percentile(w, 98, axis=0)
    return basis, centre, axes, hi - lo, lo


def _spacing(tree, pts: np.ndarray, k: int = 4) -> float:
    d, _ = tree.query(pts, k=k + 1)
    return float(np.median(d[:, 1:].mean(1)))


def _plane_basis(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = np.eye(3)[np.argmin(np.abs(n))]
    u = np.cross(n, a)
    u /= np.linalg.norm(u)
    return u, np.cross(n, u)


def _robust_sigma(r: np.ndarray) -> float:
    return 1.4826 * float(np.median(np.abs(r - np.median(r))))


def _noise_band(r: np.ndarray, inl: np.ndarray, ranges: np.ndarray | None, cfg: CleanConfig) -> np.ndarray:
    """``[N]`` half-width of the band around a plane: ``plane_noise_k`` robust standard deviations of the
    residuals ``r`` of the current inliers ``inl``, one for the whole plane (``ranges`` None), else as a
    function of the distance from the camera (``ranges [N]``): the spread in equal-count range bins,
    interpolated between their median ranges (held flat beyond the first and last)."""
    lo, hi = cfg.plane_band_range_m[0], cfg.plane_band_max_m
    if ranges is None:
        return np.full(len(r), float(np.clip(cfg.plane_noise_k * _robust_sigma(r[inl]), lo, hi)))
    idx = np.nonzero(inl)[0]
    idx = idx[np.argsort(ranges[idx])]
    bins = np.array_split(idx, max(1, min(cfg.plane_range_bins, len(idx) // 50)))
    centres = np.array([np.median(ranges[b]) for b in bins])
    sig = np.array([_robust_sigma(r[b]) for b in bins])
    band = np.interp(ranges, centres, cfg.plane_noise_k * sig)
    return np.clip(band, lo, hi)


def _refit(pts: np.ndarray, inl: np.ndarray) -> tuple[np.ndarray, float]:
    c = pts[inl].mean(0)
    _, _, vt = np.linalg.svd(pts[inl] - c, full_matrices=False)
    n = vt[2]
    return n, -float(n @ c)


def _adaptive_plane(
    pts: np.ndarray, n: np.ndarray, d: float, ranges: np.ndarray | None, cfg: CleanConfig
) -> tuple[np.ndarray, float, np.ndarray, float] | None:
    """The band of a plane in a noisy scan, from its own residuals: start from the search band, refit on
    the inliers, set the band to ``plane_noise_k`` robust standard deviations (per range from the camera
    when ``ranges`` is given), repeat until the band settles. A surface's noise converges there (a normal
    spread truncated at 3 sigma has a robust sigma of 3 sigma / 3); a slice through a volume, whose
    residuals fill any band evenly, grows it to ``plane_band_max_m`` and fails the peakedness test
    (residuals over the band's half-width: robust spread above ``plane_max_sigma_frac``). Returns
    ``(normal, offset, band [N], peakedness)`` or None."""
    band = np.full(len(pts), cfg.plane_search_band_m)
    for _ in range(cfg.plane_adapt_iters):
        inl = np.abs(pts @ n + d) < band
        if inl.sum() < 3:
            return None
        n, d = _refit(pts, inl)
        r = pts @ n + d
        new = _noise_band(r, np.abs(r) < band, ranges, cfg)
        done = np.allclose(new, band, rtol=0.03, atol=5e-4)
        band = new
        if done:
            break
    r = pts @ n + d
    inl = np.abs(r) < band
    if inl.sum() < 3:
        return None
    peak = _robust_sigma(r[inl] / band[inl])
    return n, d, band, peak


def _noise_ratio(uv: np.ndarray, z: np.ndarray, cfg: CleanConfig) -> float:
    """How much of the residuals' spread is point-to-point: the robust spread of each residual less the
    median of its 8 nearest neighbours' (in the plane) over the robust spread of the residuals, on at most
    ``plane_noise_points`` inliers (an even stride, no randomness). ``z [N]``: residuals in units of the
    band. Sensor noise is independent from point to point: about 1.06 (measured 1.03-1.10 on the floors and
    walls of the depth images and the cluttered scans); a body's relief, seen from one camera within a wide
    band, is smooth at that scale: 0.14-0.66 on the candidate planes of the 64 single-view test scans (0.2
    on a front view with 87 % of its points in one 9.6 cm band)."""
    from scipy.spatial import cKDTree

    take = np.linspace(0, len(z) - 1, min(len(z), cfg.plane_noise_points)).astype(np.int64)
    uv, z = uv[take], z[take]
    if len(z) < 10:
        return 1.0
    _, nb = cKDTree(uv).query(uv, k=9)
    local = z - np.median(z[nb[:, 1:]], axis=1)
    return _robust_sigma(local) / max(_robust_sigma(z), 1e-12)


def _find_plane(
    pts: np.ndarray, cfg: CleanConfig, rng: np.random.Generator, ranges: np.ndarray | None = None
) -> dict | None:
    """Best RANSAC plane of ``pts`` that looks like a floor or wall, or None. ``ranges [N]``: the points'
    distances from the camera, when it is known (the band then grows with the distance)."""
    from scipy.spatial import ConvexHull

    n_pts = len(pts)
    min_pts = max(100, int(cfg.plane_min_points_frac * n_pts))
    if n_pts < 3 or n_pts < min_pts:
        return None
    score_idx = rng.choice(n_pts, min(n_pts, 3000), replace=False)
    S = pts[score_idx]
    normals, offsets = _plane_hypotheses(pts, cfg.plane_trials, rng)
    if not len(normals):
        return None
    counts = (np.abs(S @ normals.T + offsets) < cfg.plane_search_band_m).sum(0)
    for best in np.argsort(counts)[::-1][:5]:  # the few best hypotheses, refitted and tested
        if counts[best] * n_pts / len(S) < min_pts:
            return None
        n, d = normals[best], offsets[best]
        for _ in range(2):  # least-squares refit on the inliers
            n, d = _refit(pts, np.abs(pts @ n + d) < cfg.plane_search_band_m)
        r = pts @ n + d
        near = np.abs(r) < cfg.plane_search_band_m
        sigma = _robust_sigma(r[near])
        peaked = sigma <= cfg.plane_max_sigma_frac * cfg.plane_search_band_m
        adaptive = None
        too_noisy = not peaked or 3.0 * sigma > cfg.plane_band_range_m[1]
        if cfg.plane_adaptive and (ranges is not None or too_noisy):
            # a depth image (the camera known: the band follows the noise's growth with distance), or a
            # plane too noisy for the fixed bands: the band from the plane's own noise
            adaptive = _adaptive_plane(pts, n, d, ranges, cfg)
            if adaptive is None or adaptive[3] > cfg.plane_max_sigma_frac:
                continue
            n, d, band_pts, peak = adaptive
            r = pts @ n + d
            inl = np.abs(r) < band_pts
            band = float(np.median(band_pts[inl]))
            sigma = _robust_sigma(r[inl])
        else:
            if not peaked:
                continue  # residuals spread over the whole band: a slice through a volume, not a surface
            band = float(np.clip(3.0 * sigma, *cfg.plane_band_range_m))
            inl = np.abs(r) < band
        if inl.sum() < min_pts:
            continue
        uv = pts[inl] @ np.stack(_plane_basis(n), 1)
        uv = uv - uv.mean(0)
        _, _, axes = np.linalg.svd(uv, full_matrices=False)  # in-plane principal axes of the inliers
        uv = uv @ axes.T
        lo, hi = np.percentile(uv, 2, axis=0), np.percentile(uv, 98, axis=0)
        extent = hi - lo
        if extent.min() < cfg.plane_min_extent_m:
            continue
        # fill: area of the occupied cells over the area of the inliers' convex hull (a floor or a wall
        # patch is filled; the flat side of a body in some pose is a thin or holed silhouette)
        core = uv[np.all((uv >= lo) & (uv <= hi), axis=1)]
        cell = max(0.05, float(np.sqrt(3.0 * extent[0] * extent[1] / max(1, len(core)))))
        occupied = len(np.unique(np.floor(core / cell).astype(np.int64), axis=0)) * cell**2
        fill = min(1.0, occupied / max(ConvexHull(core).volume, 1e-9))
        if fill < cfg.plane_min_fill:
            continue
        noise_ratio = None
        if adaptive is not None:
            # a band fitted to the plane's own spread also fits a body seen from the front (nearly planar
            # in depth): keep the plane only if its spread is sensor noise, independent from point to point,
            # not the smooth relief of a surface
            noise_ratio = _noise_ratio(uv, r[inl] / band_pts[inl], cfg)
            if noise_ratio < cfg.plane_min_noise_ratio:
                continue
        plane = {"normal": n, "offset": d, "inliers": inl, "band_m": band, "sigma_m": sigma,
                 "extent_m": extent.tolist(), "fill": float(fill)}  # fmt: skip
        if adaptive is not None:
            plane.update(adaptive=True, band_range_m=[float(band_pts[inl].min()), float(band_pts[inl].max())],
                         noise_ratio=float(noise_ratio))  # fmt: skip
        return plane
    return None


def _occluded_parts(
    P: np.ndarray,
    comp: np.ndarray,
    body: np.ndarray,
    viewpoint: np.ndarray | None,
    cfg: CleanConfig,
    direction: np.ndarray | None = None,
    never: np.ndarray | None = None,
) -> np.ndarray:
    """One camera's view: ``body`` grown by every component that comes within ``occlusion_gap_m`` of it,
    or that borders it in the image (directions from the camera within ``occlusion_angle_factor`` x the
    median angular spacing, clipped to ``occlusion_angle_rad``) across a depth jump of at most
    ``occlusion_jump_m``, and so on (the legs behind a bent-over torso, a leg behind the other, its foot
    beyond it: the body's own parts cut off by occlusion edges). Without the camera's position, from its
    ``direction`` (a far camera: the image is the plane across it, neighbours within
    ``occlusion_angle_factor`` x the median spacing there, clipped to ``cluster_radius_m``). Components in
    ``never`` (ids) are not joined."""
    from scipy.spatial import cKDTree

    body = body.copy()
    if viewpoint is not None:
        rays = P - np.asarray(viewpoint, float)
        dirs = rays / np.linalg.norm(rays, axis=1, keepdims=True)
        clip = cfg.occlusion_angle_rad
    else:
        from arteq.fit.partial import _image_axes

        e1, e2 = _image_axes(np.asarray(direction, float) / np.linalg.norm(direction))
        dirs = np.stack([P @ e1, P @ e2], 1)
        clip = cfg.cluster_radius_m
    angle = float(np.clip(cfg.occlusion_angle_factor * _spacing(cKDTree(dirs), dirs, 4), *clip))
    for _ in range(int(comp.max()) + 1):  # until nothing joins (at most one component a round)
        if body.all():
            break
        rest = np.nonzero(~body)[0]
        near3d = np.isfinite(
            cKDTree(P[body]).query(P[rest], k=1, distance_upper_bound=cfg.occlusion_gap_m)[0]
        )
        da, ia = cKDTree(dirs[body]).query(dirs[rest], k=1, distance_upper_bound=angle)
        beside = np.isfinite(da)
        jump = np.full(len(rest), np.inf)
        jump[beside] = np.linalg.norm(P[rest[beside]] - P[body][ia[beside]], axis=1)
        near = np.unique(comp[rest[near3d | (jump <= cfg.occlusion_jump_m)]])
        if never is not None:
            near = near[~np.isin(near, never)]
        if not len(near):
            break
        body |= np.isin(comp, near)
    return body


def _body_sized(
    P: np.ndarray, comp: np.ndarray, sizes: np.ndarray, main: int, cfg: CleanConfig
) -> np.ndarray:
    """``[C]`` bool: the components that are body-sized themselves (a second person, a large object)."""
    out = sizes >= cfg.second_body_frac * sizes[main]
    for c in np.nonzero(out)[0]:
        q = np.percentile(P[comp == c], [2, 98], axis=0)
        out[c] = np.linalg.norm(q[1] - q[0]) >= cfg.second_body_extent_m
    return out


def _gaps(P: np.ndarray, comp: np.ndarray, sizes: np.ndarray, main: int) -> np.ndarray:
    """``[C]`` each component's distance (metres) to the largest one (0 for itself)."""
    from scipy.spatial import cKDTree

    gaps = np.full(len(sizes), np.inf)
    gaps[main] = 0.0
    others = np.nonzero(comp != main)[0]
    if len(others):
        np.minimum.at(gaps, comp[others], cKDTree(P[comp == main]).query(P[others], k=1)[0])
    return gaps


def _one_sided_parts(
    P: np.ndarray,
    comp: np.ndarray,
    sizes: np.ndarray,
    main: int,
    body: np.ndarray,
    cfg: CleanConfig,
    rng: np.random.Generator,
) -> np.ndarray:
    """A scan with no camera position: where the cluster step would remove or flag components (beyond
    ``keep_near_m`` of the largest, or body-sized) and the largest is one camera's view
    (:func:`arteq.fit.partial.one_sidedness` above :data:`arteq.fit.partial.PARTIAL_SCORE`), ``body``
    grown as :func:`_occluded_parts` does from the estimated camera direction: a hand beyond an occlusion
    edge, or the legs below a torso they are cut from, are the body's, not clutter or a second person.
    Body-sized components beyond ``one_sided_never_m`` are never joined (a second person beside the body;
    one nearer is joined and left to the fit's check, which refuses two people fitted as one). A full
    surface is left as it is."""
    from arteq.fit.partial import PARTIAL_SCORE, one_sidedness

    gaps = _gaps(P, comp, sizes, main)
    big = _body_sized(P, comp, sizes, main, cfg)
    big[main] = False
    if not ((gaps > min(cfg.keep_near_m, cfg.one_sided_never_m)) | big).any():
        return body
    main_pts = P[body]
    if len(main_pts) > 4000:  # the score depends on the density: on the point count it was measured at
        main_pts = main_pts[rng.choice(len(main_pts), 4000, replace=False)]
    score, direction = one_sidedness(main_pts)
    if score <= PARTIAL_SCORE:
        return body
    never = np.nonzero(big & (gaps > cfg.one_sided_never_m))[0]
    return _occluded_parts(P, comp, body, None, cfg, direction=direction, never=never)


def _clean_subset(
    pts: np.ndarray, cfg: CleanConfig, rng: np.random.Generator, viewpoint: np.ndarray | None = None
) -> CleanResult:
    from scipy.spatial import cKDTree

    n = len(pts)
    codes = np.zeros(n, dtype=np.int8)
    planes: list[dict] = []
    ranges = None if viewpoint is None else np.linalg.norm(pts - np.asarray(viewpoint, float), axis=1)
    if cfg.planes:
        for _ in range(cfg.max_planes):
            alive = np.nonzero(codes == 0)[0]
            plane = _find_plane(pts[alive], cfg, rng, None if ranges is None else ranges[alive])
            if plane is None:
                break
            codes[alive[plane.pop("inliers")]] = CODES["plane"]
            plane["points"] = int((codes == CODES["plane"]).sum()) - sum(p["points"] for p in planes)
            plane["normal"] = plane["normal"].tolist()
            planes.append(plane)
    alive = np.nonzero(codes == 0)[0]
    if cfg.outliers and len(alive) > cfg.sor_k + 1:
        tree = cKDTree(pts[alive])
        d, _ = tree.query(pts[alive], k=cfg.sor_k + 1)
        md = d[:, 1:].mean(1)
        med = np.median(md)
        mad = 1.4826 * np.median(np.abs(md - med))
        limit = max(med + cfg.sor_sigmas * mad, cfg.sor_min_ratio * med)
        codes[alive[md > limit]] = CODES["outlier"]
    flags: list[str] = []
    second: dict = {}
    alive = np.nonzero(codes == 0)[0]
    if cfg.clusters and len(alive) > 10:
        P = pts[alive]
        tree = cKDTree(P)
        radius = float(np.clip(cfg.cluster_factor * _spacing(tree, P, 4), *cfg.cluster_radius_m))
        comp = linked_groups(P, radius, tree)
        sizes = np.bincount(comp)
        main = int(np.argmax(sizes))
        body = comp == main
        if viewpoint is not None:
            body = _occluded_parts(P, comp, body, viewpoint, cfg)
        elif cfg.one_sided_views and len(sizes) > 1:
            body = _one_sided_parts(P, comp, sizes, main, body, cfg, rng)
        main_tree = cKDTree(P[body])
        for c in np.argsort(sizes)[::-1]:
            members = comp == c
            if c == main or body[members].all():
                continue
            gap = float(main_tree.query(P[members], k=1)[0].min())
            q = np.percentile(P[members], [2, 98], axis=0)
            ext = float(np.linalg.norm(q[1] - q[0]))
            if not second:
                second = {"points": int(sizes[c]), "extent_m": ext, "gap_m": gap}
            if sizes[c] >= cfg.second_body_frac * sizes[main] and ext >= cfg.second_body_extent_m:
                if "second_body" not in flags:
                    flags.append("second_body")
                codes[alive[members]] = CODES["cluster"]  # the fit is of the largest one either way
            elif gap > cfg.keep_near_m:
                codes[alive[members]] = CODES["cluster"]
    return CleanResult(keep=codes == 0, codes=codes, planes=planes, flags=flags, second_cluster=second)


def clean_scan(
    points_m: np.ndarray, config: CleanConfig | None = None, viewpoint: np.ndarray | None = None
) -> CleanResult:
    """Clutter removal of one cloud ``[N, 3]`` in metres (finite). ``viewpoint [3]``: the camera's position
    (metres, the cloud's frame) when it is known, as for a depth image: plane bands then grow with the
    distance from it. See the module docstring."""
    import time

    from scipy.spatial import cKDTree

    cfg = config or CleanConfig()
    t0 = time.perf_counter()
    rng = np.random.default_rng(cfg.seed)
    n = len(points_m)
    if n > cfg.max_points:
        sub = np.sort(rng.choice(n, cfg.max_points, replace=False))
        res = _clean_subset(points_m[sub], cfg, rng, viewpoint)
        _, nn = cKDTree(points_m[sub]).query(points_m, k=1)
        res.codes = res.codes[nn]
        res.keep = res.codes == 0
        # plane point counts refer to the subset: rescale to the whole cloud
        for p in res.planes:
            p["points"] = int(round(p["points"] * n / cfg.max_points))
    else:
        res = _clean_subset(points_m, cfg, rng, viewpoint)
    res.seconds = time.perf_counter() - t0
    return res
