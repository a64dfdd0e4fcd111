"""BodyScanDataModule and BodyScanDataset on the toy body: determinism, splits, augmentation, cache."""

import pytest
import roma
import torch

from arteq.body.toy import ToyBody
from arteq.data import BodyScanDataModule, BodyScanDataset, SyntheticIDPoses
from arteq.data.dataset import seeded_generator
from arteq.geometry.sampling import sample_surface, smooth_density_field
from arteq.results import TEST_SPLITS

KEYS = {
    "points": ((5000, 3), torch.float32),
    "labels": ((5000,), torch.int64),
    "pose": ((22, 3, 3), torch.float32),
    "global_rotmats": ((22, 3, 3), torch.float32),
    "betas": ((2,), torch.float32),
    "transl": ((3,), torch.float32),
    "center": ((3,), torch.float32),
}


@pytest.fixture(scope="module")
def body():
    return ToyBody()


def _dm(tmp_path, **kw):
    args = dict(body_model={"name": "toy"}, train_size=8, val_size=6, test_size=6, batch_size=3)
    args.update(kw)
    return BodyScanDataModule(cache_root=str(tmp_path / "cache"), **args)


def test_batches_of_all_splits(tmp_path):
    dm = _dm(tmp_path)
    dm.setup()
    loaders = {"train": dm.train_dataloader(), "val": dm.val_dataloader()}
    loaders |= dict(zip(dm.test_splits, dm.test_dataloader()))
    assert list(loaders)[2:] == list(TEST_SPLITS)
    for split, loader in loaders.items():
        batch = next(iter(loader))
        assert set(batch) == set(KEYS), split
        for k, (shape, dtype) in KEYS.items():
            assert batch[k].shape == (3, *shape) and batch[k].dtype == dtype, (split, k)
        assert batch["labels"].min() >= 0 and batch["labels"].max() < 22
        assert torch.allclose(batch["points"].mean(1), torch.zeros(3, 3), atol=1e-5)  # centred
        assert torch.isfinite(batch["points"]).all()
    # every OOD set's bodies have arbitrary orientation, val / test_id ones are upright
    up = lambda s: dm.datasets[s].tensors["pose"][:, 0, 1, 1]  # noqa: E731
    assert (up("test_id") > 0.85).all() and (up("val") > 0.85).all()
    for s in TEST_SPLITS[1:]:
        assert (up(s) < 0.85).any(), s


def test_deterministic_and_independent(tmp_path):
    a = _dm(tmp_path / "a", cache=False)
    b = _dm(tmp_path / "b", cache=False)
    a.setup(), b.setup()
    for split in ("val", "test_id", "test_ood"):
        for k in KEYS:
            assert torch.equal(a.datasets[split].tensors[k], b.datasets[split].tensors[k]), (split, k)
    ta, tb = next(iter(a.train_dataloader())), next(iter(b.train_dataloader()))
    assert all(torch.equal(ta[k], tb[k]) for k in KEYS)
    # splits draw from disjoint streams; samples in a batch do not share a pattern
    assert not torch.equal(a.datasets["val"].tensors["pose"], a.datasets["test_id"].tensors["pose"][:6])
    pts = a.datasets["val"].tensors["points"]
    assert not torch.allclose(pts[0], pts[1])
    c = _dm(tmp_path / "c", cache=False, seed=1)
    c.setup("validate")
    assert not torch.equal(c.datasets["val"].tensors["points"], pts)


def test_train_is_fresh_every_epoch(tmp_path):
    dm = _dm(tmp_path)
    dm.setup("fit")
    loader = dm.train_dataloader()
    e0 = torch.cat([b["pose"] for b in loader])
    e1 = torch.cat([b["pose"] for b in loader])
    assert e0.shape == e1.shape == (8, 22, 3, 3)
    assert not torch.allclose(e0, e1)
    loader.sampler.set_epoch(0)
    assert torch.equal(torch.cat([b["pose"] for b in loader]), e0)  # resume reproduces epoch 0


