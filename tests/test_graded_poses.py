"""The graded OOD scale (one / two OOD limbs, contact-free OOD poses) and the widened training poses."""

from __future__ import annotations

import pytest
import torch

from arteq.body.skeleton import JOINT_NAMES
from arteq.data import BodyScanDataModule
from arteq.data.poses import (
    LIMBS,
    WIDE_ID_RANGES_DEG,
    ContactRejectedPoses,
    LimbOODPoses,
    SyntheticIDPoses,
    SyntheticOODPoses,
    pose_set_gaps,
)
from arteq.results import TEST_SPLITS


@pytest.mark.parametrize("n", [1, 2])
def test_limb_poses_replace_exactly_n_limbs_of_an_everyday_pose(n):
    src = LimbOODPoses(n)
    for seed in range(5):
        ang, limbs = src.euler(torch.Generator().manual_seed(seed))
        g = torch.Generator().manual_seed(seed)
        everyday, ood = src.id_source.euler(g), src.ood_source.euler(g)
        assert len(set(limbs)) == n and set(limbs) <= set(LIMBS)
        moved = [JOINT_NAMES.index(j) for limb in limbs for j in LIMBS[limb]]
        kept = [i for i in range(22) if i not in moved]
        torch.testing.assert_close(ang[moved], ood[moved], rtol=0, atol=0)
        torch.testing.assert_close(ang[kept], everyday[kept], rtol=0, atol=0)
        assert not torch.allclose(ang[moved], everyday[moved])
        pose = src.sample(0, torch.Generator().manual_seed(seed))["pose"]
        assert pose.shape == (22, 3) and torch.isfinite(pose).all()


def test_limb_count_is_checked():
    with pytest.raises(ValueError, match="num_limbs"):
        LimbOODPoses(0)


def test_contact_rejection_keeps_only_contact_free_poses(toy_body):
    src = ContactRejectedPoses(toy_body, max_fraction=0.01)
    hard = SyntheticOODPoses()
    g = torch.Generator().manual_seed(0)
    kept = [src.contact(src.sample(i, g)["pose"]) for i in range(6)]
    assert max(kept) <= 0.01
    g = torch.Generator().manual_seed(0)
    raw = [src.contact(hard.sample(i, g)["pose"]) for i in range(30)]
    assert max(raw) > 0.01  # the hard sampler does make contact: the rejection has something to reject


def test_zero_widening_is_the_narrow_source():
    narrow, zero = SyntheticIDPoses(), SyntheticIDPoses(wide_prob=0.0)
    assert narrow.fingerprint() == zero.fingerprint()
    a = narrow.sample(0, torch.Generator().manual_seed(3))["pose"]
    b = zero.sample(0, torch.Generator().manual_seed(3))["pose"]
    torch.testing.assert_close(a, b, rtol=0, atol=0)
    assert SyntheticIDPoses(wide_prob=0.5).fingerprint() != narrow.fingerprint()
    with pytest.raises(ValueError, match="wide_prob"):
        SyntheticIDPoses(wide_prob=1.5)


def test_widening_moves_only_its_joints_and_widens_them():
    narrow, wide = SyntheticIDPoses(), SyntheticIDPoses(wide_prob=1.0)
    wide_joints = {n for n in WIDE_ID_RANGES_DEG} | {
        "right_" + n[5:] for n in WIDE_ID_RANGES_DEG if n.startswith("left_")
    }
    idx = torch.tensor([JOINT_NAMES.index(n) for n in sorted(wide_joints)])
    rest = torch.tensor([i for i in range(22) if i not in set(idx.tolist())])
    spread_n, spread_w = [], []
    for seed in range(40):
        a = narrow.euler(torch.Generator().manual_seed(seed))
        b = wide.euler(torch.Generator().manual_seed(seed))
        torch.testing.assert_close(a[rest], b[rest], rtol=0, atol=0)
        spread_n.append(a[idx])
        spread_w.append(b[idx])
    # joints the everyday motions barely move (wrists, collars, neck, head: noise only) now move widely
    still = [i for i, j in enumerate(idx.tolist()) if "wrist" in JOINT_NAMES[j] or JOINT_NAMES[j] in
             ("neck", "head", "left_collar", "right_collar")]  # fmt: skip
    sn, sw = torch.stack(spread_n)[:, still].std(0).mean(), torch.stack(spread_w)[:, still].std(0).mean()
    assert sw > 3 * sn, (sw, sn)


