"""The all-ages body (anny_allages) and the shared Anny build machinery (arteq.body.anny_rig).

Fast tests build a small all-ages file (256 samples, a few seconds with a warm anny cache); the cached
full build (2000 samples, about 35 s warm) is used by the slow ones. Needs `anny` where marked.
"""

from __future__ import annotations

import json
import sys
from dataclasses import replace

import numpy as np
import pytest
import torch

from arteq.body import BodyModelFileError, create_body, load_body_model
from arteq.body.model import BODY_NAMES


def _heldout(model, bake, age_range, n, seed, extreme_only=False):
    from arteq.body import anny_allages, anny_rig

    spec = replace(
        anny_allages.spec(),
        make_sampler=lambda m: anny_allages.make_sampler(m, age_range, extreme_only=extreme_only),
    )
    return anny_rig.sample_shapes(spec, model, bake, n, seed=seed)


def _recon_error_mm(body, V: np.ndarray) -> np.ndarray:
    """Per-body mean vertex error (mm) of the least-squares projection of shapes ``V`` on the body's betas."""
    sd = body.shapedirs.double().reshape(-1, body.num_betas)
    X = torch.as_tensor(V).reshape(len(V), -1) - body.v_template.double().reshape(-1)
    betas = torch.linalg.lstsq(sd, X.T).solution.T
    R = body.double()(betas=betas).vertices
    return ((R - torch.as_tensor(V)).norm(dim=-1) * 1000).mean(1).numpy()


@pytest.fixture(scope="module")
def anny_env():
    pytest.importorskip("anny")
    from arteq.body import anny_rig

    model = anny_rig.load_anny()
    return model, anny_rig.compute_bake(model)


@pytest.fixture(scope="module")
def small_allages(tmp_path_factory, anny_env):
    """A 256-sample all-ages file (same spec as the cached one, fewer samples)."""
    from arteq.body import anny_allages, anny_rig

    path = tmp_path_factory.mktemp("bodies") / "anny_allages_small.npz"
    return anny_rig.build_anny_body(anny_allages.spec(num_samples=256), path, verbose=False)


def test_small_build_spans_children_to_elderly(small_allages, anny22):
    from arteq.body import anny_rig

    body = load_body_model("anny_allages", model_path=str(small_allages))
    assert body.name == "anny_allages" and body.num_betas == 16  # the body's own default
    # same mesh and rig as anny22: only the shape space differs
    assert torch.equal(body.faces, anny22.faces)
    torch.testing.assert_close(body.lbs_weights, anny22.lbs_weights, rtol=0, atol=1e-6)
    meta = anny_rig.read_meta(small_allages)
    assert meta["morphological_age_range_years"] == [2.0, 90.0]
    assert meta["sample_ages_years"]["min"] < 4.0 and meta["sample_ages_years"]["max"] > 85.0
    assert meta["sample_heights_m"]["min"] < 1.0 and meta["sample_heights_m"]["max"] > 1.85
    assert 0.15 < meta["sample_tags"]["extreme"] / 256 < 0.35
    with np.load(small_allages) as z:
        assert z["sample_betas"].shape == (256, 32) and z["sample_ages_years"].shape == (256,)
        # the stored betas reproduce the training shapes' spread: unit variance per component
        assert np.allclose(z["sample_betas"].std(0, ddof=1), 1.0, atol=0.02)


def test_children_need_the_allages_body(small_allages, anny_env, anny22):
    """Held-out children (3-10 y): the all-ages space reproduces them, anny22's adult space does not."""
    model, bake = anny_env
    held = _heldout(model, bake, (3.0, 10.0), 8, seed=77)
    allages = load_body_model("anny_allages", model_path=str(small_allages))
    adult = load_body_model("anny22", num_betas=16)
    e_all, e_adult = _recon_error_mm(allages, held["vertices"]), _recon_error_mm(adult, held["vertices"])
    print(f"children 3-10: all-ages 16 betas {e_all.mean():.2f} mm, anny22 16 betas {e_adult.mean():.2f} mm")
    assert e_all.mean() < 2.0  # measured 0.77 mm with 256 samples
    assert e_adult.mean() > 4 * e_all.mean()


def test_anny22_spec_is_the_old_one():
    """anny22's build parameters and provenance keys are what its cached file was always built with."""
    from arteq.body import anny22

    s = anny22.spec()
    assert (s.name, s.num_samples, s.seed, s.num_stored_betas, s.default_num_betas) == (
        "anny22",
        600,
        0,
        16,
        10,
    )
    assert s.meta == {
        "morphological_age_range_years": [18.0, 70.0],
        "gender": "uniform in [0, 1] (anny phenotype)",
    }
    assert s.default_path().name == "anny22.npz"


