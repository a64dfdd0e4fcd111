"""experiments/fitting/user_scans.py: the scans it makes and how it scores them against the issue's goals.

No network here: the pieces are checked on their own (the run writes experiments/fitting/user_scans.md).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "experiments" / "fitting"))
import user_scans as us  # noqa: E402


def _box_mesh(size=(0.4, 1.7, 0.3)):
    import trimesh

    m = trimesh.creation.box(extents=size)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def test_surface_scan_lies_on_the_mesh_within_the_noise_and_is_not_uniform():
    from scipy.spatial import cKDTree

    v, f = _box_mesh()
    rng = np.random.default_rng(0)
    pts = us.surface_scan(v, f, 5000, rng, noise=0.0)
    assert pts.shape == (5000, 3)
    half = np.array([0.2, 0.85, 0.15])
    assert np.all(np.abs(pts) <= half + 1e-9)
    on_face = np.isclose(np.abs(pts), half, atol=1e-9).any(1)
    assert on_face.all()  # every point on the surface
    noisy = us.surface_scan(v, f, 5000, np.random.default_rng(0), noise=0.005)
    assert 0.004 < (noisy - pts).std() < 0.006  # 5 mm per axis
    # non-uniform: point counts per 10 cm slab along the long side differ far more than Poisson would
    counts = np.histogram(pts[:, 1], bins=17, range=(-0.85, 0.85))[0]
    assert counts.std() > 3 * np.sqrt(counts.mean())
    assert cKDTree(pts).query(pts, k=2)[0][:, 1].max() < 0.2


def test_curved_scan_lies_on_the_smooth_surface_through_the_vertices_not_inside_the_faces():
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)  # 320 faces: edges ~2 cm, as a limb's
    v, f = np.asarray(sphere.vertices, dtype=np.float64), np.asarray(sphere.faces, dtype=np.int64)
    flat = np.linalg.norm(us.surface_scan(v, f, 20000, np.random.default_rng(0), noise=0.0), axis=1)
    rng = np.random.default_rng(0)
    curved = np.linalg.norm(us.surface_scan(v, f, 20000, rng, noise=0.0, curved=True), axis=1)
    assert flat.mean() < 0.0992  # the faces: inside the sphere by the sag of their chords
    assert abs(curved.mean() - 0.1) < 0.5 * abs(flat.mean() - 0.1)  # the curved surface: twice as near it
    assert np.all(curved >= flat - 1e-12)  # pushed out, never in, on a convex body
    assert np.all(curved <= 0.1 + 2e-3)
    # the same draws: only the surface differs (a suite made with it keeps its bodies, poses and noise)
    n1 = us.surface_scan(v, f, 100, np.random.default_rng(3), noise=0.005)
    n2 = us.surface_scan(v, f, 100, np.random.default_rng(3), noise=0.005, curved=True)
    assert 0 < np.abs(n1 - n2).max() < 3e-3


def test_pose_templates_mirror_left_to_right_and_jitter():
    from arteq.body.skeleton import JOINT_NAMES

    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    rng = np.random.default_rng(0)
    exact = us.pose_from_template({"left_hip": (-90.0, 0.0, 10.0)}, rng, jitter_deg=0.0)
    assert exact.shape == (22, 3, 3)
    eye = torch.eye(3, dtype=torch.float64)
    assert torch.allclose(exact[j["spine1"]], eye)
    # right = left mirrored through the x = 0 plane: M R M with M = diag(-1, 1, 1)
    m = torch.diag(torch.tensor([-1.0, 1.0, 1.0], dtype=torch.float64))
    assert torch.allclose(exact[j["right_hip"]], m @ exact[j["left_hip"]] @ m, atol=1e-12)
    assert torch.allclose(exact[j["right_shoulder"]], m @ exact[j["left_shoulder"]] @ m, atol=1e-12)
    assert not torch.allclose(exact[j["left_shoulder"]], eye)  # arms hang unless the template says
    jittered = us.pose_from_template({}, np.random.default_rng(1), jitter_deg=5.0)
    assert not torch.allclose(jittered[j["spine1"]], eye)
    assert torch.allclose(jittered[0], eye)  # the root (orientation) is not jittered
    with pytest.raises(ValueError, match="unknown joints"):
        us.pose_from_template({"left_tail": (0, 0, 0)}, rng)
    for table in (us.EVERYDAY,):
        for spec in table.values():
            assert torch.isfinite(us.pose_from_template(spec, rng)).all()


def test_frames_are_rotations_and_z_up_turns_the_body_up_to_z():
    rng = np.random.default_rng(3)
    for _ in range(5):
        r = us.random_rotation(rng)
        assert np.allclose(r @ r.T, np.eye(3)) and np.isclose(np.linalg.det(r), 1.0)
        z = us.z_up_heading(rng)
        assert np.allclose(z @ z.T, np.eye(3)) and np.isclose(np.linalg.det(z), 1.0)
        assert np.allclose(z @ [0.0, 1.0, 0.0], [0.0, 0.0, 1.0])


def test_clutter_is_ten_percent_stray_or_a_room_below_and_behind_the_body():
    v, _ = _box_mesh()
    rng = np.random.default_rng(0)
    up = np.array([0.0, 1.0, 0.0])
    stray = us.clutter(v, 5000, up, "stray", rng)
    assert stray.shape == (500, 3) and np.abs(stray).max() <= 2.0 + 1e-9
    room = us.clutter(v, 5000, up, "room", np.random.default_rng(0))
    assert len(room) == 500 + 2700 + 1980 + 400
    floor = room[500 : 500 + 2700]
    assert np.abs(floor[:, 1] - (-0.85 - 0.005)).max() < 0.03  # under the lowest point, 5 mm noise
    ball = room[-400:]
    centre = ball.mean(0)
    assert np.isclose(np.linalg.norm(ball - centre, axis=1).mean(), 0.2, atol=0.01)
    assert np.linalg.norm(centre[[0, 2]]) > 0.2 + 0.7 - 0.01  # beside the body, not in it
    with pytest.raises(ValueError, match="stray or room"):
        us.clutter(v, 5000, up, "floor", rng)


def test_joint_error_uses_the_15_joints():
    from arteq.body.skeleton import JOINT_NAMES

    truth = np.zeros((22, 3))
    fitted = truth.copy()
    fitted[JOINT_NAMES.index("spine2")] = 1.0  # not one of the 15: no error
    assert us.joint_error_cm(fitted, truth) == 0.0
    fitted[JOINT_NAMES.index("left_wrist"), 0] = 0.15
    assert np.isclose(us.joint_error_cm(fitted, truth), 15.0 / 15)
    assert len(us.JOINTS_15) == 15 and set(us.JOINTS_15) <= set(JOINT_NAMES)


def _rec(group, status="ok", v2v=1.0, chamfer=0.8, **kw):
    return {"group": group, "name": f"{group} {status} {v2v}", "status": status, "v2v_cm": v2v,
            "chamfer_cm": chamfer, "body": True, "fit_s": 1.0, "anny_s": 0.3, **kw}  # fmt: skip


def test_goals_are_judged_per_group():
    good = [
        _rec("acrobatic", v2v=1.5), _rec("acrobatic", v2v=2.4),
        _rec("children", status="uncertain", v2v=1.8, stature_err_cm=-1.5),
        _rec("adults", v2v=1.2, stature_err_cm=1.0, waist_err_cm=-2.5),
        _rec("clutter", vs_clean_cm=0.8, clean_seed_spread_cm=0.5),
        {"group": "non-bodies", "name": "sphere", "status": "not_single_body", "body": False, "fit_s": 1.0},
    ]  # fmt: skip
    rows = {r["group"]: r for r in us.goals(good)}
    assert all(r["met"] for r in rows.values()), rows
    assert "1.95 mean" in rows["acrobatic"]["measured"]
    bad = [
        _rec("acrobatic", v2v=1.0), _rec("acrobatic", v2v=6.0),  # mean 3.5 and one above 5
        _rec("children", status="not_single_body", v2v=1.5, stature_err_cm=None),  # usable, refused
        _rec("adults", v2v=1.2, stature_err_cm=1.0, waist_err_cm=-3.5),  # waist off
        _rec("clutter", vs_clean_cm=1.2),
        {"group": "non-bodies", "name": "two people", "status": "uncertain", "body": False, "fit_s": 2.0},
    ]  # fmt: skip
    rows = {r["group"]: r for r in us.goals(bad)}
    assert not any(r["met"] for r in rows.values()), rows
    assert "1 of 5 usable fits refused" in rows["all bodies"]["measured"]
    assert "1 of 2 above 5 cm" in rows["acrobatic"]["measured"]
    md = us.goals_table(us.goals(bad))
    assert md.splitlines()[0] == "| group | goal | measured | met |" and md.count("| no |") == 6


def test_people_suite_has_the_issues_groups_with_ground_truth():
    pytest.importorskip("anny", reason="the ground-truth bodies come from anny's sampler")
    from scipy.spatial import cKDTree

    scans = us.people_scans(seed=0)
    groups = {}
    for s in scans:
        groups.setdefault(s.group, []).append(s)
    assert {k: len(v) for k, v in groups.items()} == {
        "acrobatic": 12, "children": 8, "adults": 12, "clutter": 6, "non-bodies": 5}  # fmt: skip
    for s in scans:
        if s.group == "non-bodies":
            assert s.vertices is None and len(s.points) == 5000
            continue
        assert s.vertices.shape == (13718, 3) and s.joints.shape == (22, 3)
        assert 0.8 < s.truth["stature_m"] < 2.1 and 0.3 < s.truth["waist_circumference_m"] < 1.6
        body = s.points if s.clean_points is None else s.clean_points
        assert len(body) == 5000
        assert cKDTree(s.vertices).query(body)[0].mean() < 0.015  # on the true surface, 5 mm noise
        if s.group == "clutter":
            assert np.array_equal(s.points[:5000], s.clean_points) and len(s.points) >= 5500
    assert all(3.0 <= s.truth["age_years"] <= 12.0 for s in groups["children"])
    assert all(s.truth["age_years"] >= 18.0 for s in groups["adults"])
    statures = [s.truth["stature_m"] for s in groups["adults"]]
    assert min(statures) < 1.55 and max(statures) > 1.9  # short to tall builds
    names = [s.name for s in groups["acrobatic"]]
    assert any(n.startswith("handstand") for n in names) and any("(child)" in n for n in names)
    again = us.people_scans(seed=0)
    assert all(np.array_equal(a.points, b.points) for a, b in zip(scans, again, strict=True))


def test_exported_scans_get_short_file_names():
    assert us.file_stem("child 6 y, stand") == "child_6y_stand"
    assert us.file_stem("adult 22 y, stand: room: floor, wall, ball, 10% stray") == "adult_22y_stand_room"
    assert us.file_stem("child 9 y, wave: 10% stray points") == "child_9y_wave_stray"
