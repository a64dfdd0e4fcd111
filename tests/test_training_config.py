"""Optimisers, schedules and the trainer come from the config: Hydra partials (and the earlier ``{name: ...}``
form, which the checkpoints trained before the partials hold), output folders and epochs from the YAML."""

from __future__ import annotations

from pathlib import Path

import lightning as L
import pytest
import torch

from arteq.io.runs import checkpoint_dir
from arteq.training import optim

COSINE = {"name": "cosine", "warmup_steps": 3, "min_lr_ratio": 0.05}
COSINE_PARTIAL = {"_target_": "arteq.training.optim.warmup_cosine", "_partial_": True, "warmup_steps": 3,
                  "min_lr_ratio": 0.05, "interval": "step"}  # fmt: skip


def _lrs(opt_cfg, sched_cfg, steps: int = 12) -> tuple[type, list[float]]:
    params = [torch.nn.Parameter(torch.zeros(2))]
    opt = optim.build_optimizer(opt_cfg, params)
    sched = optim.build_scheduler(sched_cfg, opt, total_steps=10)
    out = []
    for _ in range(steps):
        out.append(opt.param_groups[0]["lr"])
        opt.step()
        if sched is not None:
            sched["scheduler"].step()
    return type(opt), out


@pytest.mark.parametrize(
    "old, new",
    [
        (({"name": "adam", "lr": 3e-3}, COSINE),
         ({"_target_": "torch.optim.Adam", "_partial_": True, "lr": 3e-3}, COSINE_PARTIAL)),
        (({"name": "AdamW", "lr": 1e-3, "weight_decay": 0.01}, {"name": "step", "step_size": 4, "gamma": 0.5}
          ),
         ({"_target_": "torch.optim.AdamW", "_partial_": True, "lr": 1e-3, "weight_decay": 0.01},
          {"_target_": "torch.optim.lr_scheduler.StepLR", "_partial_": True, "step_size": 4, "gamma": 0.5})),
        (({"name": "adam", "lr": 1e-4}, {"name": "none"}),
         ({"_target_": "torch.optim.Adam", "_partial_": True, "lr": 1e-4}, None)),
    ],
)  # fmt: skip
def test_name_form_and_partial_build_the_same_optimizer_and_rates(old, new):
    cls, old_lrs = _lrs(*old)
    assert cls is type(optim.build_optimizer(new[0], [torch.nn.Parameter(torch.zeros(1))]))
    assert _lrs(*new) == (cls, old_lrs)
    assert optim.optimizer_config(old[0])["_target_"] == new[0]["_target_"]


def test_warmup_cosine_is_the_earlier_schedule():
    _, lrs = _lrs({"name": "adam", "lr": 1.0}, COSINE, steps=12)
    assert lrs[:3] == pytest.approx([1 / 3, 2 / 3, 1.0])  # linear warm-up
    assert lrs[3] == pytest.approx(1.0) and lrs[10] == pytest.approx(0.05) and lrs[11] == pytest.approx(0.05)
    assert all(isinstance(x, float) for x in lrs)  # plain floats: weights_only checkpoints
    assert optim.build_scheduler(COSINE, torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))]), 10)[
        "interval"
    ] == "step"  # fmt: skip


def test_total_steps_is_asked_only_by_schedules_that_take_it():
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=1.0)

    def never() -> int:
        raise AssertionError("total steps asked for")

    step = optim.build_scheduler({"name": "step", "step_size": 1}, opt, never)
    assert step["interval"] == "epoch" and isinstance(step["scheduler"], torch.optim.lr_scheduler.StepLR)
    assert optim.build_scheduler({"name": "none"}, opt, never) is None
    assert optim.build_scheduler(None, opt, never) is None


def test_shipped_checkpoint_holds_the_name_form_and_builds():
    from arteq.pretrained import resolve_checkpoint

    hp = torch.load(resolve_checkpoint("anny22"), map_location="cpu", weights_only=True)["hyper_parameters"]
    assert hp["optimizer"]["name"] == "adam" and hp["scheduler"]["name"] == "cosine"
    opt = optim.build_optimizer(hp["optimizer"], [torch.nn.Parameter(torch.zeros(1))])
    assert isinstance(opt, torch.optim.Adam) and opt.param_groups[0]["lr"] == hp["optimizer"]["lr"]
    sched = optim.build_scheduler(hp["scheduler"], opt, 100)
    assert isinstance(sched["scheduler"], torch.optim.lr_scheduler.LambdaLR)


@pytest.mark.parametrize(
    "overrides, opt, sched",
    [
        ([], {"name": "adam", "lr": 3e-3}, {"name": "cosine", "warmup_steps": 20, "min_lr_ratio": 0.05}),
        (["model=arteq_local"], {"name": "adam", "lr": 3e-3},
         {"name": "cosine", "warmup_steps": 20, "min_lr_ratio": 0.05}),
        (["model=pointnet2"], {"name": "adam", "lr": 1e-3},
         {"name": "cosine", "warmup_steps": 20, "min_lr_ratio": 0.05}),
        (["+experiment=paper"], {"name": "adam", "lr": 1e-4}, {"name": "none"}),
    ],
)  # fmt: skip
def test_configs_write_partials_that_build_what_their_name_form_built(overrides, opt, sched):
    """conf/model/ and conf/scale/paper.yaml write the partial form; each is the partial the name form they
    held before translates to (``opt``, ``sched``), so runs build the same optimiser and schedule."""
    from omegaconf import OmegaConf

    from conftest import compose_config

    model = compose_config(["paths.output_dir=/tmp/unused", *overrides], hydra_config=False).model
    new_opt = OmegaConf.to_container(model.optimizer, resolve=True)
    new_sched = None if model.scheduler is None else OmegaConf.to_container(model.scheduler, resolve=True)
    assert "name" not in new_opt and new_opt["_partial_"] is True
    assert new_sched is None or ("name" not in new_sched and new_sched["_partial_"] is True)
    assert optim.optimizer_config(new_opt) == optim.optimizer_config(opt)
    assert optim.scheduler_config(new_sched) == optim.scheduler_config(sched)
    assert _lrs(new_opt, new_sched) == _lrs(opt, sched)


