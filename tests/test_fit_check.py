"""The calibrated fit check (issue 19, item 4): what is refused, what is written as uncertain.

Thresholds and their measurements: experiments/fitting/check_calibration.md. Here: the two tiers on
quality values taken from that table's scans, and the shipped model through the command on a sphere
and two people side by side (refused, nothing written).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from arteq.fit.quality import REFUSE_FLAGS, describe_flags, fit_quality, quality_flags, verdict


def _flags(inlier_frac, coverage, parts=20, beta=1.0, extent=1.6, rmse=1.0):
    return quality_flags({"inlier_frac": inlier_frac, "coverage": coverage, "parts_covered": parts,
                          "max_abs_beta": beta, "extent_m": extent, "rmse_in_cm": rmse})  # fmt: skip


def _fit(points, vertices, betas, parts):
    subset = np.arange(0, len(vertices), max(1, len(vertices) // 2000))
    return fit_quality(points, vertices, parts, subset, betas)


@pytest.fixture(scope="module")
def body(anny22):
    return anny22


def test_fit_quality_tiers_on_geometry(body):
    """fit_quality itself: a body fitted exactly passes; the same body with a sphere's worth of points
    beside it explained by nothing is refused (``unexplained_points``); a sphere alone is refused
    (``no_body_surface``); the upper half of the body is uncertain (``low_coverage``), not refused;
    a child-like |beta| 5 makes an otherwise perfect fit uncertain (``implausible_shape``)."""
    from arteq.fit.demo import synthetic_scan

    s = synthetic_scan(body, "test_id", 3, 5000, offset=0.0, rotate=False)
    v, p = s["vertices"], s["points"]
    parts = body.part_labels.numpy()
    q = _fit(p, v, s["betas"], parts)
    assert q["flags"] == [] and verdict(q["flags"]) == "ok", q
    other = synthetic_scan(body, "test_id", 5, 5000, offset=0.0, rotate=False)["points"] + [0.9, 0, 0]
    q2 = _fit(np.concatenate([p, other]), v, s["betas"], parts)
    assert "unexplained_points" in q2["flags"] and verdict(q2["flags"]) == "not_single_body", q2
    rng = np.random.default_rng(0)
    sph = rng.normal(size=(5000, 3))
    sph = 0.5 * sph / np.linalg.norm(sph, axis=1, keepdims=True) + v.mean(0)
    q3 = _fit(sph, v, s["betas"], parts)
    assert "no_body_surface" in q3["flags"] and verdict(q3["flags"]) == "not_single_body", q3
    assert "sphere" in q3["flags"] and abs(q3["sphere_radius_m"] - 0.5) < 0.01, q3
    assert q["sphere_frac"] < 0.5, q  # a body is no sphere
    # a small ball is refused by its shape whatever the body explains of it (anny_scan fitted a child into a
    # 0.3 m sphere: 37 % inliers, like a badly fitted acrobatic body), also one camera's view of it
    ball = 0.3 * sph / 0.5 + rng.normal(0, 0.005, sph.shape)
    for pts in (ball, ball[ball[:, 2] > ball[:, 2].mean()]):
        qb = _fit(pts, v, s["betas"], parts)
        assert "sphere" in qb["flags"] and verdict(qb["flags"]) == "not_single_body", qb
        assert "of the points lie on a sphere of radius 0.30 m" in describe_flags(qb, ["sphere"])
    assert q["tube_frac"] < 0.6 and "tube" not in q["flags"], q  # nor a tube
    half = p[p[:, 1] > v[:, 1].mean()]
    q4 = _fit(half, v, s["betas"], parts)
    assert verdict(q4["flags"]) == "uncertain" and "low_coverage" in q4["flags"], q4
    assert not set(q4["flags"]) & set(REFUSE_FLAGS)
    q5 = _fit(p, v, np.array([5.0, *s["betas"][1:]]), parts)
    assert q5["flags"] == ["implausible_shape"] and verdict(q5["flags"]) == "uncertain", q5
    assert describe_flags(q5) == "implausible shape (|beta| 5.0)"


def test_surface_cells_count_surface_not_lone_points():
    from arteq.fit.quality import surface_cells

    rng = np.random.default_rng(0)
    sheet = np.c_[rng.uniform(0, 1.0, (4000, 2)), np.zeros(4000)]  # 1 m^2 of surface
    o = np.zeros(3)  # one grid for every cloud here
    one = surface_cells(sheet, 0.06, o)
    assert 250 <= one <= 330  # (1 / 0.06)^2 = 278 cells, a few more where the sheet meets a cell's edge
    two = surface_cells(np.concatenate([sheet, sheet + [0, 0, 0.5]]), 0.06, o)
    assert abs(two / one - 2.0) < 0.02
    strays = rng.uniform(-5, 5, (50, 3)) + [0, 0, 10]  # far from the sheet and from each other
    assert surface_cells(np.concatenate([sheet, strays]), 0.06, o) == one
    assert surface_cells(np.zeros((0, 3)), 0.06) == 0
    # against the definition, cell by cell, on clouds of every density
    import itertools

    for n in (10, 300, 3000):
        cloud = rng.normal(size=(n, 3)) * [0.2, 0.8, 0.15]
        occ = set(map(tuple, np.floor((cloud - o) / 0.06).astype(int)))
        steps = [s for s in itertools.product((-1, 0, 1), repeat=3) if any(s)]
        ref = sum(any((c[0] + a, c[1] + b, c[2] + d) in occ for a, b, d in steps) for c in occ)
        assert surface_cells(cloud, 0.06, o) == ref


def test_extra_surface_refuses_a_second_person_against_the_body_not_a_person_on_a_stool(body):
    """Two people touching, one of them fitted and partly covered (so neither ``no_body_surface`` nor
    ``unexplained_points`` holds, as for the suite's two people 0.8 m apart fitted astride both): refused as
    ``extra_surface``. A person on a stool the clean-up keeps, fitted well: most points explained, not
    refused. The body alone: a ratio near 1."""
    from arteq.fit.demo import synthetic_scan

    a = synthetic_scan(body, "test_id", 3, 5000, offset=0.0, rotate=False)
    v, p, parts = a["vertices"], a["points"], body.part_labels.numpy()
    q = _fit(p, v, a["betas"], parts)
    assert 0.9 < q["surface_ratio"] < 1.1 and "extra_surface" not in q["flags"], q
    side = v[:, 0].max() - v[:, 0].min()
    b = synthetic_scan(body, "test_id", 5, 5000, offset=0.0, rotate=False)["points"]
    b = b - [b[:, 0].min() - v[:, 0].max() - 0.02, 0, 0]  # the second person 2 cm from the first's side
    up = np.argmax(v.max(0) - v.min(0))  # the body's long axis
    unseen = p[:, up] > np.percentile(p[:, up], 80)  # the fitted person's top fifth not scanned
    q2 = _fit(np.concatenate([p[~unseen], b]), v, a["betas"], parts)
    assert 0.33 < q2["inlier_frac"] < 0.55 and q2["coverage"] < 0.85, q2  # the old rules pass it
    assert q2["surface_ratio"] > 1.4 and "extra_surface" in q2["flags"], q2
    assert verdict(q2["flags"]) == "not_single_body" and side > 0.3
    assert "times the fitted body's surface" in describe_flags(q2, ["extra_surface"])
    rng = np.random.default_rng(1)
    stool = trimesh.creation.box(extents=(0.45, 0.45, 0.45))
    seat = np.asarray(stool.sample(1500, seed=1)) + rng.normal(0, 0.005, (1500, 3))
    hips = v[parts == 0].mean(0)
    seat = seat + hips - [0, 0.225 + 0.1, 0]  # under the pelvis, its top at the seat
    q3 = _fit(np.concatenate([p, seat]), v, a["betas"], parts)
    assert q3["inlier_frac"] > 0.55 and "extra_surface" not in q3["flags"], q3


def _tube(kind: str, rng: np.random.Generator) -> np.ndarray:
    """5000 points on a line, a pole, a capsule or a flat-ended cylinder about 1.7 m long, 3 mm noise."""
    if kind == "line":
        pts = np.c_[np.linspace(-0.85, 0.85, 5000), np.zeros((5000, 2))]
    else:
        mesh = {
            "pole": trimesh.creation.cylinder(radius=0.05, height=1.7),
            "capsule": trimesh.creation.capsule(radius=0.2, height=1.3),
            "cylinder": trimesh.creation.cylinder(radius=0.15, height=1.7),
        }[kind]
        pts = np.asarray(trimesh.sample.sample_surface(mesh, 5000, seed=0)[0])
    turn = trimesh.transformations.random_rotation_matrix(rng.random(3))[:3, :3]
    return pts @ turn.T + rng.normal(0, 0.003, pts.shape) + [0.4, 1.0, -2.0]


@pytest.mark.parametrize("kind", ["line", "pole", "capsule", "cylinder"])
def test_a_tube_is_not_a_body(body, kind):
    """A line, a pole, a capsule or a cylinder the size of a person is refused (``tube``) however well a
    body wrapped round it explains its points (anny_scan fitted a child along a 1.7 m line and a 0.2 m
    capsule and wrote them as uncertain fits); the tube's radius is measured; the test body's scan lies far
    below the threshold (above)."""
    from arteq.fit.demo import synthetic_scan

    pts = _tube(kind, np.random.default_rng(3))
    s = synthetic_scan(body, "test_id", 3, 5000, offset=0.0, rotate=False)
    near = s["vertices"] - s["vertices"].mean(0) + pts.mean(0)  # a body where the tube is, as a fit would be
    q = _fit(pts, near, s["betas"], body.part_labels.numpy())
    assert q["tube_frac"] >= 0.85 and "tube" in q["flags"] and verdict(q["flags"]) == "not_single_body", q
    radius = {"line": 0.0, "pole": 0.05, "capsule": 0.2, "cylinder": 0.15}[kind]
    assert abs(q["tube_radius_m"] - radius) < 0.01, q
    assert f"lie on a tube of radius {radius:.2f} m" in describe_flags(q, ["tube"])


@pytest.mark.parametrize(
    ("values", "expected"),
    [
        # (inliers, coverage, parts, |beta|, extent): quality values of scans in check_calibration.md
        ((0.97, 0.94, 16, 0.7, 1.45), "ok"),  # everyday adult, 1.8 cm
        ((0.93, 0.99, 20, 4.5, 0.95), "uncertain"),  # 6-year-old, 2.9 cm: refused before the calibration
        ((0.94, 0.89, 19, 1.1, 1.58), "uncertain"),  # acrobatic handstand, 27 cm: accepted before
        ((0.37, 0.54, 11, 1.0, 1.81), "uncertain"),  # heavy build, cartwheel, 42 cm: a body, badly fitted
        ((0.06, 0.20, 11, 0.7, 0.98), "not_single_body"),  # sphere
        ((0.14, 0.44, 19, 2.4, 1.70), "not_single_body"),  # box
        ((0.45, 0.95, 20, 1.2, 1.70), "not_single_body"),  # two people, fitted on one of them
    ],
)
def test_verdict_on_calibration_values(values, expected):
    inl, cov, parts, beta, ext = values
    assert verdict(_flags(inl, cov, parts, beta, ext)) == expected


def test_a_lost_single_body_is_not_refused_as_something_beside_it():
    """``unexplained_points`` needs the scan to hold more surface than the fitted body: a pike's lost fit
    (user suite seed 2: 55 % inliers, 90 % coverage, surface ratio 1.09) is uncertain, written and
    flagged; with a second body's surface beside it (ratio 2.0) the same values are refused; records
    without the ratio keep the old verdict."""
    pike = {"inlier_frac": 0.546, "coverage": 0.897, "parts_covered": 20, "max_abs_beta": 1.0,
            "extent_m": 1.6, "rmse_in_cm": 1.2}  # fmt: skip
    flags = quality_flags({**pike, "surface_ratio": 1.09})
    assert "unexplained_points" not in flags and verdict(flags) == "uncertain", flags
    assert "low_inliers" in flags and "low_coverage" in flags, flags
    two = quality_flags({**pike, "surface_ratio": 2.0})
    assert "unexplained_points" in two and verdict(two) == "not_single_body", two
    assert verdict(quality_flags(pike)) == "not_single_body"


def test_shipped_model_refuses_a_sphere_two_people_and_a_capsule(body, tmp_path):
    """The shipped network through ``arteq-fit``: a sphere, two people side by side and a capsule get
    ``not_single_body`` with the reason, nothing written for them; exit code 1."""
    from arteq.fit.cli import main as cli_main
    from arteq.fit.demo import synthetic_scan
    from arteq.pretrained import available

    if "anny22" not in available():
        pytest.skip("the shipped model src/arteq/pretrained/anny22.ckpt is not in this tree")
    rng = np.random.default_rng(1)
    sph = rng.normal(size=(5000, 3))
    sph = 0.45 * sph / np.linalg.norm(sph, axis=1, keepdims=True) + [0.3, 1.0, -0.5]
    a = synthetic_scan(body, "test_id", 11, 2500, offset=0.0, rotate=False)
    b = synthetic_scan(body, "test_id", 12, 2500, offset=0.0, rotate=False)
    second = b["points"] - b["vertices"].mean(0) + a["vertices"].mean(0) + [0.8, 0, 0]
    pair = np.concatenate([a["points"], second])
    capsule = _tube("capsule", rng)
    for name, pts in (("sphere", sph), ("pair", pair), ("capsule", capsule)):
        (tmp_path / f"{name}.ply").write_bytes(trimesh.PointCloud(pts).export(file_type="ply"))
    out = tmp_path / "fits"
    rc = cli_main([str(tmp_path / f"{n}.ply") for n in ("sphere", "pair", "capsule")]
                  + ["--out", str(out), "--device", "cpu", "--no-anny", "--no-preview"])  # fmt: skip
    rows = {r["name"]: r for r in json.loads((out / "summary.json").read_text())["inputs"]}
    assert rc == 1
    for name in ("sphere", "pair", "capsule"):
        assert rows[name]["status"] == "not_single_body", rows[name]
        assert ": not a single body (" in rows[name]["message"]
        assert list(out.glob(f"{name}.*")) == []


def _calibration_module():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "experiments" / "fitting" / "check_calibration.py"
    spec = importlib.util.spec_from_file_location("check_calibration", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_calibration_script_set_and_table():
    """experiments/fitting/check_calibration.py (rerun with --model for the next network): its labelled set
    has every group with ground truth for the bodies, and its table counts false refusals / acceptances
    as check_calibration.md defines them."""
    cal = _calibration_module()
    items = cal.labelled_set(seed=0)
    groups = {}
    for it in items:
        groups[it["group"]] = groups.get(it["group"], 0) + 1
        assert it["points"].ndim == 2 and it["points"].shape[1] == 3 and len(it["points"]) >= 5000
        assert (it.get("vertices") is None) == (it["group"] == "non-bodies"), it["name"]
    assert groups == {"everyday adults": 8, "children 3-12 y": 10, "heavy / extreme builds": 10,
                      "acrobatic adults": 12, "10% clutter": 5, "non-bodies": 9}  # fmt: skip
    ages = [int(it["name"].split("_")[1][:-1]) for it in items if it["group"] == "children 3-12 y"]
    assert all(3 <= a <= 12 for a in ages), ages
    good = {"inlier_frac": 0.95, "rmse_in_cm": 1.0, "coverage": 0.97, "parts_covered": 20,
            "max_abs_beta": 1.0, "extent_m": 1.6, "flags": []}  # fmt: skip
    child = {**good, "max_abs_beta": 4.5, "flags": ["implausible_shape"]}

    def rec(name, status, usable, body, quality):
        return {"group": "g", "name": name, "status": status, "usable": usable, "body": body,
                "quality": quality, "chamfer_cm": 1.0 if body else None}  # fmt: skip

    recs = [
        rec("a", "ok", True, True, good),
        rec("b", "uncertain", True, True, child),  # refused before (|beta| > 4), written now
        rec("c", "ok", False, True, good),  # unusable body as plain ok: false acceptance before and after
        rec("d", "uncertain", False, False, good),  # a non-body written: false acceptance after
    ]
    lines = [line.split(" | ") for line in cal.table(recs).splitlines()[2:] if line.startswith("| all ")]
    # columns: group, scans, usable, before FR, before FA, after FR, after FA, ...
    assert lines[0][1:7] == ["4", "2", "1", "2", "0", "2"], lines


def test_off_fit_group_against_a_reference():
    """The largest linked group of off-fit points, against a breadth-first search over all pairs."""
    from arteq.fit.quality import off_fit_group

    rng = np.random.default_rng(3)
    for n in (1, 2, 40, 300):
        pts = rng.uniform(0, 0.5, (n, 3))
        dist = rng.uniform(0, 0.06, n)
        far = pts[dist > 0.03]
        seen, best = set(), []
        for i in range(len(far)):
            if i in seen:
                continue
            todo, comp = [i], []
            seen.add(i)
            while todo:
                k = todo.pop()
                comp.append(k)
                for m in np.flatnonzero(np.linalg.norm(far - far[k], axis=1) < 0.08):
                    if int(m) not in seen:
                        seen.add(int(m))
                        todo.append(int(m))
            best = max(best, comp, key=len)
        size, extent = off_fit_group(pts, dist, 0.03, 0.08)
        assert size == len(best)
        ref = np.linalg.norm(far[best].max(0) - far[best].min(0)) if len(best) > 1 else 0.0
        assert extent == pytest.approx(ref)


def test_off_fit_limb_doubts_a_fit_with_a_forearm_elsewhere_not_stray_points(body):
    """A fit whose left forearm and hand are turned 120 deg about the elbow, away from their points: those
    points lie off the fit together, a limb's length across (``off_fit_limb``, uncertain, not refused). The
    body fitted exactly, and the same with 3 % stray points scattered round it: no such group."""
    import roma
    import torch

    from arteq.body.skeleton import JOINT_NAMES
    from arteq.fit.demo import synthetic_scan
    from arteq.fit.refine import branch_parts

    s = synthetic_scan(body, "test_id", 3, 5000, offset=0.0, rotate=False)
    v, p, parts = s["vertices"], s["points"], body.part_labels.numpy()
    q = _fit(p, v, s["betas"], parts)
    assert q["off_group_frac"] < 0.005 and "off_fit_limb" not in q["flags"], q
    rng = np.random.default_rng(0)
    strays = rng.uniform(v.min(0) - 0.5, v.max(0) + 0.5, (150, 3))
    q2 = _fit(np.concatenate([p, strays]), v, s["betas"], parts)
    assert q2["off_group_frac"] < 0.005 and "off_fit_limb" not in q2["flags"], q2
    with torch.no_grad():
        betas, pose = torch.as_tensor(s["betas"])[None].float(), torch.as_tensor(s["pose"])[None].float()
        out = body(betas=betas, pose=pose)
    joints = out.joints[0].double().numpy() + s["transl"]
    el, wr = JOINT_NAMES.index("left_elbow"), JOINT_NAMES.index("left_wrist")
    axis = np.cross(joints[wr] - joints[el], [0.0, 0.0, 1.0])
    turn = roma.rotvec_to_rotmat(torch.as_tensor(axis / np.linalg.norm(axis) * np.radians(120))).numpy()
    moved = np.isin(parts, branch_parts(el))
    wrong = v.copy()
    wrong[moved] = (v[moved] - joints[el]) @ turn.T + joints[el]
    q3 = _fit(p, wrong, s["betas"], parts)
    assert q3["off_group_cm"] > 20 and "off_fit_limb" in q3["flags"], q3
    assert verdict(q3["flags"]) == "uncertain"
    assert "cm across, lie off the fit together" in describe_flags(q3, ["off_fit_limb"])
