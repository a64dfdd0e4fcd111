"""Training shapes from the all-ages body's stored shape samples (``data.shape_prior``, arteq.data.shapes).

The unit tests use small synthetic sample sets; the ones marked with the real ``anny_allages`` file use its
cached build (built on first use; needs ``anny`` then, skipped without it and without the cache).
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from arteq.data.dataset import BodyScanDataset, seeded_generator
from arteq.data.poses import SyntheticIDPoses
from arteq.data.shapes import AGE_BANDS_YEARS, SHAPE_PRIORS, StoredShapePrior, make_shape_prior


def _synthetic(n=300, k=6, seed=0):
    """Two age groups with different means and spreads: children (ages 3-10) and adults (30-60)."""
    rng = np.random.default_rng(seed)
    ages = np.concatenate([rng.uniform(3, 10, n // 2), rng.uniform(30, 60, n - n // 2)])
    betas = rng.normal(0, 1, (n, k))
    betas[: n // 2] = betas[: n // 2] * 0.2 - 3.0  # children: tight, far from the adults
    betas[n // 2 :] = betas[n // 2 :] * 1.0 + 1.0
    return betas, ages


def test_draws_are_deterministic_per_generator_seed():
    prior = StoredShapePrior(*_synthetic())
    a = [prior.sample(4, torch.Generator().manual_seed(s)) for s in range(5)]
    b = [prior.sample(4, torch.Generator().manual_seed(s)) for s in range(5)]
    assert all(torch.equal(x, y) for x, y in zip(a, b, strict=True))
    assert not torch.equal(a[0], a[1])
    assert a[0].dtype == torch.float64 and a[0].shape == (4,)


def test_zero_jitter_gives_the_stored_samples_and_jitter_keeps_the_age_structure():
    betas, ages = _synthetic()
    exact = StoredShapePrior(betas, ages, jitter=0.0)
    g = torch.Generator().manual_seed(1)
    rows = {tuple(np.round(r, 9)) for r in betas[:, :3]}
    for _ in range(50):
        assert tuple(np.round(exact.sample(3, g).numpy(), 9)) in rows
    # with the default jitter the draws stay two groups (children near -3, adults near +1): the per-age
    # covariance perturbs a sample within its band, no draw falls into the empty middle a Gaussian fills
    prior = StoredShapePrior(betas, ages)
    d = torch.stack([prior.sample(6, g) for _ in range(2000)]).mean(1).numpy()
    kids, adults = (d < -1).mean(), (d > -1).mean()
    assert 0.4 < kids < 0.6 and 0.4 < adults < 0.6
    assert np.abs(d[d < -1] + 3.0).max() < 0.5  # children's spread is the tight band's, not the adults'
    one = StoredShapePrior(betas, np.full(len(ages), 40.0))  # one band: the pooled covariance
    spread = torch.stack([one.sample(6, g) - one.betas[0, :6] for _ in range(10)])
    assert torch.isfinite(spread).all()


def test_bad_input_is_refused_with_clear_errors():
    betas, ages = _synthetic()
    with pytest.raises(ValueError, match="ages must be"):
        StoredShapePrior(betas, ages[:-1])
    with pytest.raises(ValueError, match="betas must be"):
        StoredShapePrior(betas[:1], ages[:1])
    with pytest.raises(ValueError, match="finite"):
        StoredShapePrior(np.where(betas > 2, np.nan, betas), ages)
    with pytest.raises(ValueError, match="jitter"):
        StoredShapePrior(betas, ages, jitter=-1.0)
    with pytest.raises(ValueError, match="increasing"):
        StoredShapePrior(betas, ages, bands=(0.0, 50.0, 20.0))
    prior = StoredShapePrior(betas, ages)
    with pytest.raises(ValueError, match="the body has 7 betas, the stored samples 6"):
        prior.sample(7, torch.Generator())
    with pytest.raises(ValueError, match="shape_prior must be one of"):
        make_shape_prior("gaussian", {"name": "anny_allages"})
    with pytest.raises(ValueError, match="body_model=anny_allages"):
        make_shape_prior("allages", {"name": "anny22"})
    with pytest.raises(ValueError, match="body_model=anny_allages"):
        make_shape_prior("allages", None)  # no body config: the default body, anny22
    assert make_shape_prior("normal", {"name": "anny22"}) is None
    assert SHAPE_PRIORS == ("normal", "allages")


def test_dataset_draws_betas_from_the_prior_only_when_given(toy_body):
    prior = StoredShapePrior(*_synthetic(k=int(toy_body.num_betas) + 2))
    plain = BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 4, num_points=200)
    drawn = BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 4, num_points=200, shapes=prior)
    nb = int(toy_body.num_betas)
    for i in range(3):
        g = seeded_generator(0, "train", i, "shape")
        assert torch.allclose(drawn[i]["betas"].double(), prior.sample(nb, g), atol=1e-6)
        g = seeded_generator(0, "train", i, "shape")
        assert torch.allclose(plain[i]["betas"].double(), torch.randn(nb, generator=g, dtype=torch.float64))
        assert torch.equal(plain[i]["pose"], drawn[i]["pose"])  # the other streams are untouched


def test_default_config_leaves_the_datamodule_as_before(toy_body):
    from omegaconf import OmegaConf

    from arteq.data import BodyScanDataModule
    from arteq.paths import conf_dir

    cfg = OmegaConf.load(conf_dir() / "data" / "synthetic.yaml")
    assert cfg.shape_prior == "normal"
    dm = BodyScanDataModule(body_model=toy_body, cache=False, shape_prior=cfg.shape_prior)
    assert sorted(dm.sampling) == ["beta_scale", "density_contrast", "density_wavelength", "noise_std",
                                   "num_points"]  # fmt: skip
    assert dm.make_dataset("train").shapes is None
    with pytest.raises(ValueError, match="body_model=anny_allages"):
        BodyScanDataModule(body_model=toy_body, cache=False, shape_prior="allages")


# ------------------------------------------------------------------ the real all-ages body
@pytest.fixture(scope="module")
def allages():
    from arteq.body import load_body_model
    from arteq.body.anny_allages import default_path

    if not default_path().is_file():
        pytest.importorskip("anny", reason="building anny_allages needs the anny package")
    return load_body_model("anny_allages").double()


def _statures(body, betas: torch.Tensor) -> np.ndarray:
    """T-pose height (m) of each betas row: the vertical (y) extent of the rest mesh."""
    with torch.no_grad():
        rest, _ = body.shape(betas.to(body.v_template.dtype))
    y = rest[..., 1]
    return (y.amax(1) - y.amin(1)).numpy()


def test_allages_statures_span_children_to_tall_adults_and_are_deterministic(allages):
    """Through the config: body_model=anny_allages data.shape_prior=allages; 1500 training draws."""
    from hydra import compose, initialize_config_dir

    from arteq.paths import conf_dir
    from arteq.training.build import build_datamodule

    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        cfg = compose("train", overrides=["body_model=anny_allages", "data.shape_prior=allages",
                                          "data.cache=false"])  # fmt: skip
    dm = build_datamodule(cfg, body=allages)
    prior = dm.sampling["shapes"]
    assert isinstance(prior, StoredShapePrior) and prior.betas.shape[0] == 2000
    ds = dm.make_dataset("train")
    assert ds.shapes is prior
    nb = int(allages.num_betas)
    betas = torch.stack(
        [ds._betas(None, seeded_generator(dm.seed, "train", i, "shape")) for i in range(1500)]
    )
    h = _statures(allages, betas)
    # measured: 0.84-1.99 m over 2000 draws, as the stored samples (0.84-1.98 m)
    assert h.min() < 0.95 and h.max() > 1.88, (h.min(), h.max())
    assert 0.7 < h.min() and h.max() < 2.1  # no giants, no dwarfs beyond the samples' range
    stored = _statures(allages, prior.betas[:, :nb])
    for cut in (1.0, 1.3, 1.6):  # small children, children, short adults keep their share of the samples
        assert abs((h < cut).mean() - (stored < cut).mean()) < 0.045, cut
    # the normal prior over the same body blurs the ages: no toddlers (measured min 1.00 m), giants (2.25 m)
    h_normal = _statures(allages, torch.randn(600, nb, generator=torch.Generator().manual_seed(0),
                                              dtype=torch.float64))  # fmt: skip
    assert (h_normal < 1.0).mean() < (h < 1.0).mean() and h_normal.max() > h.max()
    # deterministic per seed: the same stream again, another seed another stream
    again = torch.stack([ds._betas(None, seeded_generator(dm.seed, "train", i, "shape")) for i in range(20)])
    assert torch.equal(again, betas[:20])
    other = [ds._betas(None, seeded_generator(dm.seed + 1, "train", i, "shape")) for i in range(20)]
    assert not torch.equal(torch.stack(other), betas[:20])
    # a full sample carries those betas; the fixed sets' cache keys name the prior, the default's do not
    assert torch.allclose(ds[3]["betas"].double(), betas[3], atol=1e-6)
    plain = build_datamodule(compose_plain(), body=allages)
    assert dm._cache_key(dm.make_dataset("val")) != plain._cache_key(plain.make_dataset("val"))
    assert AGE_BANDS_YEARS[0] <= float(prior.ages.min()) and float(prior.ages.max()) <= AGE_BANDS_YEARS[-1]


def compose_plain():
    from hydra import compose, initialize_config_dir

    from arteq.paths import conf_dir

    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        return compose("train", overrides=["body_model=anny_allages", "data.cache=false"])