def test_stage_config_sets_folders_and_epochs_in_the_yaml_only(tmp_path, tiny_config):
    from arteq.training.trainer import build_trainer, stage_config

    cfg = tiny_config(f"paths.output_dir={tmp_path / 'run'}", "logger=tensorboard")
    inner = stage_config(cfg, tmp_path / "run" / "stage1", max_epochs=3, resuming=True)
    assert cfg.paths.output_dir == str(tmp_path / "run") and cfg.trainer.max_epochs == 1  # not changed
    trainer = build_trainer(inner)
    stage_dir = tmp_path / "run" / "stage1"
    assert trainer.max_epochs == 3 and Path(trainer.default_root_dir) == stage_dir
    ckpts = [cb for cb in trainer.callbacks if isinstance(cb, L.pytorch.callbacks.ModelCheckpoint)]
    assert len(ckpts) == 3 and {Path(cb.dirpath) for cb in ckpts} == {checkpoint_dir(stage_dir)}
    assert {Path(lg.save_dir) for lg in trainer.loggers} == {stage_dir}
    csv_logger = next(lg for lg in trainer.loggers if isinstance(lg, L.pytorch.loggers.CSVLogger))
    assert str(csv_logger.version).startswith("resumed-")  # beside the earlier log, not over it
    outer = build_trainer(stage_config(cfg, tmp_path / "run"))
    assert outer.max_epochs == 1 and Path(outer.default_root_dir) == tmp_path / "run"


@pytest.mark.slow
def test_name_form_checkpoint_resumes_under_a_partial_config(tmp_path, tiny_config):
    """A run trained with ``{name: adam}`` / ``{name: cosine}`` (what conf/model said before the partials, and
    every checkpoint trained before them) resumes under the shipped config, whose optimizer and schedule are
    partials: states restored, steps counted on."""
    from arteq.train import train

    base = ["+experiment=stage1", "test=false", f"paths.output_root={tmp_path}"]
    name_form = ["~model.optimizer", "+model.optimizer={name:adam,lr:0.003}", "~model.scheduler",
                 "+model.scheduler={name:cosine,warmup_steps:20,min_lr_ratio:0.05}"]  # fmt: skip
    first = train(tiny_config(*base, *name_form, f"paths.output_dir={tmp_path / 'a'}"))
    hp = torch.load(first["last_ckpt"], map_location="cpu", weights_only=True)["hyper_parameters"]
    assert hp["optimizer"] == {"name": "adam", "lr": 0.003} and hp["scheduler"]["name"] == "cosine"
    cfg = tiny_config(*base, "trainer.max_epochs=2", f"ckpt_path={first['last_ckpt']}",
                      f"paths.output_dir={tmp_path / 'b'}")  # fmt: skip
    assert cfg.model.optimizer._target_ == "torch.optim.Adam"  # the shipped config: partials
    second = train(cfg)
    state = torch.load(second["last_ckpt"], map_location="cpu", weights_only=True)
    assert state["global_step"] == 4  # 2 steps per epoch (limit_train_batches=2), 2 epochs
    assert state["lr_schedulers"][0]["last_epoch"] == 4
    assert int(next(iter(state["optimizer_states"][0]["state"].values()))["step"]) == 4
    assert state["hyper_parameters"]["optimizer"]["_target_"] == "torch.optim.Adam"


def test_older_stage1_checkpoints_match_configs_that_keep_their_behaviour():
    # A stage-1 checkpoint written before an option existed holds no value for it; it must still match a
    # config whose value is what the network / data did before, and not one that changes it.
    from arteq.training.plan import ADDED_DEFAULTS, _data_signature, _with_added_defaults

    old = {"backbone": {"radii": [0.1]}, "pose_head": {"dim": 8}}
    want = {"backbone": {"radii": [0.1], "normalize": False}, "pose_head": {"dim": 8, "geometry": False,
                                                                            "logit_eps": None},
            "sides": "learned", "side_scale": 0.02}  # fmt: skip
    assert _with_added_defaults(old, ADDED_DEFAULTS["net"]) == want
    assert _with_added_defaults(old, ADDED_DEFAULTS["net"]) != {**want, "sides": "torso"}
    want["pose_head"]["geometry"] = True
    assert _with_added_defaults(old, ADDED_DEFAULTS["net"]) != want
    assert _data_signature({"num_points": 500}) == _data_signature(
        {"num_points": 500, "shape_prior": "normal"}
    )
    assert _data_signature({"num_points": 500}) != _data_signature(
        {"num_points": 500, "shape_prior": "allages"}
    )
