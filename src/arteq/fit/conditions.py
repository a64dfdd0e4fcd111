"""What kind of cloud a scan is: its noise and its point spacing, measured on the scan itself.

Scanners differ: a structured-light rig gives millimetres of noise and hundreds of thousands of points, a
depth camera at a few metres a centimetre or more, a quick scan a thousand points. The network was trained
on 1 mm noise, and the check's distances (:mod:`arteq.fit.quality`) were calibrated on 5000-point, 5 mm
clouds; measured on defective scans in experiments/fitting/scan_defects.md. Two values per scan:

- ``noise_m``: the surface noise, the lower quartile over up to 200 spread points of the residual standard
  deviation of a quadric fitted to their neighbours within 4 cm (a quadric follows the body's curvature,
  so what is left is noise; the lower quartile leaves out creases and touching parts, which the median
  did not: a tuck at 5 mm noise read 9.5 mm by the median, 6.3 by the quartile). Reads 0 / 5 / 10 / 15 mm
  of Gaussian noise as 0.3-0.5 / 4.6-5.2 / 8.4-9.4 / 10.5-11.6 mm (5000 points, 6 bodies): it saturates
  above 10 mm (a 4 cm neighbourhood cannot tell larger noise from shape). Only measured on clouds of at
  least :data:`MIN_POINTS_NOISE` points: on sparser ones the neighbourhoods are too small to tell noise
  from shape (``None`` then).
- ``spacing_m``: the 90th percentile of the distance of each point to its 10th nearest neighbour (the
  sparse regions' spacing). On the true mesh, a covering radius of 0.7 times it leaves at most 3 % of the
  evenly spread vertices without a point (500-5000 points, 5 mm noise, non-uniform density).

Uses: a full scan noisier than ``Fitter(denoise_above_mm=10)`` is smoothed (:func:`denoise`) for the network
only (the refinement fits the raw points, whose noise averages out); the check widens its inlier distance
and its covering radius to these values (:func:`arteq.fit.quality.fit_quality`). The user-scan suite's
bodies (5 mm noise) read at most 6.3 mm (the tuck), the check's labelled set (seed 0) at most 8.6 (a small
child's tuck), 15 mm scans at least 10.5.
"""

from __future__ import annotations

import numpy as np

#: clouds with fewer (distinct) points get no noise estimate
MIN_POINTS_NOISE = 3000


def scan_conditions(points: np.ndarray, seed: int = 0, samples: int = 200, radius_m: float = 0.04) -> dict:
    """``{"noise_m": float | None, "spacing_m": float, "points": int}`` of a cloud ``[N, 3]`` in metres."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    tree = cKDTree(p)
    k = min(11, len(p))
    d = tree.query(p, k)[0][:, -1] if k > 1 else np.zeros(len(p))
    out = {"noise_m": None, "spacing_m": float(np.quantile(d, 0.9)), "points": int(len(p))}
    if len(p) < MIN_POINTS_NOISE:
        return out
    rng = np.random.default_rng(seed)
    res = []
    centres = p[rng.choice(len(p), min(samples, len(p)), replace=False)]
    for idx in tree.query_ball_point(centres, radius_m):
        if len(idx) < 15:
            continue
        q = p[idx] - p[idx].mean(0)
        local = q @ np.linalg.eigh(q.T @ q)[1][:, ::-1]  # principal axes, the normal last
        x, y, z = local[:, 0], local[:, 1], local[:, 2]
        a = np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], 1)
        e = z - a @ np.linalg.solve(a.T @ a + 1e-12 * np.eye(6), a.T @ z)
        res.append(np.sqrt((e**2).sum() / (len(e) - 6)))
    if res:
        out["noise_m"] = float(np.quantile(res, 0.25))
    return out


def denoise(points: np.ndarray, k: int = 24) -> np.ndarray:
    """Each point moved onto the plane of its ``k`` nearest neighbours (least squares): noise along the
    surface normal averaged out, thin details (fingers) flattened a little."""
    from scipy.spatial import cKDTree

    p = np.asarray(points, dtype=np.float64)
    k = min(k, len(p))
    nb = p[cKDTree(p).query(p, k)[1]]
    c = nb.mean(1)
    d = nb - c[:, None]
    n = np.linalg.eigh(np.einsum("nki,nkj->nij", d, d))[1][:, :, 0]  # smallest eigenvector: the normal
    return p - ((p - c) * n).sum(1, keepdims=True) * n
