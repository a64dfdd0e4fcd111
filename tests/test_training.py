"""ArtEq network + LightningModule + train/eval entry points, on tiny configurations (CPU)."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from arteq.equivariant import element_orders, group_rotations
from arteq.results import TEST_SPLITS
from arteq.training.module import ArtEqModule
from conftest import compose_config


@pytest.fixture(scope="module")
def tiny_batch():
    from arteq.data import BodyScanDataModule

    dm = BodyScanDataModule(
        body_model={"name": "anny22"}, num_points=200, train_size=2, val_size=2, test_size=2,
        batch_size=2, num_workers=0, cache=False,
    )  # fmt: skip
    dm.setup("fit")
    return next(iter(dm.train_dataloader()))


@pytest.fixture()
def make_module(tiny_net_200):
    """``make_module(stage=2, **kw)``: the tiny network (radii for 200 points) in a fresh module, seed 0."""

    def make(stage: int = 2, **kw) -> ArtEqModule:
        torch.manual_seed(0)
        return ArtEqModule(net=tiny_net_200, body_model={"name": "anny22"}, stage=stage, **kw)

    return make


@pytest.fixture()
def run_cfg(tmp_path, tiny_config):
    """``run_cfg(*overrides)``: the tiny run's config, writing under ``tmp_path``."""
    return lambda *extra: tiny_config(f"paths.output_root={tmp_path}", *extra)


def test_gradients_finite_at_initialisation(tiny_batch, make_module):
    module = make_module()
    for stage_gt in (True, False):
        module.zero_grad()
        _, _, losses = module._step(tiny_batch, use_gt_parts=stage_gt)
        losses["loss"].backward()
        assert torch.isfinite(losses["loss"])
        for name, p in module.net.named_parameters():
            assert p.grad is not None, name
            assert torch.isfinite(p.grad).all(), name


@pytest.mark.parametrize("element", [int(torch.nonzero(element_orders() == o)[0]) for o in (3, 5)])
def test_full_model_is_equivariant(tiny_batch, element, make_module):
    module = make_module().eval()
    r = group_rotations()[element]
    pts = tiny_batch["points"]
    with torch.no_grad():
        out = module(pts)
        out_rot = module(pts @ r.T)
    torch.testing.assert_close(out_rot["part_probs"], out["part_probs"], atol=1e-4, rtol=0)
    torch.testing.assert_close(out_rot["betas"], out["betas"], atol=1e-4, rtol=1e-3)
    torch.testing.assert_close(out_rot["global_rotmats"], r @ out["global_rotmats"], atol=1e-3, rtol=0)
    # The fitted mesh follows the cloud: rotating the input rotates the output body (about the origin).
    torch.testing.assert_close(out_rot["vertices"], out["vertices"] @ r.T, atol=2e-3, rtol=0)


def test_segmenter_group_statistics_are_invariant_and_mean_is_the_default(tiny_batch, tiny_net_200):
    from arteq.models import ArtEqNet

    pts = tiny_batch["points"]
    r = group_rotations()[int(torch.nonzero(element_orders() == 5)[0])]
    torch.manual_seed(0)
    plain = ArtEqNet(**tiny_net_200).eval()
    torch.manual_seed(0)
    seg = tiny_net_200.get("segmenter", {})
    named = ArtEqNet(**{**tiny_net_200, "segmenter": {**seg, "group_pool": "mean"}})
    for (k, a), b in zip(plain.state_dict().items(), named.state_dict().values()):
        torch.testing.assert_close(a, b, rtol=0, atol=0, msg=k)  # same weights: checkpoints load as before
    torch.manual_seed(0)
    stats = ArtEqNet(**{**tiny_net_200, "segmenter": {**seg, "group_pool": "mean_max_std"}}).eval()
    with torch.no_grad():
        feats = stats.backbone(pts)
        inv = stats.segmenter.invariant(feats)
        assert inv.shape[-1] == 3 * feats.shape[-1]
        torch.testing.assert_close(inv[..., : feats.shape[-1]], feats.mean(dim=2))
        out, out_rot = stats(pts), stats(pts @ r.T)
    torch.testing.assert_close(out_rot["part_probs"], out["part_probs"], atol=1e-4, rtol=0)
    torch.testing.assert_close(out_rot["global_rotmats"], r @ out["global_rotmats"], atol=1e-3, rtol=0)
    with pytest.raises(ValueError, match="group_pool"):
        ArtEqNet(**{**tiny_net_200, "segmenter": {"group_pool": "median"}})


