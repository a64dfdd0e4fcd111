"""Holes in full-surface training clouds (arteq.data.holes, ``data.holes``)."""

from __future__ import annotations

import pytest
import torch

from arteq.data import BodyScanDataModule
from arteq.data.dataset import BodyScanDataset
from arteq.data.holes import HoleConfig, carve_holes
from arteq.data.poses import SyntheticIDPoses
from arteq.data.single_view import SingleViewConfig, SingleViewDataset


def test_carved_holes_are_empty_and_the_point_count_is_kept():
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(3000, 3, generator=g, dtype=torch.float64)
    cfg = HoleConfig(prob=1.0, count=(3, 3), radius_m=(0.15, 0.15))
    kept, centres = carve_holes(pts, 1500, cfg, torch.Generator().manual_seed(1))
    assert kept.shape == (1500,) and len(set(kept.tolist())) == 1500
    assert bool((kept[1:] > kept[:-1]).all())  # in the sampler's (random) order
    assert centres.shape == (3, 3)
    d = torch.cdist(pts[kept], centres).min(1).values
    assert float(d.min()) >= 0.15  # nothing left inside a hole
    # every point outside the holes is kept up to the count: the holes removed only what they cover
    outside = torch.cdist(pts, centres).min(1).values >= 0.15
    assert int(outside.sum()) >= 1500 and torch.equal(kept, torch.nonzero(outside)[:1500, 0])


def test_a_hole_that_would_leave_too_few_points_is_skipped():
    pts = torch.rand(1000, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    big = HoleConfig(prob=1.0, count=(4, 4), radius_m=(0.5, 0.5))  # each hole takes half the cube or more
    kept, centres = carve_holes(pts, 900, big, torch.Generator().manual_seed(2))
    assert kept.shape == (900,) and centres.shape[0] == 0
    with pytest.raises(ValueError, match="cannot keep"):
        carve_holes(pts, 1001, big, torch.Generator())


def test_bad_hole_options_are_clear_errors():
    with pytest.raises(ValueError, match="prob"):
        HoleConfig(prob=1.5)
    with pytest.raises(ValueError, match="count"):
        HoleConfig(count=(3, 1))
    with pytest.raises(ValueError, match="radius_m"):
        HoleConfig(radius_m=(0.0, 0.1))
    with pytest.raises(ValueError, match="radius_m"):
        HoleConfig(radius_m=(5.0, 10.0))  # centimetres given for metres
    with pytest.raises(ValueError, match="unknown keys"):
        HoleConfig.from_mapping({"radius": 0.1})


def test_training_clouds_get_holes_and_the_others_are_drawn_as_before(toy_body):
    kw = {"num_points": 400, "seed": 3}
    plain = BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 24, **kw)
    holey = BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 24, holes=HoleConfig(prob=0.5), **kw)
    with_holes = 0
    for i in range(24):
        a, b = plain[i], holey[i]
        for k in ("pose", "betas", "global_rotmats"):
            torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)  # the same body
        assert b["points"].shape == (400, 3) and b["labels"].shape == (400,)
        with_holes += not torch.equal(a["points"], b["points"])
    assert 6 <= with_holes <= 18  # about half; the others bit for bit the clouds drawn without the option


def test_a_cloud_with_holes_misses_the_surface_there(toy_body):
    # uniform density, 2000 points: a complete cloud has no 5 cm gaps, so the holes are what is missing
    kw = {"num_points": 2000, "seed": 3, "density_contrast": 0.0}

    def data(holes):
        return BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 8, holes=holes, **kw)

    plain, holey = data(None), data(HoleConfig(prob=1.0, count=(4, 4), radius_m=(0.08, 0.08)))
    tiny = data(HoleConfig(prob=1.0, count=(1, 1), radius_m=(1e-6, 1e-6)))  # oversampled, nothing carved

    def far(x, y):  # points of x more than 5 cm from every point of y (both in the scan frame)
        d = torch.cdist(x["points"] + x["center"], y["points"] + y["center"]).min(1).values
        return int((d > 0.05).sum())

    for i in range(4):
        assert far(plain[i], holey[i]) >= 25  # four 8 cm holes
        assert far(plain[i], tiny[i]) <= 10 and far(holey[i], plain[i]) <= 10  # on the same surface


def test_holes_reach_the_full_share_of_a_mixed_stream_and_only_training(toy_body, tmp_path):
    kw = {"num_points": 300, "seed": 1}
    mixed = SingleViewDataset(SyntheticIDPoses(), toy_body, "train", 16, config=SingleViewConfig(prob=0.5),
                              holes=HoleConfig(prob=1.0), **kw)  # fmt: skip
    plain = BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 16, holes=HoleConfig(prob=1.0), **kw)
    views = SingleViewDataset(SyntheticIDPoses(), toy_body, "train", 16, config=SingleViewConfig(prob=0.5),
                              **kw)  # fmt: skip
    same = sum(torch.equal(mixed[i]["points"], plain[i]["points"]) for i in range(16))
    same_views = sum(torch.equal(mixed[i]["points"], views[i]["points"]) for i in range(16))
    # the full clouds with holes, the views as they were
    assert same + same_views == 16 and same >= 3 and same_views >= 3
    dkw = {"body_model": toy_body, "num_points": 64, "test_size": 2, "val_size": 2, "train_size": 4,
           "batch_size": 2, "cache_root": str(tmp_path)}  # fmt: skip
    dm = BodyScanDataModule(**dkw, holes={"prob": 1.0, "count": [2, 4]})
    assert dm.make_dataset("train").holes == HoleConfig(prob=1.0, count=(2, 4))
    assert dm.make_dataset("val").holes is None and dm.make_dataset("test_ood").holes is None
    assert dm.cache_path("test_id") == BodyScanDataModule(**dkw).cache_path("test_id")  # test files unchanged
    with pytest.raises(ValueError, match="data.holes"):
        BodyScanDataModule(**dkw, holes={"prob": 2.0})


def test_the_data_config_has_holes_off():
    from conftest import compose_config

    assert compose_config([]).data.holes.prob == 0
    assert compose_config(["data.holes.prob=0.5"]).data.holes.prob == 0.5
