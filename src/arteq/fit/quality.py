"""Is a fit a fit? Measured after fitting, each value with the threshold that flags it.

| value | meaning | flag (reason code) when |
|---|---|---|
| ``inlier_frac`` | scan points within ``inlier_cm`` of the fit | < ``min_inlier_frac`` (``low_inliers``) |
| ``rmse_in_cm`` | RMS distance of those inliers | > ``max_rmse_cm`` (``high_residual``) |
| ``coverage`` | spread vertices with a point within ``cover_cm`` | < ``min_coverage`` (``low_coverage``) |
| ``parts_covered`` | parts (of 22) holding >= 0.5 % of the inliers | < ``min_parts`` (``missing_parts``) |
| ``label_agree`` | inliers whose fitted part is among their 2 most probable predicted parts | reported only |
| ``max_abs_beta`` | shape plausibility (units of sigma) | > ``max_beta`` (``implausible_shape``) |
| ``extent_m`` | robust size of the cloud | outside ``extent_m_range`` (``wrong_size``) |

Clutter removal (:mod:`arteq.fit.clean`) adds the flag ``second_body`` when the scan holds a second
body-sized cluster apart from the fitted one (two people).

One human body with 10 % outliers and 5 mm noise sits well inside every threshold; two bodies side by
side, a sphere or a box fail at least one (measured: ``experiments/fitting/README.md``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class QualityThresholds:
    inlier_cm: float = 2.0
    cover_cm: float = 4.0
    min_inlier_frac: float = 0.65
    max_rmse_cm: float = 1.5
    min_coverage: float = 0.75
    min_parts: int = 14
    max_beta: float = 4.0
    extent_m_range: tuple[float, float] = (0.5, 3.0)


def fit_quality(
    points: np.ndarray,
    vertices: np.ndarray,
    vertex_parts: np.ndarray,
    subset: np.ndarray,
    betas: np.ndarray,
    part_probs: np.ndarray | None = None,
    thresholds: QualityThresholds | None = None,
) -> dict:
    """Quality values and flags of one fit.

    Args:
        points: ``[N, 3]`` scan points (metres, same frame as ``vertices``).
        vertices: ``[V, 3]`` fitted mesh; ``vertex_parts [V]`` part of each vertex; ``subset [S]`` the
            evenly spread vertices used for coverage; ``betas [nb]``.
        part_probs: ``[N, K]`` predicted part probabilities (for ``label_agree``), optional.
    Returns:
        dict of the values above plus ``flags`` (list of reason codes, empty when the fit passes).
    """
    from scipy.spatial import cKDTree

    th = thresholds or QualityThresholds()
    d, vi = cKDTree(vertices).query(points)
    inl = d < th.inlier_cm / 100
    inlier_frac = float(inl.mean())
    rmse = float(np.sqrt(np.mean(d[inl] ** 2)) * 100) if inl.any() else float("inf")
    dv, _ = cKDTree(points).query(vertices[subset])
    coverage = float((dv < th.cover_cm / 100).mean())
    fitted_part = vertex_parts[vi]
    counts = np.bincount(fitted_part[inl], minlength=22)
    parts_covered = int((counts >= 0.005 * max(1, inl.sum())).sum())
    agree = float("nan")
    if part_probs is not None and inl.any():
        top2 = np.argsort(part_probs[inl], axis=1)[:, -2:]
        agree = float((top2 == fitted_part[inl, None]).any(1).mean())
    c = points - np.median(points, axis=0)
    _, _, vt = np.linalg.svd(c[:: max(1, len(c) // 5000)], full_matrices=False)
    proj = c @ vt.T
    q = np.percentile(proj, [1, 99], axis=0)
    extent = float((q[1] - q[0]).max())
    max_beta = float(np.abs(betas).max()) if len(betas) else 0.0
    flags = []
    if inlier_frac < th.min_inlier_frac:
        flags.append("low_inliers")
    if rmse > th.max_rmse_cm:
        flags.append("high_residual")
    if coverage < th.min_coverage:
        flags.append("low_coverage")
    if parts_covered < th.min_parts:
        flags.append("missing_parts")
    if max_beta > th.max_beta:
        flags.append("implausible_shape")
    if not th.extent_m_range[0] <= extent <= th.extent_m_range[1]:
        flags.append("wrong_size")
    return {
        "inlier_frac": inlier_frac,
        "rmse_in_cm": rmse,
        "coverage": coverage,
        "parts_covered": parts_covered,
        "label_agree": agree,
        "max_abs_beta": max_beta,
        "extent_m": extent,
        "mean_dist_cm": float(d.mean() * 100),
        "flags": flags,
    }


def describe_flags(q: dict) -> str:
    """One human-readable clause for the flags of :func:`fit_quality`."""
    parts = {
        "low_inliers": f"only {q['inlier_frac']:.0%} of the points lie on the fitted body",
        "high_residual": f"inlier residual {q['rmse_in_cm']:.1f} cm",
        "low_coverage": f"the scan covers only {q['coverage']:.0%} of the fitted body",
        "missing_parts": f"points on only {q['parts_covered']} of 22 body parts",
        "implausible_shape": f"implausible shape (|beta| {q['max_abs_beta']:.1f})",
        "wrong_size": f"size {q['extent_m']:.2f} m",
        "second_body": (
            f"a second body-sized object beside it ({q.get('second_body_points', 0)} points, "
            f"{q.get('second_body_extent_m', 0.0):.1f} m across, "
            f"{q.get('second_body_gap_m', 0.0):.2f} m away)"
        ),
    }
    return "; ".join(parts[f] for f in q["flags"])