def test_overfits_a_tiny_batch(tiny_batch, make_module):
    module = make_module(stage=1, optimizer={"name": "adam", "lr": 3e-3})
    opt = torch.optim.Adam(module.net.parameters(), lr=3e-3)
    losses, rot_err = [], []
    from arteq.geometry.rotations import geodesic_deg

    # parts with (almost) no points have no defined rotation (their pooled feature is ~0 and the weighted
    # mean M ~0, so the projection is decided by rounding): score the parts every cloud actually shows
    counts = F.one_hot(tiny_batch["labels"], 22).sum(1)  # [B, 22]
    seen = counts >= 5
    for _ in range(80):
        opt.zero_grad()
        pred, gt, terms = module._step(tiny_batch, use_gt_parts=True)
        terms["loss"].backward()
        opt.step()
        losses.append(terms["loss"].item())
        rot_err.append(geodesic_deg(pred["global_rotmats"], gt["global_rotmats"])[seen].mean().item())
    first, last = sum(losses[:3]) / 3, sum(losses[-3:]) / 3
    assert last < first / 4, (first, last)
    # the rotation trajectory of 80 steps on 2 clouds depends on rounding (projections of near-singular
    # means early on): the gather-form and Fourier-form backbones, equal to ~3e-6 in float32 gradients,
    # end at 0.66-0.70 and 0.73-0.79 of the start; an untrained or broken pose path stays near 1
    assert sum(rot_err[-3:]) / 3 < 0.85 * sum(rot_err[:3]) / 3, (rot_err[:3], rot_err[-3:])


def test_weights_from_a_body_with_other_betas_load_only_when_asked(tmp_path, tiny_net_200):
    torch.manual_seed(0)
    src = ArtEqModule(net=tiny_net_200, body_model={"name": "anny22"}, stage=2)
    ckpt = tmp_path / "other_body.ckpt"
    torch.save({"state_dict": {f"net.{k}": v for k, v in src.net.state_dict().items()}}, ckpt)
    torch.manual_seed(1)
    dst = ArtEqModule(net=tiny_net_200, body_model={"name": "toy"}, stage=2)  # 2 betas, anny22 has 10
    fresh = {k: v.clone() for k, v in dst.net.state_dict().items()}
    with pytest.raises(ValueError, match="reinit_mismatched"):
        dst.load_net_weights(str(ckpt))
    reinit = dst.load_net_weights(str(ckpt), reinit_mismatched=True)
    assert reinit and all(k.startswith("shape_head.") for k in reinit)
    for k, v in dst.net.state_dict().items():
        torch.testing.assert_close(v, fresh[k] if k in reinit else src.net.state_dict()[k], rtol=0, atol=0)


def test_stage2_trains_stage1_first_then_finds_it(tmp_path, run_cfg):
    from arteq.train import train

    out1 = tmp_path / "run_a"
    s = train(run_cfg("+experiment=stage2", f"paths.output_dir={out1}"))
    assert s["stage1_init"]["how"] == "trained first in this run"
    metrics = json.loads((out1 / "metrics.json").read_text())["metrics"]
    for split in ("test_id", "test_ood"):
        for key in ("part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg"):
            assert torch.isfinite(torch.tensor(metrics[split][key])), (split, key)
    assert (out1 / "metrics.md").read_text().count("| ArtEq |") == 1

    # A stage-1 run of the same network is found by a later stage-2 run.
    s1 = train(run_cfg("+experiment=stage1", f"paths.output_dir={tmp_path / 'stage1' / 'r1'}", "test=false"))
    assert Path(s1["last_ckpt"]).is_file()
    s2 = train(run_cfg("+experiment=stage2", f"paths.output_dir={tmp_path / 'run_b'}", "test=false"))
    assert s2["stage1_init"] == {"ckpt": s1["last_ckpt"], "how": "found from a previous stage-1 run"}
    # ... but not by one trained on other data (here: with rotation augmentation)
    from arteq.train import find_stage1_checkpoint

    assert find_stage1_checkpoint(run_cfg("+experiment=stage2", "data.augment=so3")) is None
    assert find_stage1_checkpoint(run_cfg("+experiment=stage2")) == Path(s1["last_ckpt"])

    with pytest.raises(FileNotFoundError, match="stage1.ckpt"):
        train(
            run_cfg(
                "+experiment=stage2",
                "stage1.ckpt=/nonexistent.ckpt",
                f"paths.output_dir={tmp_path}/c",
            )
        )


