"""Fitting single-view scans (arteq.fit.partial and the fitter's scan modes): one-sidedness, visibility,
which mode a scan is fitted in and why, which parts were seen."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from arteq.data.dataset import BodyScanDataset
from arteq.data.poses import SyntheticIDPoses
from arteq.data.single_view import SingleViewDataset
from arteq.fit.partial import PARTIAL_SCORE, one_sidedness, visible_vertices


def test_one_sidedness_tells_a_single_view_from_a_full_surface(anny22):
    kw = {"num_points": 4000, "augment": "so3", "seed": 7}
    full = BodyScanDataset(SyntheticIDPoses(), anny22, "test_view", 3, **kw)
    for i in range(3):
        score, _ = one_sidedness(full[i]["points"].double().numpy())
        assert score < PARTIAL_SCORE - 0.03, score
    for view in ("front", "top"):
        ds = SingleViewDataset(SyntheticIDPoses(), anny22, "test_view", 2, view=view, **kw)
        for i in range(2):
            score, direction = one_sidedness(ds[i]["points"].double().numpy())
            assert score > PARTIAL_SCORE + 0.03, (view, score)
            assert abs(np.linalg.norm(direction) - 1) < 1e-9


def test_the_estimated_camera_direction_and_the_visible_vertices(anny22):
    from arteq.data.dataset import seeded_generator
    from arteq.data.single_view import single_view_scan
    from arteq.geometry.normals import vertex_normals

    out = anny22(betas=torch.zeros(1, 10), pose=torch.eye(3).expand(1, 22, 3, 3))
    v = out.vertices[0].double()
    for view in ("top", "side", "back", "front"):  # the last, a front view, is used below
        for seed in range(3):  # the camera's side, not its opposite: the sign from the surface's bulge
            scan = single_view_scan(v, anny22.faces, anny22.lbs_weights, out.joints[0, 0], torch.eye(3), 4000,
                                    seeded_generator(seed, view), view=view)  # fmt: skip
            _, direction = one_sidedness(scan["points"].numpy())
            to_cam = (scan["camera"] - out.joints[0, 0]).double().numpy()
            cos = direction @ to_cam / np.linalg.norm(to_cam)
            assert cos > 0.75, (view, seed, cos)  # the best of 100 directions (about 20 degrees apart)
    normals = vertex_normals(v[None], anny22.faces)[0].numpy()
    vis = visible_vertices(v.numpy(), normals, camera=scan["camera"].numpy())
    vis_far = visible_vertices(v.numpy(), normals, direction=to_cam)
    assert 0.25 < vis.mean() < 0.6 and 0.25 < vis_far.mean() < 0.6
    assert (vis & vis_far).sum() > 0.8 * vis.sum()
    from scipy.spatial import cKDTree

    d, _ = cKDTree(scan["points"].numpy()).query(v.numpy())
    assert np.median(d[vis]) < 0.02 < np.median(d[~vis])  # what it calls visible is what the camera saw
    with pytest.raises(ValueError, match="exactly one"):
        visible_vertices(v.numpy(), normals)
    # the refinement's form: a batch of posed bodies, its normals computed or given (the re-match's own)
    from arteq.fit.partial import visibility_function

    visible = visibility_function(anny22.faces, [(scan["camera"].numpy(), None), None])
    both = torch.stack([v, v + 0.1])
    got = visible(both)
    assert np.array_equal(got[0].numpy(), vis) and bool(got[1].all())  # a full scan's row: every vertex
    assert torch.equal(visible(both, vertex_normals(both, anny22.faces)), got)


def test_the_camera_direction_refined_from_the_normals(anny22):
    """facing_direction: the direction every seen point faces, nearer the simulator's camera than the first
    estimate on side and top views of everyday poses (where the first estimate is worst; 8 scans: 17 -> 10
    degrees on average); too few points give the start back."""
    import roma

    from arteq.data.dataset import seeded_generator
    from arteq.data.single_view import single_view_scan
    from arteq.fit.partial import facing_direction

    def angle(a, b):
        return np.degrees(np.arccos(np.clip(a @ b / np.linalg.norm(a) / np.linalg.norm(b), -1, 1)))

    poses = SyntheticIDPoses()
    first, refined = [], []
    for i in range(8):
        pose = roma.rotvec_to_rotmat(poses.sample(i, seeded_generator(3, "pose", i))["pose"].float())
        out = anny22(betas=torch.zeros(1, 10), pose=pose[None])
        view = ("side", "top")[i % 2]
        v, root = out.vertices[0].double(), out.global_rotmats[0, 0]
        scan = single_view_scan(v, anny22.faces, anny22.lbs_weights, out.joints[0, 0], root, 4000,
                                seeded_generator(i, view), view=view)  # fmt: skip
        pts = scan["points"].numpy()
        to_cam = scan["camera"].double().numpy() - pts.mean(0)
        _, d0 = one_sidedness(pts)
        d1 = facing_direction(pts, d0)
        assert abs(np.linalg.norm(d1) - 1) < 1e-9
        first.append(angle(d0, to_cam))
        refined.append(angle(d1, to_cam))
    assert np.mean(refined) < np.mean(first) - 3, (first, refined)
    assert max(refined) < 25, refined
    d = np.array([0.0, 1.0, 0.0])
    assert np.array_equal(facing_direction(np.zeros((5, 3)), d), d)


@pytest.fixture(scope="module")
def tiny_fitter(tmp_path_factory):
    from omegaconf import OmegaConf

    from arteq.fit.api import Fitter
    from conftest import compose_config
    from fit_helpers import write_tiny_checkpoint
    from test_single_view_parts import TINY

    net = OmegaConf.to_container(compose_config(["model=arteq", *TINY]).model.net, resolve=True)
    ckpt = write_tiny_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny.ckpt", net)
    return lambda **kw: Fitter(ckpt=ckpt, device="cpu", check=False, anny=False, points=1000,
                               refine=False, **kw)  # fmt: skip


def _full_and_side(body) -> tuple[np.ndarray, np.ndarray]:
    """One body's full-surface cloud and its side view (3000 points each, any orientation)."""
    kw = {"num_points": 3000, "augment": "so3", "seed": 1}
    full = BodyScanDataset(SyntheticIDPoses(), body, "test_view", 1, **kw)[0]["points"].numpy()
    side = SingleViewDataset(SyntheticIDPoses(), body, "test_view", 1, view="side", **kw)[0]["points"].numpy()
    return full, side


