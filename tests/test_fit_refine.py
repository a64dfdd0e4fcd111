"""Refinement (arteq.fit.refine) and the single-body check (arteq.fit.quality), from starts the
test controls: the ground truth perturbed, with a stated fraction of wrong part labels."""

from __future__ import annotations

import numpy as np
import pytest
import roma
import torch

from arteq.body.skeleton import JOINT_NAMES, PARENTS
from arteq.fit.demo import synthetic_scan
from arteq.fit.quality import fit_quality
from arteq.fit.refine import (
    RefineConfig,
    _KDTreeMatcher,
    _TorchMatcher,
    allowed_parts,
    body_tables,
    branch_parts,
    refine,
    refine_iteration,
    sphere_directions,
    swing_search,
    turn_joint_ids,
    twist_search,
)
from arteq.geometry.normals import vertex_normals


@pytest.fixture(scope="module")
def body():
    from arteq.body import load_body_model

    return load_body_model("anny22")


def perturbed_start(s, centre, rng, rot=0.15, betas=0.5, transl=0.03):
    pose = torch.as_tensor(s["pose"], dtype=torch.float32)[None]
    axis = rng.normal(size=(1, 22, 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    pert = roma.rotvec_to_rotmat(torch.as_tensor(axis * rot, dtype=torch.float32))
    off = rng.normal(size=3)
    return {
        "local_rotmats": pose @ pert,
        "betas": torch.as_tensor(s["betas"] + betas * rng.normal(size=10), dtype=torch.float32)[None],
        "transl": torch.as_tensor(
            s["transl"] - centre + transl * off / np.linalg.norm(off), dtype=torch.float32
        )[None],
    }


def noisy_probs(labels, rng, wrong=0.2):
    lab = np.where(labels < 0, rng.integers(0, 22, len(labels)), labels)
    lab = np.where(rng.random(len(lab)) < wrong, rng.integers(0, 22, len(lab)), lab)
    return torch.as_tensor(np.eye(22)[lab] * 0.7 + 0.3 / 22, dtype=torch.float32)


def v2v_cm(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1).mean() * 100)


@pytest.mark.parametrize("outliers", [0.0, 0.1])
def test_refinement_recovers_the_body_from_a_perturbed_start(body, outliers):
    """ID and OOD scans (5000 points, 5 mm noise, random orientation, 2 m offset), start = truth with
    every joint rotated 0.15 rad, betas +0.5 sigma, translation 3 cm off; 20 % wrong part labels.
    Bounds (measured 1.2-2.2 cm per scan, experiments/fitting/README.md): mean V2V < 2.5 cm, every scan
    < 3.5 cm and at least 4x better than its start."""
    starts, ends = [], []
    for i, split in enumerate(["test_id", "test_ood", "test_ood"]):
        rng = np.random.default_rng(i)
        s = synthetic_scan(body, split, i, 5000, offset=2.0, outliers=outliers)
        c = s["points"].mean(0)
        pts = torch.as_tensor(s["points"] - c, dtype=torch.float32)[None]
        init = perturbed_start(s, c, rng)
        with torch.no_grad():
            v0 = body(betas=init["betas"], pose=init["local_rotmats"], transl=init["transl"]).vertices[0]
        out = refine(body, pts, noisy_probs(s["labels"], rng)[None], init, RefineConfig())
        starts.append(v2v_cm(v0.numpy() + c, s["vertices"]))
        ends.append(v2v_cm(out.vertices[0].numpy() + c, s["vertices"]))
    assert np.mean(ends) < 2.5, (starts, ends)
    assert max(ends) < 3.5, (starts, ends)
    assert all(e < s / 4 for s, e in zip(starts, ends)), (starts, ends)


@pytest.mark.parametrize("subset", ["random", "fps"])
def test_batched_refinement_matches_one_by_one(body, subset):
    """Scans are independent, also when the objective uses a subset of their points (``points``)."""
    rng = np.random.default_rng(3)
    scans = [synthetic_scan(body, "test_ood", i, 1000, offset=0.0) for i in range(2)]
    cfg = RefineConfig(iters=6, points=600, subset=subset)
    pts = torch.stack([torch.as_tensor(s["points"], dtype=torch.float32) for s in scans])
    inits = [perturbed_start(s, 0.0, rng) for s in scans]
    probs = torch.stack([noisy_probs(s["labels"], rng) for s in scans])
    batch = refine(body, pts, probs, {k: torch.cat([i[k] for i in inits]) for k in inits[0]}, cfg)
    for j in range(2):
        one = refine(body, pts[j : j + 1], probs[j : j + 1], inits[j], cfg)
        torch.testing.assert_close(one.vertices[0], batch.vertices[j], atol=2e-4, rtol=0)


@pytest.mark.parametrize("backend", ["kdtree", "torch"])
def test_stopped_rows_keep_their_fit_and_the_others_go_on_unchanged(body, backend):
    """``stop``: a row stopped at a re-matching iteration keeps its fit of that iteration (what the
    callback saw there in a run without ``stop``), the rows still refined end as in that run, in their
    places; a model -> scan visibility function still sees the whole batch."""
    rng = np.random.default_rng(5)
    scans = [synthetic_scan(body, "test_ood", i, 800, offset=0.0) for i in range(3)]
    cfg = RefineConfig(iters=12, backend=backend, swing_at=-1)
    at = refine_iteration(cfg, 0.5)
    assert at == 5  # the first free iteration (the gated phase: 0.4 of 12, rounded): matches renewed
    pts = torch.stack([torch.as_tensor(s["points"], dtype=torch.float32) for s in scans])
    inits = [perturbed_start(s, 0.0, rng) for s in scans]
    init = {k: torch.cat([i[k] for i in inits]) for k in inits[0]}
    probs = torch.stack([noisy_probs(s["labels"], rng) for s in scans])
    seen = {}
    full = refine(body, pts, probs, init, cfg, callback=lambda it, v: seen.setdefault(it, v.clone()))
    calls, sizes = [], []

    def stop(it, rows, verts):
        calls.append((it, rows.tolist()))
        return rows == 1

    def everyone(verts, normals):
        # the re-match's own vertex normals of these vertices come along (no second computation)
        sizes.append(verts.shape[0])
        torch.testing.assert_close(normals, vertex_normals(verts, body.faces), atol=1e-5, rtol=0)
        return torch.ones(verts.shape[:2], dtype=torch.bool)

    out = refine(body, pts, probs, init, cfg, stop=stop, stop_at=(at,), m2s_visible=everyone)
    assert calls == [(at, [0, 1, 2])]
    assert set(sizes) == {3}
    torch.testing.assert_close(out.vertices[1], seen[at][1], atol=1e-5, rtol=0)
    for j in (0, 2):
        torch.testing.assert_close(out.vertices[j], full.vertices[j], atol=2e-4, rtol=0)
    assert v2v_cm(out.vertices[1], full.vertices[1]) > 0.05  # it did stop
    # stopping every row, or none, changes nothing
    for rule in (lambda it, r, v: torch.ones(len(r), dtype=torch.bool), lambda it, r, v: r < 0):
        same = refine(body, pts, probs, init, cfg, stop=rule, stop_at=(at,))
        torch.testing.assert_close(same.vertices, full.vertices, atol=2e-4, rtol=0)


def test_kdtree_matches_are_the_same_on_a_thread_pool(body):
    """``workers=2`` spreads a batch's scans over two threads: the same matches as one by one."""
    rng = np.random.default_rng(1)
    scans = [synthetic_scan(body, "test_ood", i, 600, offset=0.0) for i in range(3)]
    pts = torch.stack([torch.as_tensor(s["points"], dtype=torch.float32) for s in scans])
    allowed = allowed_parts(torch.stack([noisy_probs(s["labels"], rng, wrong=0.4) for s in scans]))
    verts = torch.stack([torch.as_tensor(s["vertices"], dtype=torch.float32) for s in scans]) + 0.01
    one, two = (_KDTreeMatcher(pts, allowed, body.part_labels, w) for w in (1, 2))
    for gated in (True, False):
        assert torch.equal(one.scan_to_model(verts, gated), two.scan_to_model(verts, gated))
    assert torch.equal(one.model_to_scan(verts[:, :300]), two.model_to_scan(verts[:, :300]))
    assert torch.equal(one.rows(np.array([True, False, True])).model_to_scan(verts[[0, 2], :300]),
                       one.model_to_scan(verts[:, :300])[[0, 2]])  # fmt: skip


def test_kdtree_and_torch_matchers_agree(body):
    """Same nearest vertices, gated by part and free (the GPU path run on CPU)."""
    s = synthetic_scan(body, "test_ood", 1, 600, offset=0.0)
    rng = np.random.default_rng(0)
    pts = torch.as_tensor(s["points"], dtype=torch.float32)[None]
    allowed = allowed_parts(noisy_probs(s["labels"], rng, wrong=0.4)[None])
    verts = torch.as_tensor(s["vertices"], dtype=torch.float32)[None] + 0.01
    kd = _KDTreeMatcher(pts, allowed, body.part_labels, 1)
    th = _TorchMatcher(pts, allowed, body.part_labels, chunk=128)
    for gated in (True, False):
        a, b = kd.scan_to_model(verts, gated), th.scan_to_model(verts, gated)
        da = (pts - verts[0, a[0]]).norm(dim=-1)
        db = (pts - verts[0, b[0]]).norm(dim=-1)
        torch.testing.assert_close(da, db, atol=1e-5, rtol=0)
        if gated:  # every match is a vertex of one of the point's allowed parts
            assert allowed[0, torch.arange(600), body.part_labels[a[0]]].all()
    sub = verts[:, :50]
    assert torch.equal(kd.model_to_scan(sub), th.model_to_scan(sub))
    # points matched to the model: a subset; the model matched to the whole scan
    half = pts[:, ::2]
    kd = _KDTreeMatcher(half, allowed[:, ::2], body.part_labels, 1, scan=pts)
    th = _TorchMatcher(half, allowed[:, ::2], body.part_labels, chunk=128, scan=pts)
    assert kd.scan_to_model(verts, False).shape == (1, 300)
    spread = verts[:, ::100]
    full = torch.cdist(spread[0], pts[0]).argmin(1)
    assert torch.equal(kd.model_to_scan(spread)[0], full) and torch.equal(th.model_to_scan(spread)[0], full)
    assert (full % 2).any()  # points outside the subset are matched: the whole scan is used
    rows = torch.zeros(1, spread.shape[1], dtype=torch.bool)
    rows[0, ::3] = True  # a partial scan's visible vertices: only those are matched, the same way
    for m in (kd, th):
        got = m.model_to_scan(spread, rows)[0]
        assert torch.equal(got[rows[0]], full[rows[0]])
    assert not kd.model_to_scan(spread, rows)[0][~rows[0]].any()  # not matched: index 0
    dist = torch.cdist(spread[0], pts[0]).amin(1).double()
    torch.testing.assert_close(kd.scan_distance(0, spread[0]), dist, atol=1e-5, rtol=0)
    torch.testing.assert_close(th.scan_distance(0, spread[0]).double(), dist, atol=1e-5, rtol=0)


def _quality(body, points, s, labels, seed=0):
    rng = np.random.default_rng(seed)
    c = points.mean(0)
    pts = torch.as_tensor(points - c, dtype=torch.float32)[None]
    probs = noisy_probs(labels, rng)
    out = refine(body, pts, probs[None], perturbed_start(s, c, rng, rot=0.1, betas=0.3, transl=0.02))
    sub = body_tables(body).m2s_subset.numpy()
    return fit_quality(points - c, out.vertices[0].double().numpy(), body.part_labels.numpy(), sub,
                       out.betas[0].numpy(), probs.numpy())  # fmt: skip


def test_single_body_check_passes_a_body_and_flags_two_bodies_and_a_sphere(body):
    """Even from the best start (one body's own ground truth), two bodies side by side and a sphere
    must be flagged; one body with 10 % outliers must pass."""
    s = synthetic_scan(body, "test_id", 0, 5000, offset=0.0, outliers=0.1)
    q = _quality(body, s["points"], s, s["labels"])
    assert q["flags"] == [], q
    s2 = synthetic_scan(body, "test_id", 7, 5000, offset=0.0)
    both = np.concatenate([s["points"][::2], s2["points"][::2] + s["rotation"] @ [0.9, 0, 0]])
    q2 = _quality(body, both, s, np.concatenate([s["labels"][::2], -np.ones(2500, int)]))
    assert "low_inliers" in q2["flags"] and q2["inlier_frac"] < 0.55, q2
    rng = np.random.default_rng(0)
    sph = rng.normal(size=(4000, 3))
    sph = 0.5 * sph / np.linalg.norm(sph, axis=1, keepdims=True) + s["vertices"].mean(0)
    q3 = _quality(body, sph, s, -np.ones(4000, int))
    assert {"low_inliers", "low_coverage"} <= set(q3["flags"]), q3


def test_refine_config_from_command_line_strings():
    """``--set KEY=VALUE``: each value read as its field's type; unknown keys and bad values are errors."""
    from arteq.fit.refine import RefineConfig

    cfg = RefineConfig.from_strings(["sigma_end=3", "iters=12", "backend=torch"], iters=7)
    assert (cfg.sigma_end, cfg.iters, cfg.backend) == (3.0, 12, "torch")
    assert RefineConfig.from_strings([], iters=7).iters == 7
    with pytest.raises(ValueError, match="KEY one of iters"):
        RefineConfig.from_strings(["sigma=3"])
    with pytest.raises(ValueError, match="not of type int"):
        RefineConfig.from_strings(["iters=1.5"])
    with pytest.raises(ValueError, match="subset must be random or fps"):
        RefineConfig.from_strings(["subset=even"])


def turned_truth(body, s, centre, turns):
    """The truth's start with each joint of ``turns`` ({joint: (kind, degrees)}) turned in the world frame:
    ``roll`` about its parent segment (parent joint -> joint, a hand about its forearm), ``swing`` about
    the normal to its own segment (joint -> child) and the z axis. Returns the start and its posed body."""
    pose = torch.as_tensor(s["pose"], dtype=torch.float32)[None].clone()
    betas = torch.as_tensor(s["betas"], dtype=torch.float32)[None]
    transl = torch.as_tensor(s["transl"] - centre, dtype=torch.float32)[None]
    with torch.no_grad():
        o = body(betas=betas, pose=pose, transl=transl)
    for j, (kind, deg) in turns.items():
        if kind == "roll":
            axis = o.joints[0, j] - o.joints[0, PARENTS[j]]
        else:
            seg = o.joints[0, PARENTS.index(j)] - o.joints[0, j]
            axis = torch.linalg.cross(seg, torch.tensor([0.0, 0.0, 1.0]))
        turn = roma.rotvec_to_rotmat(axis / axis.norm() * np.radians(deg))
        parent = o.global_rotmats[0, PARENTS[j]]
        pose[0, j] = parent.T @ turn @ parent @ pose[0, j]
    with torch.no_grad():
        o = body(betas=betas, pose=pose, transl=transl)
    return {"local_rotmats": pose, "betas": betas, "transl": transl}, o


def test_twist_search_turns_a_rolled_hand_back(body):
    """A right hand rolled 150 deg about the forearm comes back by the 210 deg turn (a grid angle of 12
    steps); the left hand, not rolled, and a joint whose branch is far from every point stay."""
    s = synthetic_scan(body, "test_id", 0, 5000, offset=0.0)
    pts = torch.as_tensor(s["points"], dtype=torch.float32)[None]
    lw, rw = JOINT_NAMES.index("left_wrist"), JOINT_NAMES.index("right_wrist")
    _, posed = turned_truth(body, s, 0.0, {rw: ("roll", 150.0)})
    matcher = _KDTreeMatcher(pts, allowed_parts(torch.ones(1, 5000, 22)), body.part_labels, 1)
    tables = body_tables(body)
    subsets = {j: tables.branch_subset(j) for j in (lw, rw)}
    turns = twist_search(posed.vertices, posed.joints, subsets, matcher.scan_distance)
    axis = posed.joints[0, rw] - posed.joints[0, PARENTS[rw]]
    want = roma.rotvec_to_rotmat(axis / axis.norm() * np.radians(210.0))
    torch.testing.assert_close(turns[0, rw], want, atol=1e-4, rtol=0)
    assert torch.equal(turns[0, lw], torch.eye(3))
    far = twist_search(posed.vertices + 5.0, posed.joints + 5.0, subsets, matcher.scan_distance)
    assert torch.equal(far, torch.eye(3).expand_as(far))


@pytest.mark.parametrize(
    "index, turns, parts, off, bound_off",
    [  # hands rolled about their forearms; a forearm swung away from its points
        (1, {"left_wrist": ("roll", 150.0), "right_wrist": ("roll", -120.0)}, ["left_wrist", "right_wrist"],
         {"twist_at": -1.0}, 4.0),
        (2, {"left_elbow": ("swing", 100.0)}, ["left_elbow", "left_wrist"], {"swing_at": -1.0}, 10.0),
    ],
)  # fmt: skip
def test_refinement_restarts_turned_joints(body, index, turns, parts, off, bound_off):
    """From the truth with joints turned away (20 % wrong labels), the refinement with its searches brings
    the turned parts back (V2V < 1.5 cm on them); with the search off they stay off (> ``bound_off`` cm):
    the searches, not the local matches, undo the turns."""
    rng = np.random.default_rng(index - 1)
    s = synthetic_scan(body, "test_id", index, 5000, offset=0.0)
    c = s["points"].mean(0)
    pts = torch.as_tensor(s["points"] - c, dtype=torch.float32)[None]
    init, _ = turned_truth(body, s, c, {JOINT_NAMES.index(j): t for j, t in turns.items()})
    probs = noisy_probs(s["labels"], rng)[None]
    sel = np.isin(body.part_labels.numpy(), [JOINT_NAMES.index(j) for j in parts])
    err = {}
    for name, cfg in (("search", RefineConfig()), ("none", RefineConfig(**off))):
        out = refine(body, pts, probs, init, cfg)
        err[name] = v2v_cm(out.vertices[0].numpy()[sel] + c, s["vertices"][sel])
    assert err["search"] < 1.5 and err["none"] > bound_off, err


def test_twist_joints_are_checked():
    assert turn_joint_ids("left_wrist, right_ankle") == [20, 8]
    assert turn_joint_ids("") == []
    with pytest.raises(ValueError, match="'left_hand' is not a non-root joint"):
        turn_joint_ids("left_hand")
    with pytest.raises(ValueError, match="'pelvis'"):
        turn_joint_ids("pelvis")
    with pytest.raises(ValueError, match="'left_wrist' ends a chain"):
        RefineConfig(swing_joints="left_elbow,left_wrist")


def test_swing_search_points_a_lost_forearm_back(body):
    """A left forearm swung 100 deg away from its points comes back to within 3 cm (the direction grid's
    spacing is about 16 deg); the right arm, where it should be, is not tried."""
    s = synthetic_scan(body, "test_id", 2, 5000, offset=0.0)
    le, re_ = JOINT_NAMES.index("left_elbow"), JOINT_NAMES.index("right_elbow")
    _, posed = turned_truth(body, s, 0.0, {le: ("swing", 100.0)})
    tables = body_tables(body)
    turns = swing_search(
        [s["points"]], posed.vertices.double().numpy(), posed.joints.double().numpy(),
        body.part_labels.numpy(), {j: tables.branch_subset(j).numpy() for j in (le, re_)},
        {j: tables.branch_fraction(j) for j in (le, re_)},
    )  # fmt: skip
    arm = np.isin(body.part_labels.numpy(), branch_parts(le))
    pivot = posed.joints[0, le].double().numpy()
    moved = (posed.vertices[0].double().numpy()[arm] - pivot) @ turns[0, le].T + pivot
    before = v2v_cm(posed.vertices[0].numpy()[arm], s["vertices"][arm])
    after = v2v_cm(moved, s["vertices"][arm])
    assert before > 15 and after < 3.0, (before, after)
    assert np.array_equal(turns[0, re_], np.eye(3))
    # two scans (the lost arm and the truth) on two threads: the same turns, the truth's untouched
    _, truth = turned_truth(body, s, 0.0, {})
    both = swing_search(
        [s["points"]] * 2, torch.cat([posed.vertices, truth.vertices]).double().numpy(),
        torch.cat([posed.joints, truth.joints]).double().numpy(), body.part_labels.numpy(),
        {j: tables.branch_subset(j).numpy() for j in (le, re_)},
        {j: tables.branch_fraction(j) for j in (le, re_)}, workers=2,
    )  # fmt: skip
    assert np.array_equal(both[0], turns[0]) and np.array_equal(both[1], np.tile(np.eye(3), (22, 1, 1)))


def test_sphere_directions_cover_the_sphere():
    d = sphere_directions(162)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
    probe = np.random.default_rng(0).normal(size=(2000, 3))
    probe /= np.linalg.norm(probe, axis=1, keepdims=True)
    worst = np.degrees(np.arccos(np.clip(probe @ d.T, -1, 1).max(1))).max()
    assert worst < 15.0, worst


def test_rotation_between_batched_agrees_with_one_by_one():
    """The swing search's batched call: each of many directions (one the same as ``aim``, one opposite)
    gets the rotation a one-by-one call gives, and it takes ``aim`` there."""
    from arteq.geometry.rotations import rotation_between

    rng = np.random.default_rng(0)
    aim = rng.normal(size=3)
    dirs = np.concatenate([rng.normal(size=(20, 3)), [aim * 2.0, -aim]])
    got = rotation_between(torch.as_tensor(aim), torch.as_tensor(dirs)).numpy()
    for d, r in zip(dirs, got):
        want = rotation_between(torch.as_tensor(aim), torch.as_tensor(d)).numpy()
        np.testing.assert_allclose(r, want, atol=1e-9)
        np.testing.assert_allclose(r @ (aim / np.linalg.norm(aim)), d / np.linalg.norm(d), atol=1e-9)


def test_fps_subsets_are_each_clouds_own_and_reused_for_a_cloud_met_before():
    from arteq.fit import refine as R
    from arteq.geometry.pointops import fps_from_centroid

    g = torch.Generator().manual_seed(0)
    a, b = torch.randn(2, 300, 3, generator=g).unbind(0)
    batch = torch.stack([a, b, a])  # a cloud twice in one batch (a second start)
    want = fps_from_centroid(batch.double(), 50).sort(dim=1).values
    calls = []
    real = R.fps_from_centroid
    R.fps_from_centroid = lambda x, m: calls.append(len(x)) or real(x, m)
    try:
        assert torch.equal(R.fps_subsets(batch, 50), want)
        assert torch.equal(R.fps_subsets(batch[1:], 50), want[1:])  # met before: not sampled again
        assert torch.equal(
            R.fps_subsets(batch[:1], 40), fps_from_centroid(a[None].double(), 40).sort(1).values
        )
    finally:
        R.fps_from_centroid = real
    assert calls == [2, 1]  # two distinct clouds, then none, then another count


def test_skin_subset_poses_the_same_vertices_as_the_body(body):
    from arteq.fit.refine import skin_subset, subset_rows

    g = torch.Generator().manual_seed(1)
    dtype = body.v_template.dtype
    betas = torch.randn(2, body.num_betas, generator=g).to(dtype)
    pose = roma.rotvec_to_rotmat(0.4 * torch.randn(2, 22, 3, generator=g)).to(dtype)
    transl = torch.randn(2, 3, generator=g).to(dtype)
    sel = torch.randperm(body.v_template.shape[0], generator=g)[:300].sort().values
    full = body(betas=betas, pose=pose, transl=transl).vertices[:, sel]
    tables = body_tables(body)
    kept = subset_rows(body, sel, body.num_betas)
    torch.testing.assert_close(skin_subset(body, tables, sel, betas, pose, transl), full, rtol=0, atol=1e-5)
    torch.testing.assert_close(
        skin_subset(body, tables, sel, betas, pose, transl, kept), full, rtol=0, atol=1e-5
    )