def test_translation_convention(body):
    """body(betas, pose, transl) is the GT mesh in the centred frame; points lie on it."""
    ds = BodyScanDataset(SyntheticIDPoses(), body, "t", 4, num_points=2000, noise_std=0.0)
    s = ds[2]
    out = body(betas=s["betas"][None], pose=s["pose"][None], transl=s["transl"][None])
    verts, pelvis, grot = out.vertices[0], out.joints[0, 0], out.global_rotmats[0]
    # re-draw the same surface pattern on this mesh: it reproduces the sample's points exactly
    g = seeded_generator(0, "t", 2, "surface")
    dens = smooth_density_field((verts[body.faces].mean(1) - pelvis) @ grot[0], g, ds.density_contrast)
    again, _, _ = sample_surface(verts, body.faces, 2000, g, dens, 0.0)
    assert torch.allclose(again, s["points"], atol=1e-5)
    assert torch.allclose(out.global_rotmats[0], s["global_rotmats"], atol=1e-5)
    # back in the scan frame (synthetic ID: scan translation 0): adding center undoes the centring
    scan = body(betas=s["betas"][None], pose=s["pose"][None]).vertices[0]
    assert torch.allclose(out.vertices[0] + s["center"], scan, atol=1e-5)


@pytest.mark.parametrize("augment", ["so3", "z"])
def test_augmentation_rotates_about_pelvis(body, augment):
    plain = BodyScanDataset(SyntheticIDPoses(), body, "t", 4, num_points=1000, noise_std=0.0)
    aug = BodyScanDataset(SyntheticIDPoses(), body, "t", 4, num_points=1000, noise_std=0.0, augment=augment)
    for i in range(3):
        s, a = plain[i], aug[i]
        assert torch.equal(s["betas"], a["betas"]) and torch.equal(s["labels"], a["labels"])
        assert torch.allclose(s["pose"][1:], a["pose"][1:])
        r = a["pose"][0] @ s["pose"][0].T
        angle = roma.rotmat_geodesic_distance(r, torch.eye(3))
        assert angle > 1e-3
        if augment == "z":  # about the vertical (y) axis
            assert torch.allclose(r[:, 1], torch.tensor([0.0, 1, 0]), atol=1e-5)
        pelvis = body(betas=s["betas"][None], pose=s["pose"][None]).joints[0, 0]
        ps, pa = s["points"] + s["center"], a["points"] + a["center"]  # scan frame
        assert torch.allclose(pa, (ps - pelvis) @ r.T + pelvis, atol=1e-4)


def test_fixed_sets_cached_and_reused(tmp_path, monkeypatch):
    dm = _dm(tmp_path)
    dm.setup("test")
    assert sorted(dm.generated) == sorted(TEST_SPLITS)
    files = sorted((tmp_path / "cache").glob("*.pt"))
    assert len(files) == len(TEST_SPLITS)
    dm2 = _dm(tmp_path)

    def boom(*a, **k):
        raise AssertionError("regenerated although cached")

    monkeypatch.setattr(dm2, "_generate", boom)
    dm2.setup("test")
    assert dm2.generated == []
    for s in ("test_id", "test_ood"):
        assert torch.equal(dm.datasets[s].tensors["points"], dm2.datasets[s].tensors["points"])
    # a config change gives a new key, hence a new file
    dm3 = _dm(tmp_path, noise_std=0.002)
    dm3.setup("validate")
    assert dm3.generated == ["val"] and len(list((tmp_path / "cache").glob("*.pt"))) == len(TEST_SPLITS) + 1


def test_num_points_range_and_bad_config(tmp_path):
    dm = _dm(tmp_path, num_points=500, cache=False)
    dm.setup("fit")
    assert next(iter(dm.train_dataloader()))["points"].shape == (3, 500, 3)
    with pytest.raises(ValueError, match="augment"):
        _dm(tmp_path, augment="so2")
    with pytest.raises(ValueError, match="noise_std.*metres"):
        _dm(tmp_path, noise_std=1.0)  # millimetres passed as metres
    with pytest.raises(ValueError, match="source"):
        _dm(tmp_path, source="dfaust")