def test_graded_sets_lie_between_id_and_the_hard_set():
    gaps = pose_set_gaps(
        SyntheticIDPoses(),
        {"id": SyntheticIDPoses(), "limb1": LimbOODPoses(1), "limb2": LimbOODPoses(2),
         "hard": SyntheticOODPoses()},
        n_ref=300, n_query=40,
    )  # fmt: skip
    d = {k: v["mean_deg"] for k, v in gaps.items()}
    assert d["id"] < d["limb1"] < d["limb2"] < d["hard"], d


def test_datamodule_runs_the_chosen_test_sets_in_order(toy_body, tmp_path):
    dm = BodyScanDataModule(
        body_model=toy_body, num_points=64, test_size=2, val_size=2, train_size=4, batch_size=2,
        cache_root=str(tmp_path), test_splits=["test_ood_limb1", "test_id"],
    )  # fmt: skip
    assert dm.test_splits == ("test_id", "test_ood_limb1")  # TEST_SPLITS order
    dm.setup("test")
    loaders = dm.test_dataloader()
    assert len(loaders) == 2
    batch = next(iter(loaders[1]))
    assert batch["points"].shape == (2, 64, 3)
    assert set(dm.test_splits) <= set(TEST_SPLITS)
    with pytest.raises(ValueError, match="test_splits"):
        BodyScanDataModule(body_model=toy_body, test_splits=["test_nowhere"])


def test_training_pose_mix_draws_each_source_at_its_weight_and_leaves_tests_alone(toy_body):
    mixed = BodyScanDataModule(
        body_model=toy_body, train_pose_mix={"id": 0.5, "ood": 0.3, "limb2": 0.2, "contact": 0.0}, cache=False
    )
    src = mixed._sources("train")
    assert src.weights == pytest.approx({"id": 0.5, "ood": 0.3, "limb2": 0.2})  # zero weights dropped
    g = torch.Generator().manual_seed(0)
    picks = [src.pick(g) for _ in range(2000)]
    for name, w in src.weights.items():
        assert abs(picks.count(name) / len(picks) - w) < 0.04
    # a draw is the chosen source's own draw from the same generator state
    for seed in range(6):
        g = torch.Generator().manual_seed(seed)
        name = src.pick(g)
        want = src.sources[name].sample(0, g)["pose"]
        got = src.sample(0, torch.Generator().manual_seed(seed))["pose"]
        torch.testing.assert_close(got, want, rtol=0, atol=0)
    # OOD picks are far from everyday poses, the ID picks are not
    ood = SyntheticOODPoses()
    assert src.fingerprint() != SyntheticIDPoses().fingerprint()
    plain = BodyScanDataModule(body_model=toy_body, cache=False)
    for split in ("val", *TEST_SPLITS):
        assert mixed._sources(split).fingerprint() == plain._sources(split).fingerprint()
    assert plain._sources("train").fingerprint() == SyntheticIDPoses().fingerprint()
    assert ood.fingerprint() == mixed._sources("test_ood").fingerprint()


@pytest.mark.parametrize(
    "mix, match",
    [({"pose_prior": 1.0}, "unknown sources"), ({"id": -1.0}, ">= 0"), ({"id": 0.0}, "not all 0"),
     ([0.5, 0.5], "mapping"), ({"id": "many"}, "numbers")],
)  # fmt: skip
def test_training_pose_mix_is_checked(toy_body, mix, match):
    with pytest.raises(ValueError, match=match):
        BodyScanDataModule(body_model=toy_body, train_pose_mix=mix)


def test_athletic_training_source_is_the_ood_sampler_over_the_wider_range(toy_body):
    from arteq.data.poses import ATHLETIC_LIMITS_DEG

    mixed = BodyScanDataModule(body_model=toy_body, train_pose_mix={"id": 0.6, "athletic": 0.4}, cache=False)
    src = mixed._sources("train")
    want = SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG)
    assert src.sources["athletic"].fingerprint() == want.fingerprint()
    plain = BodyScanDataModule(body_model=toy_body, cache=False)
    for split in ("val", *TEST_SPLITS):  # no test set draws from it
        assert mixed._sources(split).fingerprint() == plain._sources(split).fingerprint()


def test_athletic_spine_source_is_the_athletic_sampler_with_half_its_draws_chained(toy_body):
    from arteq.data.poses import ATHLETIC_LIMITS_DEG

    mixed = BodyScanDataModule(body_model=toy_body, train_pose_mix={"athletic_spine": 1.0}, cache=False)
    src = mixed._sources("train").sources["athletic_spine"]
    want = SyntheticOODPoses(limits=ATHLETIC_LIMITS_DEG, spine_chain_prob=0.5)
    assert src.fingerprint() == want.fingerprint()
    plain = BodyScanDataModule(body_model=toy_body, cache=False)
    for split in ("val", *TEST_SPLITS):
        assert mixed._sources(split).fingerprint() == plain._sources(split).fingerprint()
