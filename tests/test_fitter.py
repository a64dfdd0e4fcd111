"""Optimisation fitter: recovers a known pose and shape; objective; candidates; bad input."""

import pytest
import roma
import torch

from arteq.geometry.pointops import farthest_point_sample
from arteq.geometry.rotations import geodesic_deg
from arteq.optim_fit import chamfer_terms, fit_body, root_candidates


@pytest.fixture(scope="module")
def body():
    from arteq.body import load_body_model

    return load_body_model("anny22")


def test_recovers_pose_and_shape_from_15_degree_perturbation(body):
    """Clean cloud = an even vertex subset of the true mesh; start = truth with every joint rotated
    by 15 degrees and betas off by 0.3 sigma. Tolerances: rotation error < 5 deg per part on
    average (< 10 deg worst part), V2V < 1 cm."""
    torch.manual_seed(0)
    aa_gt = torch.randn(1, 22, 3) * 0.25
    betas_gt = torch.randn(1, 10) * 0.5
    gt = body(betas=betas_gt, pose=aa_gt, transl=torch.tensor([[0.05, -0.1, 0.02]]))
    sub = farthest_point_sample(body.v_template[None], 1500)[0]
    pts = gt.vertices[:, sub]
    axis = torch.nn.functional.normalize(torch.randn(1, 22, 3), dim=-1)
    pert = roma.rotvec_to_rotmat(axis * torch.deg2rad(torch.tensor(15.0)))
    init = {"pose": roma.rotvec_to_rotmat(aa_gt) @ pert, "betas": betas_gt + 0.3 * torch.randn(1, 10)}
    start = body(betas=init["betas"], pose=init["pose"])
    start_err = geodesic_deg(start.global_rotmats, gt.global_rotmats).mean()
    res = fit_body(
        body, pts, init=init, iters=8, optimizer="lbfgs", lr=1.0, w_pose=0.0, w_betas=0.0, mesh_subset=sub
    )
    err = geodesic_deg(res.global_rotmats, gt.global_rotmats)[0]
    v2v = (res.vertices - gt.vertices).norm(dim=-1).mean() * 100
    assert start_err > 15.0
    assert err.mean() < 5.0, err
    assert err.max() < 10.0, err
    assert v2v < 1.0
    assert res.iterations == len(res.history) <= 8
    assert res.history[-1]["loss"] < res.history[0]["loss"]
    assert res["pose"].shape == (1, 22, 3, 3) and res.seconds > 0


def test_standard_start_with_root_candidates_finds_orientation(body):
    """From the rest pose, the best of the cube's 24 root orientations must put the body's up axis
    where the truth's is (the truth is lying down: 90 degrees about x, plus 6 degrees). Front/back is
    nearly symmetric for a rest-pose cloud, so only the up axis is asserted."""
    rot = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])  # 90 deg about x
    pose = torch.eye(3).repeat(1, 22, 1, 1)
    pose[0, 0] = rot @ roma.rotvec_to_rotmat(torch.tensor([0.0, 0.0, 0.1]))
    gt = body(pose=pose)
    pts = gt.vertices[:, farthest_point_sample(gt.vertices, 800)[0]]

    def up_error(res):
        up, up_gt = res.global_rotmats[0, 0, :, 1], gt.global_rotmats[0, 0, :, 1]
        return torch.rad2deg(torch.acos(torch.dot(up, up_gt).clamp(-1, 1)))

    assert up_error(fit_body(body, pts, iters=0, num_roots=24)) < 10.0
    assert up_error(fit_body(body, pts, iters=0, num_roots=1)) > 80.0


def test_root_candidates_are_the_24_cube_rotations():
    c = root_candidates(24, dtype=torch.float64)
    assert c.shape == (24, 3, 3)
    assert torch.allclose(c[0], torch.eye(3, dtype=torch.float64))
    assert torch.allclose(torch.linalg.det(c), torch.ones(24, dtype=torch.float64))
    assert len({tuple(m.flatten().tolist()) for m in c}) == 24
    with pytest.raises(ValueError, match="1 or 24"):
        root_candidates(5)


def test_chamfer_terms_zero_on_identity_and_cm_units():
    v = torch.rand(1, 50, 3)
    p2m, m2p = chamfer_terms(v.clone(), v)
    assert p2m.item() == pytest.approx(0.0, abs=1e-8) and m2p.item() == pytest.approx(0.0, abs=1e-8)
    p2m, m2p = chamfer_terms(v + torch.tensor([0.0, 0.0, 0.01]), v, torch.arange(10))
    assert p2m.item() == pytest.approx(1.0, rel=1e-3)  # 1 cm shift -> 1 cm^2 (every nn is the shifted copy)


def test_bad_input(body):
    with pytest.raises(ValueError, match=r"\[B, N, 3\]"):
        fit_body(body, torch.zeros(100, 3))
    with pytest.raises(ValueError, match="empty"):
        fit_body(body, torch.zeros(1, 0, 3))
    with pytest.raises(ValueError, match="NaN"):
        fit_body(body, torch.full((1, 10, 3), float("nan")))
    with pytest.raises(ValueError, match="metres"):
        fit_body(body, torch.rand(1, 100, 3) * 1000)
    with pytest.raises(ValueError, match="optimizer"):
        fit_body(body, torch.rand(1, 100, 3), optimizer="sgd")
    with pytest.raises(ValueError, match=r"init\['pose'\]"):
        fit_body(body, torch.rand(1, 100, 3), init={"pose": torch.zeros(1, 21, 3)})


def test_refinement_and_optimisation_return_one_result_type(body):
    """``fit_body`` and ``refine`` return the same :class:`arteq.results.BodyFitResult`, under their old
    names too; ``pose`` / ``["pose"]`` read the local rotations, ``pose_aa`` is their axis-angle where the
    fitter optimises it (``fit_body``) and None after refinement; the refined body is the body model's
    output at the returned parameters."""
    from arteq.fit.refine import RefineConfig, RefineOutput, refine
    from arteq.optim_fit import OptimFitResult
    from arteq.results import BodyFitResult

    assert OptimFitResult is BodyFitResult and RefineOutput is BodyFitResult
    torch.manual_seed(0)
    sub = farthest_point_sample(body.v_template[None], 300)[0]
    pts = body(pose=torch.randn(1, 22, 3) * 0.2).vertices[:, sub]
    opt = fit_body(body, pts, iters=2)
    assert type(opt) is BodyFitResult
    assert opt.pose is opt.local_rotmats and opt["pose"] is opt.local_rotmats
    assert torch.allclose(roma.rotvec_to_rotmat(opt.pose_aa), opt.local_rotmats, atol=1e-6)
    probs = torch.nn.functional.one_hot(body.part_labels[torch.cdist(pts[0], body.v_template).argmin(1)], 22)
    init = {"local_rotmats": opt.local_rotmats, "betas": opt.betas, "transl": opt.transl}
    ref = refine(body, pts, probs[None].float(), init, RefineConfig(iters=2))
    assert type(ref) is BodyFitResult and ref.pose_aa is None and ref.iterations == len(ref.history) == 2
    again = body(betas=ref["betas"], pose=ref.pose, transl=ref.transl)
    assert torch.allclose(again.vertices, ref.vertices) and torch.allclose(again.joints, ref.joints)
