"""A scan's noise and spacing (arteq.fit.conditions) and what the fitter does with them: the check's
distances grow with a noisy or sparse cloud, and a noisy full surface reaches the network smoothed.
Measured on defective scans: experiments/fitting/scan_defects.md."""

from __future__ import annotations

import numpy as np
import pytest

from arteq.fit.conditions import MIN_POINTS_NOISE, denoise, scan_conditions
from arteq.fit.quality import fit_quality


@pytest.fixture(scope="module")
def scan(anny22):
    """A posed body and 20000 noise-free points on its surface (area-uniform)."""
    import trimesh

    from arteq.fit.demo import synthetic_scan

    s = synthetic_scan(anny22, "test_id", 3, 5000, offset=0.0, rotate=False)
    mesh = trimesh.Trimesh(s["vertices"], anny22.faces.numpy(), process=False)
    s["points"] = np.asarray(trimesh.sample.sample_surface(mesh, 20000, seed=0)[0])
    return anny22, s


def _noisy(points, sigma, seed=0):
    return points + np.random.default_rng(seed).normal(0.0, sigma, points.shape)


def test_noise_estimate_follows_the_noise_and_is_none_on_sparse_clouds(scan):
    """The estimate reads 0, 5 and 10 mm of Gaussian noise within 2 mm, grows with it, and is not made on
    clouds sparser than MIN_POINTS_NOISE; the spacing grows as the cloud thins."""
    _, s = scan
    p = s["points"][:5000]
    est = [scan_conditions(_noisy(p, sig))["noise_m"] for sig in (0.0, 0.005, 0.010)]
    assert est[0] < 0.003 and abs(est[1] - 0.005) < 0.002 and abs(est[2] - 0.010) < 0.002, est
    sparse = scan_conditions(p[: MIN_POINTS_NOISE - 1])
    assert sparse["noise_m"] is None and sparse["points"] == MIN_POINTS_NOISE - 1
    assert scan_conditions(p[:1000])["spacing_m"] > 1.5 * scan_conditions(p)["spacing_m"]


def test_denoise_moves_points_toward_the_surface(scan):
    """Smoothing a 15 mm noisy cloud brings it at least a third closer to the true surface (11.4 -> 6.8 mm
    when written)."""
    import torch
    from scipy.spatial import cKDTree

    from arteq.geometry.normals import vertex_normals

    body, s = scan
    v = s["vertices"]
    n = vertex_normals(torch.as_tensor(v)[None], body.faces)[0].numpy()
    tree = cKDTree(v)

    def to_surface(x):  # along the nearest vertex's normal (the Anny mesh is fine: a few mm between vertices)
        i = tree.query(x)[1]
        return np.abs(((x - v[i]) * n[i]).sum(1)).mean()

    p = _noisy(s["points"][:5000], 0.015)
    before, after = to_surface(p), to_surface(denoise(p))
    assert after < 0.65 * before, (before, after)


def test_check_widens_its_distances_for_noisy_and_sparse_scans(scan):
    """The true body under 15 mm noise, or under 800 points, is a good fit: without the scan's conditions
    the check doubts it (too few inliers / too little coverage); with them it passes, and its distances say
    what it used. A sphere stays refused with the widened distances."""
    body, s = scan
    v, betas, parts = s["vertices"], s["betas"], body.part_labels.numpy()
    subset = np.arange(0, len(v), max(1, len(v) // 2000))
    noisy = _noisy(s["points"][:5000], 0.015)
    q0 = fit_quality(noisy, v, parts, subset, betas)
    assert "low_inliers" in q0["flags"], q0
    q1 = fit_quality(noisy, v, parts, subset, betas, conditions=scan_conditions(noisy))
    assert q1["flags"] == [] and q1["inlier_cm"] > 2.5, q1
    sparse = s["points"][:800]
    q2 = fit_quality(sparse, v, parts, subset, betas)
    assert "low_coverage" in q2["flags"], q2
    q3 = fit_quality(sparse, v, parts, subset, betas, conditions=scan_conditions(sparse))
    assert q3["flags"] == [] and q3["cover_cm"] > 4.0, q3
    rng = np.random.default_rng(0)
    sph = rng.normal(size=(5000, 3))
    sph = _noisy(0.5 * sph / np.linalg.norm(sph, axis=1, keepdims=True) + v.mean(0), 0.015)
    q4 = fit_quality(sph, v, parts, subset, betas, conditions=scan_conditions(sph))
    assert "no_body_surface" in q4["flags"] and "sphere" in q4["flags"], q4


def test_fitter_smooths_a_noisy_full_scan_for_the_network_only(scan):
    """Through the public API (network only, for speed): a 15 mm noisy scan is marked denoised and reports
    its noise; a 2 mm one is not; ``denoise_above_mm=None`` turns it off."""
    from arteq.fit import Fitter

    _, s = scan
    f = Fitter(ckpt="anny22", device="cpu", refine=False, anny=False, second_start=False)
    noisy = f.fit_points(_noisy(s["points"][:5000], 0.015))
    assert noisy.quality["denoised"] and noisy.quality["noise_mm"] > 8, noisy.quality
    quiet = f.fit_points(_noisy(s["points"][:5000], 0.002))
    assert not quiet.quality["denoised"] and quiet.quality["noise_mm"] < 5, quiet.quality
    off = Fitter(ckpt="anny22", device="cpu", refine=False, anny=False, second_start=False,
                 denoise_above_mm=None)  # fmt: skip
    assert not off.fit_points(_noisy(s["points"][:5000], 0.015)).quality["denoised"]
    # one camera's view is not smoothed (the single views' depth noise is in the network's training)
    view = Fitter(ckpt="anny22", device="cpu", refine=False, anny=False, second_start=False, partial=True)
    assert not view.fit_points(_noisy(s["points"][:5000], 0.015)).quality["denoised"]
    assert noisy.summary_row()["noise_mm"] == noisy.quality["noise_mm"]