def test_resume_continues_step_count_and_checkpoints_load_weights_only(tmp_path, run_cfg):
    from arteq.train import train

    s = train(run_cfg("+experiment=stage1", f"paths.output_dir={tmp_path / 'r'}", "test=false"))
    ckpt = torch.load(s["last_ckpt"], map_location="cpu", weights_only=True)
    assert ckpt["global_step"] == 2
    assert not any(k.startswith("body.") for k in ckpt["state_dict"])  # licensed model data never saved
    resumed = train(
        run_cfg("+experiment=stage1", f"paths.output_dir={tmp_path / 'r'}", "test=false",
             f"ckpt_path={s['last_ckpt']}", "trainer.max_epochs=2")
    )  # fmt: skip
    ckpt2 = torch.load(resumed["last_ckpt"], map_location="cpu", weights_only=True)
    csvs = sorted((tmp_path / "r" / "csv").glob("**/metrics.csv"))
    assert len(csvs) == 2  # the first segment's log is kept, the resumed one goes beside it
    assert ckpt2["global_step"] == 4  # 2 more steps, not 2 from scratch
    # the resumed segment trained epoch 1 only (Lightning stores the epoch counter as of the save,
    # which is 1 or 2 depending on whether the final validation improved the monitored metric)
    resumed_rows = list(csv.DictReader(open(next(p for p in csvs if "resumed" in str(p)))))
    assert {r["epoch"] for r in resumed_rows if r.get("epoch")} == {"1"}
    module = ArtEqModule.load_from_checkpoint(resumed["last_ckpt"], map_location="cpu", weights_only=True)
    assert module.hparams.stage == 1


def test_eval_entry_point_writes_json_and_markdown(tmp_path, run_cfg, tiny_config):
    from arteq.eval import evaluate
    from arteq.train import train

    s = train(run_cfg("+experiment=stage1", f"paths.output_dir={tmp_path / 'r'}", "test=false"))
    cfg = tiny_config(f"ckpt_path={s['last_ckpt']}", f"output_dir={tmp_path / 'ev'}", config_name="eval")
    evaluate(cfg)
    out = json.loads((tmp_path / "ev" / "metrics.json").read_text())
    assert set(out["metrics"]) == set(TEST_SPLITS)  # ID, the hard OOD set and the graded OOD scale
    md = (tmp_path / "ev" / "metrics.md").read_text()
    assert "| ArtEq |" in md and "OOD-1limb part_acc" in md
    bad = compose_config(["ckpt_path=/no/such.ckpt"], "eval", hydra_config=False)
    with pytest.raises(FileNotFoundError, match="ckpt_path=/no/such.ckpt: .*no such file"):
        evaluate(bad)
    bad_name = compose_config(["ckpt_path=no_such_model"], "eval", hydra_config=False)
    with pytest.raises(FileNotFoundError, match="no pretrained model of that name"):
        evaluate(bad_name)
    # metrics of a run's checkpoint go to its run folder; of any other file, to the eval's own folder
    from arteq.eval import default_output_dir

    assert default_output_dir(Path(s["last_ckpt"])) == Path(s["last_ckpt"]).parent.parent
    assert default_output_dir(tmp_path / "model.ckpt") != tmp_path


@pytest.mark.parametrize("stage", [1, 2])
def test_fast_dev_run_each_stage(tmp_path, stage, run_cfg):
    from arteq.train import train

    s = train(
        run_cfg(f"+experiment=stage{stage}", "+trainer.fast_dev_run=true", "stage1.init=false",
             f"paths.output_dir={tmp_path / 'r'}")
    )  # fmt: skip
    for split in ("test_id", "test_ood"):
        assert s["metrics"][split]["v2v_cm"] > 0