def test_anny22_file_has_no_new_keys(anny22):
    """The extra arrays of the all-ages file (sample betas...) are not written into anny22's."""
    from arteq.body import anny22 as a22

    path = a22.ensure_anny22()
    with np.load(path) as z:
        assert set(z.files) == {"v_template", "shapedirs", "posedirs", "J_regressor", "weights",
                                "kintree_table", "f", "tpose_bake_rotmats", "meta_json"}  # fmt: skip
        meta = json.loads(str(z["meta_json"]))
    assert "default_num_betas" not in meta and meta["name"] == "anny22"


def test_names_and_missing_files(tmp_path):
    assert {"anny22", "anny_allages", "smpl"} <= set(BODY_NAMES)
    missing = tmp_path / "nope.npz"
    with pytest.raises(
        BodyModelFileError, match=r"anny_allages model file not found.*python -m arteq.body.anny_allages"
    ):
        create_body({"name": "anny_allages", "model_path": str(missing)})
    with pytest.raises(ValueError, match="unknown body model 'anny23'.*'anny_allages'"):
        load_body_model("anny23")


def test_build_without_anny_says_what_to_install(tmp_path, monkeypatch):
    from arteq.body import anny_allages

    monkeypatch.setitem(sys.modules, "anny", None)  # import anny -> ImportError
    with pytest.raises(RuntimeError, match=r"anny_allages body model is not cached at .*pip install anny"):
        anny_allages.ensure_anny_allages(tmp_path / "anny_allages.npz")


def test_checkpoint_records_its_body(small_allages, tmp_path, tiny_net):
    """A model trained on anny_allages reloads with anny_allages (16 betas; the fit refines all 32 the file
    stores by default); an anny22 one with anny22 (10, the fit too)."""
    import lightning

    from arteq.fit.api import Fitter
    from arteq.training.module import ArtEqModule

    for spec, name, nb, fit_nb in (
        ({"name": "anny_allages", "model_path": str(small_allages)}, "anny_allages", 16, 32),
        ({"name": "anny22"}, "anny22", 10, 10),  # what every existing checkpoint records
    ):
        m = ArtEqModule(net=tiny_net, body_model=spec, data={"num_points": 200})
        path = tmp_path / f"{name}.ckpt"
        torch.save({"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams),
                    "pytorch-lightning_version": lightning.__version__}, path)  # fmt: skip
        f = Fitter(ckpt=path, device="cpu")
        assert f.module.body.name == name and f.module.body.num_betas == nb
        assert f.body.name == name and f.body.num_betas == fit_nb
        assert Fitter(ckpt=path, device="cpu", shape_betas=nb).body.num_betas == nb
        with torch.no_grad():
            assert f.module(torch.randn(1, 200, 3))["betas"].shape == (1, nb)


def test_fit_default_shape_betas_follow_what_the_file_stores(anny_env, tmp_path, tiny_net):
    """An all-ages file that stores only the network's 16 components: the fit's default falls back to them
    with a warning naming the checkpoint; asking for 32 explicitly is an error."""
    import dataclasses

    import lightning

    from arteq.body import anny_allages, anny_rig
    from arteq.fit.api import Fitter
    from arteq.training.module import ArtEqModule

    spec = dataclasses.replace(anny_allages.spec(num_samples=64), num_stored_betas=16)
    body_path = anny_rig.build_anny_body(spec, tmp_path / "allages16.npz", verbose=False)
    m = ArtEqModule(net=tiny_net, body_model={"name": "anny_allages", "model_path": str(body_path)},
                    data={"num_points": 200})  # fmt: skip
    path = tmp_path / "net.ckpt"
    torch.save({"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams),
                "pytorch-lightning_version": lightning.__version__}, path)  # fmt: skip
    with pytest.warns(UserWarning, match="net.ckpt: fitting the network's 16 shape components"):
        f = Fitter(ckpt=path, device="cpu", anny=False)
    assert f.body is f.module.body and f.body.num_betas == 16
    with pytest.raises(ValueError, match="shape_betas=32"):
        Fitter(ckpt=path, device="cpu", anny=False, shape_betas=32)


@pytest.mark.slow
def test_cached_allages_body_per_group(anny_env):
    """The cached full build: held-out children, adults and extreme builds within 1.5 mm mean with 16 betas
    (measured 0.91 / 0.41 / 0.53 mm on 100 bodies each, experiments/body/README.md)."""
    model, bake = anny_env
    body = load_body_model("anny_allages")
    for rng, kw, seed in (
        ((2.0, 12.0), {}, 5),
        ((18.0, 70.0), {}, 6),
        ((2.0, 90.0), {"extreme_only": True}, 7),
    ):
        held = _heldout(model, bake, rng, 12, seed=seed, **kw)
        err = _recon_error_mm(body, held["vertices"])
        print(rng, kw, f"{err.mean():.2f} mm")
        assert err.mean() < 1.5
