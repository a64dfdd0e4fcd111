"""``arteq.optim_fit.evaluate``: each test loader is reported under its own split's name."""

from __future__ import annotations

import pytest
import torch

from arteq.optim_fit.evaluate import evaluate_fitter, loader_split_names
from arteq.results import TEST_SPLITS


def test_a_subset_of_test_splits_and_a_view_split_get_their_own_names(toy_body, tmp_path):
    from arteq.data import BodyScanDataModule

    dm = BodyScanDataModule(
        body_model=toy_body, num_points=64, test_size=2, val_size=2, train_size=4, batch_size=2,
        eval_batch_size=2, num_workers=0, cache_root=str(tmp_path), test_splits=["test_ood"],
        view_splits=["front"],
    )  # fmt: skip
    assert loader_split_names(dm) == ("test_ood", "test_view_front")
    assert TEST_SPLITS[0] != "test_ood"  # the old pairing with TEST_SPLITS called test_ood "test_id"
    seen = {}
    real = dm.test_dataloader

    def tagged():  # remember which cached set each loader serves
        loaders = real()
        for name, loader in zip(dm.test_loader_splits, loaders):
            seen[name] = next(iter(loader))["points"]
        return loaders

    dm.test_dataloader = tagged
    out = evaluate_fitter(dm, toy_body, {"iters": 1, "num_roots": 1}, max_samples=2)
    assert list(out["metrics"]) == ["test_ood", "test_view_front"] == list(out["fit"])
    assert all(v["samples"] == 2 for v in out["fit"].values())
    # the loaders really are those sets: the OOD set's clouds, then the front views (other clouds)
    assert torch.equal(seen["test_ood"], next(iter(dm._eval_loader("test_ood")))["points"])
    assert not torch.equal(seen["test_ood"], seen["test_view_front"])


def test_names_fall_back_to_the_datamodule_s_split_attributes():
    class Old:  # a datamodule without test_loader_splits
        test_splits = ("test_id", "test_ood_limb1")
        view_splits = ("test_view_top",)

    class Bare:
        pass

    assert loader_split_names(Old()) == ("test_id", "test_ood_limb1", "test_view_top")
    assert loader_split_names(Bare()) == tuple(TEST_SPLITS)


def test_a_loader_count_that_does_not_match_the_names_is_an_error():
    class Wrong:
        test_loader_splits = ("test_id", "test_ood")

        def setup(self, stage):
            pass

        def test_dataloader(self):
            return [[]]

    with pytest.raises(ValueError, match="1 test loaders for the 2 splits"):
        evaluate_fitter(Wrong(), None, {})
