"""Surface sampling: on-surface points, noise level, non-uniform density, labels, bad input."""

import pytest
import torch
from scipy.spatial import cKDTree

from arteq.body.toy import ToyBody
from arteq.geometry.sampling import (
    face_areas,
    interpolate_labels,
    sample_surface,
    smooth_density_field,
)


@pytest.fixture(scope="module")
def body():
    return ToyBody()


def _gen(s=0):
    return torch.Generator().manual_seed(s)


def _square():
    v = torch.tensor([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    f = torch.tensor([[0, 1, 2], [0, 2, 3]])
    return v, f


def test_points_on_surface_and_deterministic():
    v, f = _square()
    p, fi, b = sample_surface(v, f, 2000, _gen(1))
    p2, fi2, b2 = sample_surface(v, f, 2000, _gen(1))
    assert torch.equal(p, p2) and torch.equal(fi, fi2) and torch.equal(b, b2)
    assert p.shape == (2000, 3) and fi.shape == (2000,) and b.shape == (2000, 3)
    assert torch.allclose(b.sum(-1), torch.ones(2000)) and (b >= 0).all()
    assert p[:, 2].abs().max() < 1e-7  # on the plane
    # face 0 is the triangle below the diagonal x >= y
    assert ((p[fi == 0, 0] - p[fi == 0, 1]) >= -1e-6).all()
    # uniform: both triangles (equal area) get ~half the points, x and y are spread uniformly
    assert abs((fi == 0).float().mean() - 0.5) < 0.05
    assert abs(p[:, 0].mean() - 0.5) < 0.03


def test_noise_std_measured():
    v, f = _square()
    p, _, _ = sample_surface(v, f, 20000, _gen(2), noise_std=0.001)
    assert p[:, 2].std().item() == pytest.approx(0.001, rel=0.05)


def test_density_weights_face_choice():
    v, f = _square()
    p, fi, _ = sample_surface(v, f, 4000, _gen(3), density=torch.tensor([3.0, 1.0]))
    assert (fi == 0).float().mean().item() == pytest.approx(0.75, abs=0.03)
    _, fi, _ = sample_surface(v, f, 500, _gen(3), density=torch.tensor([0.0, 1.0]))
    assert (fi == 1).all()


def test_smooth_density_field_is_smooth_and_non_uniform(body):
    verts = body.v_template
    d = smooth_density_field(verts, _gen(4), contrast=1.0, wavelength=0.6)
    assert d.shape == (verts.shape[0],) and (d > 0).all()
    assert d.mean().item() == pytest.approx(1.0, rel=1e-5)
    assert d.max() / d.min() > 3  # clearly non-uniform over a body
    # smooth: the log-density changes by < 0.3 between points 1 cm apart (up to the normalisation)
    shifted = smooth_density_field(verts + torch.tensor([0.01, 0, 0]), _gen(4), contrast=1.0, wavelength=0.6)
    dlog = shifted.log() - d.log()
    dlog = dlog - dlog.mean()
    assert dlog.abs().max() < 0.3 and dlog.abs().mean() < 0.06
    other = smooth_density_field(verts, _gen(5))
    assert not torch.allclose(d, other)  # a fresh field per generator
    assert torch.allclose(smooth_density_field(verts, _gen(5), contrast=0.0), torch.ones(len(verts)))


def test_non_uniform_sampling_follows_density(body):
    v, f = body.v_template, body.faces
    cen = v[f].mean(1)
    dens = smooth_density_field(cen, _gen(6))
    _, fi, _ = sample_surface(v, f, 20000, _gen(7), density=dens)
    hi = dens > dens.median()
    area = face_areas(v, f)
    expected = (area * dens)[hi].sum() / (area * dens).sum()
    uniform = area[hi].sum() / area.sum()
    got = hi[fi].float().mean()
    assert got.item() == pytest.approx(expected.item(), abs=0.02)
    assert got - uniform > 0.1  # denser regions get clearly more points than area alone gives


def test_labels_agree_with_nearest_vertex_of_face(body):
    """Toy body (coarse, overlapping primitives): compare with the nearest corner of the point's own face."""
    v, f = body.v_template, body.faces
    p, fi, b = sample_surface(v, f, 5000, _gen(8), noise_std=0.001)
    labels = interpolate_labels(body.lbs_weights, f, fi, b)
    corner = f[fi, b.argmax(-1)]
    agree = (labels == body.part_labels[corner]).float().mean().item()
    assert agree > 0.95, agree
    assert labels.dtype == torch.long and labels.min() >= 0 and labels.max() < 22


def test_labels_agree_with_nearest_vertex_anny22():
    """Real body: label vs the part of the globally nearest vertex (rate printed; asserted > 95%)."""
    from arteq.paths import cache_dir

    if not any(cache_dir("body_models").glob("anny22*")):
        pytest.skip("anny22 not built yet (python -m arteq.body.anny22)")
    from arteq.body import load_body_model

    body = load_body_model("anny22")
    out = body(betas=None, pose=torch.eye(3).expand(1, 22, 3, 3))
    v, f = out.vertices[0], body.faces
    p, fi, b = sample_surface(v, f, 5000, _gen(9), noise_std=0.001)
    labels = interpolate_labels(body.lbs_weights, f, fi, b)
    _, nn = cKDTree(v.numpy()).query(p.numpy())
    agree = (labels == body.part_labels[torch.from_numpy(nn)]).float().mean().item()
    print(f"anny22 label agreement with nearest vertex: {agree:.4f}")
    assert agree > 0.95, agree
    assert labels.dtype == torch.long and labels.min() >= 0 and labels.max() < 22


def test_bad_input_errors():
    v, f = _square()
    with pytest.raises(ValueError, match="vertices"):
        sample_surface(v[:, :2], f, 10, _gen())
    with pytest.raises(ValueError, match="empty"):
        sample_surface(v, f[:0], 10, _gen())
    with pytest.raises(ValueError, match="NaN"):
        sample_surface(torch.full_like(v, float("nan")), f, 10, _gen())
    with pytest.raises(ValueError, match="out of range"):
        sample_surface(v, f + 10, 10, _gen())
    with pytest.raises(ValueError, match="density"):
        sample_surface(v, f, 10, _gen(), density=torch.ones(3))
    with pytest.raises(ValueError, match="noise_std"):
        sample_surface(v, f, 10, _gen(), noise_std=-1.0)
    with pytest.raises(ValueError, match="n must be"):
        sample_surface(v, f, 0, _gen())
