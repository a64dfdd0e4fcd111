"""The network's prediction averaged over several random subsets of a scan (``Fitter(net_draws=K)``):
the chordal mean of the global rotations, the mean shape and translation; the first draw and the
refinement's points stay those of one draw."""

from __future__ import annotations

import numpy as np
import pytest
import roma
import torch

from arteq.body.skeleton import JOINT_NAMES, local_to_global
from arteq.fit.api import Fitter, mean_prediction
from fit_helpers import write_tiny_checkpoint


@pytest.fixture(scope="module")
def tiny_ckpt(tmp_path_factory, tiny_net):
    return write_tiny_checkpoint(tmp_path_factory.mktemp("ckpt") / "tiny.ckpt", tiny_net)


@pytest.fixture(scope="module")
def scan(anny22):
    from arteq.fit.demo import synthetic_scan

    return synthetic_scan(anny22, "test_id", 0, 3000, offset=1.0)["points"]


def _rot(axis, deg):
    return roma.rotvec_to_rotmat(torch.tensor(axis, dtype=torch.float64) * np.deg2rad(deg))


def test_mean_prediction_is_the_chordal_mean_of_global_rotations():
    """Two draws of two scans. Scan 0: the elbow turned +30 / -30 deg about z under a shoulder turned 40 deg
    in both: the mean keeps the shoulder and puts the elbow at rest (local and global). Scan 1: both draws
    equal: the mean is that draw. Betas and translation: the plain mean."""
    torch.manual_seed(0)
    local = torch.eye(3, dtype=torch.float64).repeat(4, 22, 1, 1)
    sh, el = JOINT_NAMES.index("left_shoulder"), JOINT_NAMES.index("left_elbow")
    local[0:2, sh] = _rot([1.0, 0.0, 0.0], 40)
    local[0, el], local[1, el] = _rot([0.0, 0.0, 1.0], 30), _rot([0.0, 0.0, 1.0], -30)
    same = roma.random_rotmat(22, dtype=torch.float64)
    local[2], local[3] = same, same
    pred = {"local_rotmats": local, "betas": torch.randn(4, 10), "transl": torch.randn(4, 3)}
    out = mean_prediction(pred, 2)
    assert out["local_rotmats"].shape == (2, 22, 3, 3)
    assert torch.allclose(out["local_rotmats"][0, sh], _rot([1.0, 0.0, 0.0], 40), atol=1e-10)
    assert torch.allclose(out["local_rotmats"][0, el], torch.eye(3, dtype=torch.float64), atol=1e-10)
    others = [j for j in range(22) if j not in (sh, el)]
    assert torch.allclose(out["local_rotmats"][0, others], torch.eye(3, dtype=torch.float64), atol=1e-10)
    assert torch.allclose(out["local_rotmats"][1], same, atol=1e-10)
    assert torch.allclose(local_to_global(out["local_rotmats"][1]), local_to_global(same), atol=1e-10)
    assert torch.allclose(out["betas"], pred["betas"].reshape(2, 2, 10).mean(1))
    assert torch.allclose(out["transl"], pred["transl"].reshape(2, 2, 3).mean(1))


class _Recording(Fitter):
    """A Fitter that keeps the clouds its network read and the scan's centre."""

    def prepare(self, points, units="m", name="points", viewpoint=None):
        item = super().prepare(points, units, name, viewpoint)
        self.centre = item["center"]
        return item

    def _network(self, clouds, turns=None, shifts=None, torso=None):
        self.clouds = [c.copy() for c in clouds]
        return super()._network(clouds, turns)


def test_net_draws_fit_is_the_mean_of_the_draws(tiny_ckpt, scan):
    """``net_draws=3``: the network reads 3 different subsets, the first the one ``net_draws=1`` reads;
    the body written is the one posed from :func:`mean_prediction` of the three predictions; the points
    the fit is measured on are the same as with one draw."""
    kw = dict(ckpt=tiny_ckpt, device="cpu", refine=False, check=False, anny=False, clean=False)
    one, three = _Recording(net_draws=1, **kw), _Recording(net_draws=3, **kw)
    r1, r3 = one.fit_points(scan), three.fit_points(scan)
    assert len(one.clouds) == 1 and len(three.clouds) == 3
    assert np.array_equal(three.clouds[0], one.clouds[0])
    assert not np.array_equal(three.clouds[1], three.clouds[0])
    assert np.array_equal(r1.scan_points, r3.scan_points)
    with torch.no_grad():
        pred = Fitter._network(three, three.clouds)
        mean = mean_prediction(pred, 3)
        dt = three.body.v_template.dtype
        verts = three.body(betas=mean["betas"].to(dt), pose=mean["local_rotmats"].to(dt),
                           transl=mean["transl"].to(dt)).vertices[0].double().numpy()  # fmt: skip
    np.testing.assert_allclose(r3.vertices, verts + three.centre, atol=1e-5)
    assert np.abs(r3.vertices - r1.vertices).max() > 1e-4  # the average is not the first draw's


def test_net_draws_must_be_positive(tiny_ckpt):
    with pytest.raises(ValueError, match="net_draws must be >= 1"):
        Fitter(ckpt=tiny_ckpt, device="cpu", net_draws=0)
