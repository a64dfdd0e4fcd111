"""Ablation / baseline configs compose and build their module; a tiny multirun gives unique job dirs
and a report (slow)."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from conftest import CONF
from conftest import compose_config as _compose

SWEEPS = {
    "ablation_nc": {"model.net.parent_conditioning": "invariant,aligned,none"},
    "ablation_aug": {"data.augment": "none,so3"},
    "ablation_points": {"data.num_points": "500,1000,2500,5000"},
}
VARIANTS = ["arteq", "arteq_nc", "arteq_so3", "pointnet2", "pointnet2_so3", "points_1000", "points_2500",
            "points_5000"]  # fmt: skip


@pytest.mark.parametrize("name", sorted(SWEEPS))
def test_ablation_sweep_params(name):
    cfg = _compose([f"+experiment={name}", "+sweep=quick"])
    assert cfg.task_name == name
    assert OmegaConf.to_container(cfg.hydra.sweeper.params) == SWEEPS[name]
    assert cfg.trainer.max_epochs == 2 and cfg.data.train_size == 96  # the quick preset applied


def test_ablation_all_lists_every_variant():
    cfg = _compose(["+experiment=ablation_all"])
    assert cfg.hydra.sweeper.params["+sweep/variant"].split(",") == VARIANTS
    files = {p.stem for p in (Path(CONF) / "sweep" / "variant").glob("*.yaml")}
    # points_500: for paper-scale runs, whose own count is 5000; arteq_aligned: the aligned parent for
    # model=arteq_local sweeps (the default network's own form, so ablation_all does not list it)
    assert files - set(VARIANTS) == {"points_500", "arteq_aligned"}


def _tiny_module(cfg):
    from arteq.train import build_module

    return build_module(cfg, stage=cfg.stage)


@pytest.mark.parametrize("variant", VARIANTS)
def test_variant_composes_and_builds(variant, tiny_pn2_overrides):
    pn2 = tiny_pn2_overrides if variant.startswith("pointnet2") else ()
    cfg = _compose(["+experiment=ablation_all", f"+sweep/variant={variant}", *pn2])
    assert cfg.variant == variant
    expect = {"arteq_nc": ("arteq", False, "none", 500), "arteq_so3": ("arteq", "aligned", "so3", 500),
              "pointnet2": ("pointnet2", None, "none", 500), "pointnet2_so3": ("pointnet2", None, "so3", 500),
              "points_2500": ("arteq", "aligned", "none", 2500)}.get(variant)  # fmt: skip
    if expect:
        arch, pc, aug, pts = expect
        assert cfg.model.net.get("arch", "arteq") == arch
        assert cfg.model.net.get("parent_conditioning") == pc
        assert (cfg.data.augment, cfg.data.num_points) == (aug, pts)
    if variant in ("arteq", "arteq_nc", "pointnet2"):  # one module per architecture / head variant
        module = _tiny_module(cfg)
        assert module.net.num_parts == 22
        if variant == "arteq_nc":
            assert not module.net.pose_head.parent_conditioning


def test_baseline_experiments(tiny_pn2_overrides):
    from arteq.models.baselines import PointNet2Regressor

    for name, aug in (("baseline_pointnet2", "none"), ("baseline_pointnet2_aug", "so3")):
        cfg = _compose([f"+experiment={name}", *tiny_pn2_overrides])
        assert cfg.task_name == name and cfg.data.augment == aug
        assert isinstance(_tiny_module(cfg).net, PointNet2Regressor)


@pytest.mark.slow
def test_tiny_multirun_unique_dirs_and_report(tmp_path, tiny_micro_overrides):
    env = dict(os.environ, ARTEQ_OUTPUT_ROOT=str(tmp_path / "out"))
    # the tiny presets with the micro network; fewer clouds and one stage-1 epoch: 6 jobs run here
    tiny = [*tiny_micro_overrides, "data.train_size=4", "data.val_size=2", "data.test_size=2",
            "stage1.epochs=1"]  # fmt: skip
    env.pop("WANDB_API_KEY", None)
    env.update(WANDB_MODE="offline", WANDB_SILENT="true", NETRC=str(tmp_path / "no-netrc"))
    cmd = [sys.executable, "-m", "arteq.train", "-m", "+experiment=ablation_nc", *tiny]
    for logger in ("wandb", "csv"):  # re-running must not clobber the first sweep
        subprocess.run(cmd + [f"logger={logger}"], check=True, env=env, capture_output=True, timeout=900)
    sweeps = sorted((tmp_path / "out" / "multirun" / "ablation_nc").iterdir())
    assert len(sweeps) == 2
    jobs = [p.parent for p in (tmp_path / "out").rglob("metrics.json")]
    assert len(jobs) == 6 and len(set(jobs)) == 6
    # wandb (offline): one run per job and stage (stage 1 is trained inside each stage-2 job)
    wandb_runs = sorted(p.name for p in sweeps[0].rglob("offline-run-*"))
    assert len(wandb_runs) == 6 and len(set(wandb_runs)) == 6
    for job in ("0", "1", "2"):
        assert len(list((sweeps[0] / job / "wandb").glob("offline-run-*"))) == 1
        assert len(list((sweeps[0] / job / "stage1" / "wandb").glob("offline-run-*"))) == 1
    from arteq.report import find_runs, write_report

    runs = find_runs([tmp_path / "out"])
    assert sorted(r.method for r in runs) == [
        "ArtEq",
        "ArtEq",
        "ArtEq invariant-parent",
        "ArtEq invariant-parent",
        "ArtEq nc",
        "ArtEq nc",
    ]
    text = write_report(runs, tmp_path / "report", plots=False).read_text()
    assert "| ArtEq nc | 200 |" in text


def test_backbone_radii_follow_point_density_and_the_local_network_keeps_them_metric():
    from arteq.config import radii_for_points

    paper = [0.08, 0.113, 0.16, 0.16]
    for n in (500, 1000, 2500, 5000):
        radii = _compose([f"data.num_points={n}"]).model.net.backbone.radii
        assert list(radii) == radii_for_points(paper, n)
        # same expected ball population (points per area ~ N) as the paper's radii at 5000 points
        assert abs(radii[0] ** 2 * n - 0.08**2 * 5000) < 0.01 * 0.08**2 * 5000
        # model=arteq_local: part-sized balls in metres at every point count, with neighbour means
        local = _compose([f"data.num_points={n}", "model=arteq_local"]).model.net.backbone
        assert list(local.radii) == paper and local.normalize
    assert list(_compose(["data.num_points=5000"]).model.net.backbone.radii) == paper
    with pytest.raises(ValueError, match="point counts"):
        radii_for_points(paper, 0)


def test_aligned_variant_sets_the_part_local_networks_parent_row():
    cfg = _compose(["+experiment=ablation_all", "+sweep/variant=arteq_aligned", "model=arteq_local"])
    assert cfg.variant == "arteq_aligned" and cfg.model.net.parent_conditioning == "aligned"
    assert cfg.model.net.backbone.normalize  # still the part-local network
