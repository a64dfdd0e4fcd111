"""anny22 against Anny itself, and the cached model file's properties.

Needs `anny` (skipped without it). Builds the cached anny22 file on first use (about a minute, once).
"""

from __future__ import annotations

import numpy as np
import pytest
import roma
import torch

from arteq.body import load_body_model, skin
from arteq.body.skeleton import JOINT_NAMES

anny = pytest.importorskip("anny")

from arteq.body import anny22  # noqa: E402


@pytest.fixture(scope="module")
def built():
    path = anny22.ensure_anny22()
    model = anny22.load_anny()
    return path, model, anny22.read_bake(path)


def test_lbs_reproduces_anny(built):
    """Random poses of the 20 joints that are Anny bones (the folded bones and virtual feet at rest)."""
    path, model, bake = built
    body = load_body_model("anny22")
    g = torch.Generator().manual_seed(0)
    B = 3
    phen = {k: 0.15 + 0.7 * torch.rand(B, generator=g, dtype=torch.float64) for k in model.phenotype_labels}
    with torch.no_grad():
        v_rest, j_rest = anny22.anny_tpose(model, phen, bake)
        pose = roma.rotvec_to_rotmat(0.6 * torch.randn(B, 22, 3, generator=g, dtype=torch.float64))
        pose[:, [JOINT_NAMES.index("left_foot"), JOINT_NAMES.index("right_foot")]] = torch.eye(3).double()
        out = model(pose_parameters=anny22.anny_deltas_from_pose(model, bake, pose), phenotype_kwargs=phen)
        C = torch.as_tensor(anny22.ANNY_TO_SMPL)
        theirs = out["vertices"] @ C.T
        ours, joints, _ = skin(v_rest, j_rest, pose, body.lbs_weights.double())
    err = (ours - theirs).norm(dim=-1) * 1000.0
    # Vertices skinned to bones that the T-pose bake moved by different amounts (the shoulder blend region)
    # cannot match exactly: LBS of a baked LBS is not LBS. Everywhere else the match is exact.
    from anny.skinning.skinning import dense_bone_weights

    dense = dense_bone_weights(model.vertex_bone_weights, model.vertex_bone_indices, len(model.bone_labels))
    bake_g = anny22.baked_globals(model, bake).reshape(len(model.bone_labels), 9)
    spread = torch.stack(
        [(bake_g[dense[v] > 0] - bake_g[dense[v] > 0][0]).abs().max() for v in range(len(dense))]
    )
    blend = spread > 1e-9
    print(
        f"anny22 LBS vs Anny: mean {err.mean():.3f} mm, max {err.max():.2f} mm; outside the shoulder bake "
        f"blend region ({(~blend).float().mean() * 100:.1f}% of vertices) max {err[:, ~blend].max():.1e} mm"
    )
    assert (theirs - v_rest).norm(dim=-1).mean() > 0.05  # the poses really move the body
    assert err.mean() < 1.0
    assert err[:, ~blend].max() < 1e-3
    assert err.max() < 50.0


def test_template_is_upright_t_pose_facing_z(built):
    body = load_body_model("anny22")
    J = body().joints[0]
    j = {n: J[i] for i, n in enumerate(JOINT_NAMES)}
    assert j["pelvis"].abs().max() < 0.01  # pelvis at the origin
    assert j["head"][1] > j["neck"][1] > j["pelvis"][1] > j["left_knee"][1] > j["left_ankle"][1]
    for side, sign in (("left", 1.0), ("right", -1.0)):
        arm = j[f"{side}_wrist"] - j[f"{side}_shoulder"]
        assert sign * arm[0] > 0.4 and arm[1].abs() < 0.03 and arm[2].abs() < 0.03  # horizontal along x
        assert sign * j[f"{side}_hip"][0] > 0.05  # +x is the body's left
        assert j[f"{side}_foot"][2] > j[f"{side}_ankle"][2] + 0.05  # toes point forward (+z)
    height = body.v_template[:, 1].max() - body.v_template[:, 1].min()
    assert 1.4 < height < 2.0  # metres


def test_file_contents_and_shape_space(built):
    path, _, _ = built
    body = load_body_model("anny22", num_betas=16)
    assert body.num_vertices == 13718 and body.faces.shape == (27420, 3) and body.num_betas == 16
    torch.testing.assert_close(body.lbs_weights.sum(1), torch.ones(13718), atol=1e-5, rtol=0)
    assert body.posedirs.shape[0] == 0
    assert torch.all(body.J_regressor >= 0)
    torch.testing.assert_close(body.J_regressor.sum(1), torch.ones(22), atol=1e-5, rtol=0)
    assert set(body.part_labels.unique().tolist()) == set(range(22))
    meta = anny22.read_meta(path)
    assert meta["morphological_age_range_years"] == [18.0, 70.0]
    assert meta["variance_explained_cumulative"][9] > 0.99
    assert meta["joint_regressor_heldout_error_mm"]["mean"] < 10.0
    # unit variance: a beta of 1 on component k moves vertices by sqrt(lambda_k) along a unit direction
    sd = body.shapedirs.double().reshape(-1, 16)
    norms = sd.norm(dim=0)
    assert torch.all(norms[:-1] >= norms[1:] - 1e-6)
    gram = (sd / norms).T @ (sd / norms)
    torch.testing.assert_close(gram, torch.eye(16, dtype=torch.float64), atol=1e-4, rtol=0)
    with np.load(path, allow_pickle=False) as z:
        assert {"v_template", "shapedirs", "posedirs", "J_regressor", "weights", "kintree_table", "f"} <= set(
            z
        )


def test_anny_shape_is_spanned_by_betas(built):
    """A shape sampled from Anny's (adult) distribution is reproduced by projecting on the 16 betas."""
    _, model, bake = built
    from anny.shape_distribution import SimpleShapeDistribution

    body = load_body_model("anny22", num_betas=16).double()
    torch.manual_seed(123)
    age = torch.distributions.Uniform(torch.tensor(18.0).double(), torch.tensor(70.0).double())
    _, phen = SimpleShapeDistribution(model, morphological_age_distribution=age).sample(4)
    with torch.no_grad():
        v, j = anny22.anny_tpose(model, phen, bake)
    v = v - j[:, :1]
    sd = body.shapedirs.reshape(-1, 16)
    betas = torch.linalg.lstsq(sd, (v - body.v_template).reshape(4, -1).T).solution.T
    recon = body(betas=betas).vertices
    err = (recon - v).norm(dim=-1) * 1000.0
    print(f"shape reconstruction with 16 betas: mean {err.mean():.2f} mm, max {err.max():.2f} mm")
    assert err.mean() < 5.0
    assert betas.abs().max() < 6.0  # unit-variance betas: realistic shapes are within a few sigma
