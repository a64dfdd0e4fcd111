"""Test metrics per age band and per build (arteq.training.breakdown) for test sets of the all-ages prior.

Small synthetic stored shape samples on the procedural toy body (no anny, no anny_allages build): what a
draw records about its body, that the draws (and the normal prior's sets and cache keys) are unchanged, the
grouped metrics against the plain metric on each subset, the test loop, metrics.json / metrics.md and the
card.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch

from arteq.data.dataset import META_KEYS, SAMPLE_KEYS, BodyScanDataset, seeded_generator
from arteq.data.poses import SyntheticIDPoses
from arteq.data.shapes import SHAPE_META_KEYS, StoredShapePrior, rest_measurements
from arteq.training.breakdown import (
    AGE_GROUPS,
    BMI_GROUPS,
    GROUPINGS,
    GroupedBodyFitMetrics,
    group_indices,
)
from arteq.training.metrics import BodyFitMetrics

AGES = (3.0, 8.0, 12.5, 13.0, 15.0, 17.9, 18.0, 30.0, 45.0, 64.9, 65.0, 80.0)


def _prior(k: int, n: int = 48, seed: int = 0, extreme: bool = True) -> StoredShapePrior:
    """``n`` stored samples over every age band (:data:`AGES` repeated), a quarter extreme builds."""
    rng = np.random.default_rng(seed)
    ages = np.resize(np.array(AGES), n)
    betas = rng.normal(0, 0.5, (n, k)) + (ages[:, None] > 17.5) * 0.5
    flags = rng.random(n) < 0.25 if extreme else None
    return StoredShapePrior(betas, ages, extreme=flags)


def _old_draw(prior: StoredShapePrior, nb: int, g: torch.Generator) -> tuple[torch.Tensor, int]:
    """The draw as the code did it before it recorded the body (one index, one Gaussian vector)."""
    i = int(torch.randint(len(prior.betas), (1,), generator=g))
    z = torch.randn(nb, generator=g, dtype=torch.float64)
    chol = prior.chol[prior.band[i], :nb, :nb]
    return prior.betas[i, :nb] + prior.jitter * (chol @ z), i


class _SampleOnly:
    """A prior with ``sample`` alone (the dataset's path before it recorded what body a draw is)."""

    def __init__(self, prior: StoredShapePrior) -> None:
        self.prior = prior

    def sample(self, nb: int, g: torch.Generator) -> torch.Tensor:
        return self.prior.sample(nb, g)


# ------------------------------------------------------------------ what a draw records
def test_a_draw_records_its_stored_sample_and_keeps_the_betas():
    prior = _prior(6)
    for seed in range(20):
        betas, meta = prior.draw(4, torch.Generator().manual_seed(seed))
        old, i = _old_draw(prior, 4, torch.Generator().manual_seed(seed))
        assert torch.equal(betas, old)  # bit for bit: the same random numbers, the same arithmetic
        assert torch.equal(prior.sample(4, torch.Generator().manual_seed(seed)), old)
        assert sorted(meta) == sorted(SHAPE_META_KEYS)
        assert int(meta["shape_index"]) == i
        assert float(meta["age_years"]) == pytest.approx(float(prior.ages[i]))
        assert int(meta["build_extreme"]) == int(prior.extreme[i])
    unknown = _prior(6, extreme=False)
    assert int(unknown.draw(4, torch.Generator())[1]["build_extreme"]) == -1
    assert unknown.fingerprint() == prior.fingerprint()  # the labels do not change the draws' fingerprint
    assert unknown.meta_spec() != prior.meta_spec()
    with pytest.raises(ValueError, match="extreme must be"):
        StoredShapePrior(prior.betas.numpy(), prior.ages.numpy(), extreme=np.zeros(3, bool))


def test_dataset_samples_carry_the_body_and_are_unchanged_otherwise(toy_body):
    nb = int(toy_body.num_betas)
    prior = _prior(nb + 2)
    new = BodyScanDataset(SyntheticIDPoses(), toy_body, "test_id", 6, num_points=100, shapes=prior)
    kw = dict(num_points=100)
    old = BodyScanDataset(SyntheticIDPoses(), toy_body, "test_id", 6, shapes=_SampleOnly(prior), **kw)
    assert new.records_shapes and not old.records_shapes
    for i in range(4):
        a, b = new[i], old[i]
        assert sorted(b) == sorted(SAMPLE_KEYS)  # a prior without `draw`: the keys of before
        assert sorted(a) == sorted((*SAMPLE_KEYS, *META_KEYS))
        assert all(torch.equal(a[k], b[k]) for k in SAMPLE_KEYS), i
        expect, j = _old_draw(prior, nb, seeded_generator(0, "test_id", i, "shape"))
        assert torch.equal(a["betas"], expect.float())
        assert int(a["shape_index"]) == j and float(a["age_years"]) == pytest.approx(float(prior.ages[j]))
        assert int(a["build_extreme"]) == int(prior.extreme[j])
    # the normal prior: the keys of before
    plain = BodyScanDataset(SyntheticIDPoses(), toy_body, "test_id", 2, num_points=100)
    assert not plain.records_shapes and sorted(plain[0]) == sorted(SAMPLE_KEYS)


def _datamodule(toy_body, prior=None, **kw):
    from arteq.data import BodyScanDataModule

    args = dict(body_model=toy_body, num_points=100, val_size=2, test_size=6, batch_size=3, num_workers=0)
    dm = BodyScanDataModule(**(args | kw))
    if prior is not None:  # the all-ages prior over a toy body (make_shape_prior wants anny_allages)
        dm.sampling["shapes"] = prior
    return dm


def test_fixed_sets_store_the_body_and_the_normal_sets_keep_their_keys(toy_body, tmp_path):
    from arteq.data.datamodule import read_cache, tensors_digest

    plain = _datamodule(toy_body, cache_root=str(tmp_path))
    # the normal prior's cache keys are the ones of before (measured before the body was recorded): the
    # caches already on disk are still found
    assert plain._cache_key(plain.make_dataset("test_id")) == "29123d3d2aa85c0e67a8"
    prior = _prior(int(toy_body.num_betas))
    dm = _datamodule(toy_body, prior, cache_root=str(tmp_path))
    assert dm._cache_key(dm.make_dataset("test_id")) != plain._cache_key(plain.make_dataset("test_id"))
    fixed = dm.fixed_set("test_id")
    assert sorted(fixed.tensors) == sorted((*SAMPLE_KEYS, *META_KEYS))
    again = read_cache(dm.cache_path("test_id"), "test_id")
    assert all(torch.equal(again[k], fixed.tensors[k]) for k in fixed.tensors)
    live = dm.make_dataset("test_id")
    for i in (0, 5):
        assert all(torch.equal(fixed[i][k], live[i][k]) for k in (*SAMPLE_KEYS, *META_KEYS))
    normal = plain.fixed_set("test_id")
    assert sorted(normal.tensors) == sorted(SAMPLE_KEYS)
    payload = torch.load(plain.cache_path("test_id"), weights_only=True)
    assert sorted(payload["tensors"]) == sorted(SAMPLE_KEYS)
    assert payload["sha256"] == tensors_digest({k: normal.tensors[k] for k in SAMPLE_KEYS})


# ------------------------------------------------------------------ groups and grouped metrics
def test_groups_of_ages_builds_and_bmi(toy_body):
    nb = int(toy_body.num_betas)
    ages = torch.tensor([2.0, 12.99, 13.0, 17.5, 18.0, 64.99, 65.0, 90.0, math.nan])
    batch = {
        "age_years": ages,
        "build_extreme": torch.tensor([0, 1, -1, 0, 1, 0, 1, 0, -1]),
        "shape_index": torch.tensor([0, 1, 2, 3, 4, 5, 6, 7, -1]),
        "betas": torch.zeros(len(ages), nb),
    }
    g = group_indices(batch, toy_body)
    assert g["age"].tolist() == [0, 0, 1, 1, 2, 2, 3, 3, -1]
    assert g["build"].tolist() == [0, 1, -1, 0, 1, 0, 1, 0, -1]
    bmi = rest_measurements(toy_body, batch["betas"])["bmi"]
    expect = [next(i for i, (_, lo, hi) in enumerate(BMI_GROUPS) if lo <= float(bmi[0]) < hi)] * 8 + [-1]
    assert g["bmi"].tolist() == expect
    assert [a[0] for a in AGE_GROUPS] == list(GROUPINGS["age"]) == ["2-12", "13-17", "18-64", "65+"]


def test_rest_measurements_of_a_cube():
    class Cube(torch.nn.Module):
        v = torch.tensor([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=torch.float64)
        faces = torch.tensor([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                              [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])  # fmt: skip
        v_template = v

        def shape(self, betas):  # betas[:, 0] scales the cube
            s = 1 + betas[:, :1, None]
            return self.v[None] * s, None

    m = rest_measurements(Cube(), torch.tensor([[0.0], [1.0]], dtype=torch.float64))
    assert torch.allclose(m["volume_m3"], torch.tensor([1.0, 8.0], dtype=torch.float64))
    assert torch.allclose(m["stature_m"], torch.tensor([1.0, 2.0], dtype=torch.float64))
    assert torch.allclose(m["bmi"], torch.tensor([980.0, 980.0 * 8 / 4], dtype=torch.float64))


def test_grouped_metrics_equal_the_plain_metric_on_each_subset():
    g = torch.Generator().manual_seed(0)
    B, V, N = 10, 30, 40
    from arteq.geometry.rotations import random_rotmat

    args = [
        torch.randn(B, V, 3, generator=g), torch.randn(B, V, 3, generator=g),
        torch.randn(B, 22, 3, generator=g), torch.randn(B, 22, 3, generator=g),
        random_rotmat(B * 22, g).reshape(B, 22, 3, 3), random_rotmat(B * 22, g).reshape(B, 22, 3, 3),
        torch.randint(0, 22, (B, N), generator=g), torch.randint(0, 22, (B, N), generator=g),
    ]  # fmt: skip
    groups = torch.tensor([0, 2, 2, -1, 1, 0, 2, 2, 0, 1])
    grouped = GroupedBodyFitMetrics(4)
    for s in (slice(0, 4), slice(4, 10)):  # two batches
        grouped.update(groups[s], *[a[s] for a in args])
    out = grouped.compute()
    assert out["count"].tolist() == [3, 2, 4, 0]
    assert int(out["count"].sum()) == int((groups >= 0).sum())
    for k in range(3):
        plain = BodyFitMetrics()
        mask = groups == k
        plain.update(*[a[mask] for a in args])
        ref = plain.compute()
        for key in ("part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg"):
            assert float(out[key][k]) == pytest.approx(float(ref[key]), rel=1e-12, abs=1e-12), (k, key)


# ------------------------------------------------------------------ the test loop, metrics files, card
def _test(toy_body, tiny_net, dm):
    import lightning as L

    from arteq.training.module import ArtEqModule

    torch.manual_seed(0)
    net = {**tiny_net, "backbone": {**tiny_net["backbone"], "radii": [0.3, 0.4, 0.5, 0.5]}}
    module = ArtEqModule(net=net, body_model={"name": "toy"}, body=toy_body)
    trainer = L.Trainer(accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False)  # fmt: skip
    trainer.test(module, datamodule=dm, verbose=False)
    return module


def test_the_test_loop_breaks_the_allages_sets_down_and_the_normal_ones_not(toy_body, tiny_net, tmp_path):
    from arteq.eval import module_breakdown, write_metrics
    from arteq.results import BREAKDOWN_NOTE, metrics_markdown, summary_rows

    splits = ["test_id", "test_ood"]
    prior = _prior(int(toy_body.num_betas))
    dm = _datamodule(toy_body, prior, cache=False, test_splits=splits, view_splits=["front"])
    module = _test(toy_body, tiny_net, dm)
    breakdown = module_breakdown(module)
    assert list(breakdown) == [*splits, "test_view_front"] == list(module.test_results)
    for split, res in breakdown.items():
        assert list(res) == list(GROUPINGS)
        for grouping, rows in res.items():
            assert sum(r["count"] for r in rows.values()) == 6, (split, grouping)  # the split's clouds
            assert all(math.isfinite(r[k]) for r in rows.values() for k in r)
    # a group's values are the plain metrics of its clouds: a split whose clouds all fall in one group
    one = _prior(int(toy_body.num_betas), extreme=False)
    one.ages[:] = 40.0
    dm1 = _datamodule(toy_body, one, cache=False, test_splits=["test_id"])
    m1 = _test(toy_body, tiny_net, dm1)
    (adults,) = m1.test_breakdown["test_id"]["age"].values()
    assert adults["count"] == 6 and m1.test_breakdown["test_id"]["build"] == {}  # build not known
    for k in ("part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg"):
        assert adults[k] == pytest.approx(m1.test_results["test_id"][k], rel=1e-5), k

    summary = {"task_name": "t", "metrics": module.test_results, "breakdown": breakdown}
    write_metrics(summary, tmp_path / "a", "ArtEq")
    md = (tmp_path / "a" / "metrics.md").read_text()
    assert "Test metrics per age band" in md and "Test metrics per BMI band" in md and BREAKDOWN_NOTE in md
    assert "| ID | " in md and "| front-view | " in md
    assert json.loads((tmp_path / "a" / "metrics.json").read_text())["breakdown"] == json.loads(
        json.dumps(breakdown)
    )

    # the normal prior: no breakdown, metrics.json / metrics.md as before
    normal = _test(toy_body, tiny_net, _datamodule(toy_body, cache=False, test_splits=splits))
    assert module_breakdown(normal) == {} and list(normal.test_results) == splits
    summary = {"task_name": "t", "metrics": normal.test_results}
    write_metrics(summary, tmp_path / "b", "ArtEq")
    assert "breakdown" not in json.loads((tmp_path / "b" / "metrics.json").read_text())
    md = (tmp_path / "b" / "metrics.md").read_text()
    assert md.rstrip("\n") == metrics_markdown("t", summary_rows(summary, "ArtEq")).rstrip("\n")


def test_card_shows_the_breakdown_when_the_metrics_have_it(tmp_path):
    from arteq.pretrained.card import write_card

    row = {"count": 3, "part_acc": 50.0, "v2v_cm": 10.0, "mpjpe_cm": 8.0, "rot_err_deg": 30.0}
    breakdown = {"test_id": {"age": {"2-12": row, "18-64": row}, "build": {"typical": row},
                             "bmi": {"18.5-25": row}}}  # fmt: skip
    metrics = {"test_id": {"part_acc": 50.0, "v2v_cm": 10.0, "mpjpe_cm": 8.0, "rot_err_deg": 30.0}}
    info = {"name": "m", "subset_n": 2, "subset_tolerance": 0.05, "subset_metrics": metrics,
            "test_metrics": metrics}  # fmt: skip
    hparams = {"body_model": {"name": "anny_allages"}, "net": {}, "data": {}}
    write_card(tmp_path / "plain.md", info, hparams, 10)
    write_card(tmp_path / "broken.md", info | {"test_breakdown": breakdown}, hparams, 10)
    plain, broken = (tmp_path / "plain.md").read_text(), (tmp_path / "broken.md").read_text()
    assert "per age band" not in plain and "free anny_allages body" in plain
    assert "## Test metrics per age band (years)" in broken and "## Test metrics per build" in broken
    assert "| ID | 2-12 | 3 | 50.00 | 10.00 | 8.00 | 30.00 |" in broken
    assert broken.index("per age band") < broken.index("## Subset metrics")
    # the run's metrics.json -> the card's info (export)
    from arteq.pretrained.card import _run_summary

    (tmp_path / "run").mkdir()
    (tmp_path / "run" / "metrics.json").write_text(json.dumps({"metrics": metrics, "breakdown": breakdown}))
    assert _run_summary(tmp_path / "run")["breakdown"] == breakdown
    (tmp_path / "run" / "metrics.json").write_text(json.dumps({"metrics": metrics}))
    assert "breakdown" not in _run_summary(tmp_path / "run")


def test_card_export_takes_the_breakdown_of_an_eval(toy_body, tiny_net, tmp_path, monkeypatch):
    """A run trained before the breakdown existed: the card takes it from ``arteq.eval``'s metrics.json."""
    import lightning as L

    import arteq.pretrained.card as card
    from arteq.training.module import ArtEqModule

    torch.manual_seed(0)
    net = {**tiny_net, "backbone": {**tiny_net["backbone"], "radii": [0.3, 0.4, 0.5, 0.5]}}
    data = {"num_points": 100, "test_size": 2, "num_workers": 0}
    module = ArtEqModule(net=net, body_model={"name": "toy"}, body=toy_body, data=data)
    trainer = L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.strategy.connect(module)
    run = tmp_path / "run"
    trainer.save_checkpoint(run / "checkpoints" / "epoch00.ckpt", weights_only=False)
    metrics = {"test_id": {"part_acc": 1.0, "v2v_cm": 2.0, "mpjpe_cm": 3.0, "rot_err_deg": 4.0}}
    (run / "metrics.json").write_text(json.dumps({"metrics": metrics}))
    row = {"count": 2, "part_acc": 1.0, "v2v_cm": 2.0, "mpjpe_cm": 3.0, "rot_err_deg": 4.0}
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "metrics.json").write_text(
        json.dumps({"metrics": metrics, "breakdown": {"test_id": {"age": {"65+": row}}}})
    )
    monkeypatch.setattr(card, "PRETRAINED_DIR", tmp_path / "pre")
    (tmp_path / "pre").mkdir()
    card.export(run, "m", None, None, 2)
    assert "per age band" not in (tmp_path / "pre" / "m.md").read_text()
    card.export(run, "m", None, None, 2, breakdown_from=tmp_path / "eval")
    assert "| ID | 65+ | 2 | 1.00 | 2.00 | 3.00 | 4.00 |" in (tmp_path / "pre" / "m.md").read_text()
    with pytest.raises(ValueError, match="no breakdown"):
        card.export(run, "m", None, None, 2, breakdown_from=run / "metrics.json")


def test_card_export_of_a_checkpoint_file_takes_every_test_set_of_an_eval(
    toy_body, tiny_net, tmp_path, monkeypatch
):
    """A resumable checkpoint whose run folder is gone: the card's test table is the eval's, every set."""
    import lightning as L

    import arteq.pretrained.card as card
    from arteq.training.module import ArtEqModule

    torch.manual_seed(0)
    net = {**tiny_net, "backbone": {**tiny_net["backbone"], "radii": [0.3, 0.4, 0.5, 0.5]}}
    module = ArtEqModule(net=net, body_model={"name": "toy"}, body=toy_body,
                         data={"num_points": 100, "test_size": 2, "num_workers": 0})  # fmt: skip
    trainer = L.Trainer(accelerator="cpu", logger=False, enable_progress_bar=False)
    trainer.strategy.connect(module)
    ckpt = tmp_path / "resume.ckpt"
    trainer.save_checkpoint(ckpt, weights_only=False)
    monkeypatch.setattr(card, "PRETRAINED_DIR", tmp_path / "pre")
    (tmp_path / "pre").mkdir()
    with pytest.raises(ValueError, match="needs --metrics-from"):
        card.export(ckpt, "m", None, None, 2)
    row = {"part_acc": 1.0, "v2v_cm": 2.0, "mpjpe_cm": 3.0, "rot_err_deg": 4.0}
    (tmp_path / "eval").mkdir()
    (tmp_path / "eval" / "metrics.json").write_text(
        json.dumps({"metrics": {"test_id": row, "test_ood": row, "test_ood_limb1": {**row, "part_acc": 7.0}}})
    )
    card.export(ckpt, "m", None, None, 2, metrics_from=tmp_path / "eval")
    text = (tmp_path / "pre" / "m.md").read_text()
    assert "| test_ood_limb1 (" in text and "| 7.00 | 2.00 | 3.00 | 4.00 |" in text
    assert "arteq.eval` on the checkpoint" in text


def test_card_export_with_a_bad_metrics_file_names_it_and_writes_nothing(tmp_path, monkeypatch):
    """A missing, unreadable or empty metrics.json: an error naming the file, before anything is written."""
    import arteq.pretrained.card as card

    monkeypatch.setattr(card, "PRETRAINED_DIR", tmp_path / "pre")
    (tmp_path / "pre").mkdir()
    ckpt = tmp_path / "resume.ckpt"
    ckpt.write_bytes(b"never read: the metrics files are checked first")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    good = tmp_path / "good.json"
    good.write_text(json.dumps({"metrics": {"test_id": {"part_acc": 1.0}}}))
    missing = tmp_path / "missing.json"
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps({"metrics": {}}))
    cases = [({"metrics_from": empty}, empty, "no test metrics"),
             ({"metrics_from": missing}, missing, "no such metrics file"),
             ({"metrics_from": bad}, bad, "not a readable"),
             ({"metrics_from": tmp_path / "pre"}, tmp_path / "pre" / "metrics.json", "no such metrics file"),
             ({"metrics_from": good, "breakdown_from": bad}, bad, "not a readable"),
             ({"metrics_from": good, "breakdown_from": good}, good, "no breakdown")]  # fmt: skip
    for kwargs, path, match in cases:
        with pytest.raises((ValueError, FileNotFoundError), match=match) as err:
            card.export(ckpt, "m", None, None, 2, **kwargs)
        assert str(path) in str(err.value)
    assert not list((tmp_path / "pre").iterdir())
