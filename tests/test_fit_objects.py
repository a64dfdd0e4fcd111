"""Flat objects touching the body (a chair, a stool, a platform): found among the points a doubted fit leaves
off it (arteq.fit.clean.touching_planes) and removed before the scan is fitted again (Fitter's ``objects``
step; experiments/fitting/contact_clutter.md)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from arteq.fit.clean import CODES, CleanConfig, touching_planes
from arteq.fit.demo import synthetic_scan
from fit_helpers import write_tiny_checkpoint
from test_fit_cli import OracleFitter

NOISE = 0.005


def _cylinder(radius, length, n, rng, axis=2):
    """Points on a closed-ended cylinder's side along ``axis``, centred at the origin, with noise."""
    t, h = rng.uniform(0, 2 * np.pi, n), rng.uniform(-length / 2, length / 2, n)
    p = np.stack([radius * np.cos(t), radius * np.sin(t), h], 1)
    return np.roll(p, axis - 2, axis=1) + rng.normal(0, NOISE, (n, 3))


def _board(centre, u, v, size_u, size_v, n, rng):
    s = rng.uniform(-0.5, 0.5, (n, 2)) * [size_u, size_v]
    normal = np.cross(u, v)
    return centre + s[:, :1] * u + s[:, 1:] * v + rng.normal(0, NOISE, (n, 1)) * normal


def test_a_board_against_a_torso_is_found_and_the_torso_kept():
    """A torso (cylinder r = 15 cm) with a 50 x 45 cm board against its back: the board's points go, those
    where it touches the torso included; the torso, curved everywhere, loses at most a few."""
    rng = np.random.default_rng(0)
    torso = _cylinder(0.15, 0.6, 4000, rng)
    board = _board(np.array([0.0, -0.17, 0.0]), np.eye(3)[0], np.eye(3)[2], 0.5, 0.45, 700, rng)
    pts = np.concatenate([torso, board])
    dist = np.abs(np.linalg.norm(pts[:, :2], axis=1) - 0.15)  # to a fit that is the torso itself
    dist[np.abs(pts[:, 2]) > 0.3] = 1.0  # (and nothing beyond its ends)
    removed, planes = touching_planes(pts, dist, noise_m=NOISE)
    assert len(planes) >= 1 and planes[0]["extent_m"][0] >= 0.4
    assert removed[len(torso) :].mean() > 0.95
    assert removed[: len(torso)].mean() < 0.01


def test_limbs_and_curved_bodies_off_the_fit_are_not_taken_for_objects():
    """Off the fit but not flat: a forearm (tube r = 3.5 cm, 30 cm) and a whole torso (r = 15 cm) that the
    fit missed entirely are left; so is a board smaller than ``object_min_extent_m`` across."""
    rng = np.random.default_rng(1)
    limb = _cylinder(0.035, 0.3, 600, rng, axis=0) + [0.5, 0, 0]
    torso = _cylinder(0.15, 0.6, 4000, rng) + [0, 1.0, 0]
    strip = _board(np.array([-1.0, 0, 0]), np.eye(3)[0], np.eye(3)[1], 0.5, 0.1, 400, rng)
    pts = np.concatenate([limb, torso, strip])
    removed, planes = touching_planes(pts, np.ones(len(pts)), noise_m=NOISE)
    assert not removed.any() and planes == []
    # such a board made wide enough is an object (beside the strip, which stays)
    board = _board(np.array([-1.0, 0, 0.5]), np.eye(3)[0], np.eye(3)[1], 0.5, 0.3, 1200, rng)
    removed, planes = touching_planes(
        np.concatenate([pts, board]), np.ones(len(pts) + len(board)), noise_m=NOISE
    )
    assert len(planes) == 1 and removed[len(pts) :].mean() > 0.95 and not removed[: len(pts)].any()


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory, tiny_net):
    return write_tiny_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny.ckpt", tiny_net)


def test_a_scan_with_a_board_touching_the_body_is_fitted_again_without_it(anny22, tiny_ckpt):
    """The fitter on a body scan with a board (60 x 50 cm, a quarter as many points as the body) against its
    back, the network a perturbed truth: with the objects step the board's points are coded ``object``, the
    body keeps its own, the refit stays flagged and lies nearer the truth than the fit with the board."""
    s = synthetic_scan(anny22, "test_id", index=0, seed=5, offset=1.0)
    rng = np.random.default_rng(3)
    v, up = s["vertices"], s["rotation"] @ np.array([0.0, 1.0, 0.0])
    front = s["rotation"] @ np.array([0.0, 0.0, 1.0])
    side = np.cross(up, front)
    centre = v.mean(0)
    back = ((v - centre) @ front).min()
    board = _board(centre + (back - 0.012) * front, side, up, 0.6, 0.5, 1250, rng)
    pts = np.concatenate([s["points"], board])
    nb = len(s["points"])
    fits = {}
    for objects in (False, True):
        f = OracleFitter(ckpt=tiny_ckpt, device="cpu", anny=False, clean_config=CleanConfig(objects=objects))
        f.truth = s
        r = f.fit_points(pts, name="board")
        fits[objects] = r
        assert r.vertices is not None
    off, on = fits[False], fits[True]
    assert not (off.point_clutter == CODES["object"]).any() and off.clean.counts["object"] == 0
    assert off.status != "ok"  # the check doubts the fit with the board
    board_gone = (on.point_clutter[nb:] == CODES["object"]).mean()
    body_gone = (on.point_clutter[:nb] == CODES["object"]).mean()
    assert board_gone > 0.8 and body_gone < 0.02, (board_gone, body_gone)
    assert on.clean.counts["object"] == int((on.point_clutter == CODES["object"]).sum()) and on.clean.objects
    assert on.status != "ok" and "refitted" in on.quality["flags"]  # picked by its surface: stays flagged
    assert "flat object" in on.message and on.timings["objects"] > 0
    v2v = {k: float(np.linalg.norm(r.vertices - v, axis=1).mean()) for k, r in fits.items()}
    assert v2v[True] < v2v[False], v2v
    assert on.summary_row()["removed_object"] == on.clean.counts["object"]
    assert on.arrays()["clutter_object"] == on.clean.counts["object"]
    objects = json.loads(json.dumps(on.to_json()))["clutter_objects"]  # what a person reads
    assert objects and all(min(o["extent_m"]) >= 0.15 and o["points"] > 0 for o in objects)
    assert json.loads(json.dumps(off.to_json()))["clutter_objects"] == []


def test_a_box_is_still_refused_when_all_of_it_is_flat(tiny_ckpt):
    """A box (every face a plane) is refused as before: the objects step would leave nothing to fit, so the
    first fit's verdict stands (no points coded ``object``, no crash on an empty cloud)."""
    import trimesh

    from arteq.fit import Fitter

    p, _ = trimesh.sample.sample_surface(trimesh.creation.box(extents=(0.6, 0.9, 0.6)), 5000, seed=0)
    p = np.asarray(p) + np.random.default_rng(0).normal(0, NOISE, (5000, 3))
    r = Fitter(ckpt=tiny_ckpt, device="cpu", anny=False).fit_points(p, name="box")
    assert r.status == "not_single_body", r.message
    assert not (r.point_clutter == CODES["object"]).any()