def test_the_fit_says_which_mode_it_used_and_which_parts_it_saw(anny22, tiny_fitter):
    full, side = _full_and_side(anny22)
    auto = tiny_fitter()
    r_full, r_side = auto.fit_points(full), auto.fit_points(side)
    assert r_full.scan_mode == "full" and r_full.scan_mode_reason.startswith("full (detected: one-sidedness")
    assert r_side.scan_mode == "partial" and r_side.scan_mode_reason.startswith("partial (detected")
    assert r_side.view_dir is not None and r_full.view_dir is None
    for r in (r_full, r_side):
        assert r.part_points.sum() == 1000 and r.parts_seen.dtype == bool
        assert (
            r.parts_seen.sum() == len(r.seen_names()) and len(r.seen_names(False)) == 22 - r.parts_seen.sum()
        )
        assert r.summary_row()["parts_seen"] == int(r.parts_seen.sum())
        assert r.arrays()["scan_mode"] == r.scan_mode
    assert tiny_fitter(partial=False).fit_points(side).scan_mode_reason == "full (--no-partial)"
    forced = tiny_fitter(partial=True).fit_points(full)
    assert forced.scan_mode == "partial" and "--partial" in forced.scan_mode_reason
    given = tiny_fitter(view_dir=[0, 0, 2]).fit_points(side)
    assert given.scan_mode_reason == "partial (--view-dir)"
    np.testing.assert_allclose(given.view_dir, [0, 0, 1])
    with pytest.raises(ValueError, match="view_dir"):
        tiny_fitter(view_dir=[0, 0, 0])
    with pytest.raises(ValueError, match="partial=False"):
        tiny_fitter(view_dir=[0, 0, 1], partial=False)


def test_a_partial_scans_network_reads_the_torso_middle_behind_its_points(anny22, tiny_fitter):
    # The network's left / right split gets each partial scan's torso shift (away from its camera,
    # TORSO_DEPTH_M), every draw of it; a full scan none.
    from arteq.fit.partial import TORSO_DEPTH_M, torso_shift

    full, side = _full_and_side(anny22)
    fitter = tiny_fitter(view_dir=[0, 0, 2])
    seen = []
    forward = fitter.module.forward

    def recording(points, turn=None, torso_shift=None, turn_torso=None):
        seen.append(None if torso_shift is None else torso_shift.clone())
        return forward(points, turn, torso_shift, turn_torso)

    fitter.module.forward = recording
    fitter.fit_points(side)
    assert seen[0].shape == (fitter.net_draws, 3)
    torch.testing.assert_close(
        seen[0], torch.tensor([[0.0, 0.0, -TORSO_DEPTH_M]]).expand(fitter.net_draws, 3)
    )
    seen.clear()
    plain = tiny_fitter(partial=False)  # full scans: no shift
    forward = plain.module.forward
    plain.module.forward = recording
    plain.fit_points(full)
    assert seen == [None]
    np.testing.assert_allclose(
        torso_shift(np.array([3.0, 0, 4])), [-0.6 * TORSO_DEPTH_M, 0, -0.8 * TORSO_DEPTH_M]
    )
    with pytest.raises(ValueError, match="view_dir"):
        torso_shift(np.zeros(3))


def test_partial_refinement_leaves_the_unseen_side_alone(anny22):
    """From a perturbed ground truth on a side view, the model -> scan term on the camera's vertices only
    fits better than on every vertex (which pulls the hidden side onto the visible points); with every
    vertex visible it is the full-scan objective."""
    import roma

    from arteq.fit.partial import visibility_function
    from arteq.fit.refine import RefineConfig, refine, visible_trimmed_mean

    d = SingleViewDataset(SyntheticIDPoses(), anny22, "test_view", 2, view="back", num_points=3000, seed=4)
    items = [d[i] for i in range(2)]
    b = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    g = torch.Generator().manual_seed(0)
    axis = torch.nn.functional.normalize(torch.randn(2, 22, 3, generator=g), dim=-1)
    init = {"local_rotmats": b["pose"] @ roma.rotvec_to_rotmat(0.15 * axis), "betas": b["betas"] + 0.5,
            "transl": b["transl"] + 0.03}  # fmt: skip
    probs = torch.nn.functional.one_hot(b["labels"], 22).float() * 0.7 + 0.3 / 22
    views = [(None, one_sidedness(p.double().numpy())[1]) for p in b["points"]]
    cfg = RefineConfig(iters=30)
    gt = anny22(betas=b["betas"], pose=b["pose"], transl=b["transl"]).vertices
    err = {}
    for arm, visible in (("full", None), ("partial", visibility_function(anny22.faces, views))):
        out = refine(anny22, b["points"], probs, init, cfg, m2s_visible=visible)
        err[arm] = float((out.vertices - gt).norm(dim=-1).mean() * 100)
    assert err["partial"] < err["full"] - 0.3, err
    everything = refine(anny22, b["points"], probs, init, RefineConfig(iters=3),
                        m2s_visible=lambda v, n: torch.ones(v.shape[:2], dtype=torch.bool))  # fmt: skip
    default = refine(anny22, b["points"], probs, init, RefineConfig(iters=3))
    torch.testing.assert_close(everything.vertices, default.vertices, rtol=0, atol=1e-5)
    d2 = torch.tensor([[1.0, 4.0, 9.0, 16.0], [1.0, 2.0, 3.0, 4.0]])
    vis = torch.tensor([[True, True, False, True], [False, False, False, False]])
    torch.testing.assert_close(visible_trimmed_mean(d2, d2, vis, 0.34), torch.tensor([2.5, 0.0]))
