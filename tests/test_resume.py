"""Kill -9 mid-epoch and resume: at most N steps lost, and the run continues with exactly the samples
and weights an uninterrupted run has (CPU, tiny configuration, one dataloader worker)."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir

from conftest import compose_config, subprocess_env

ROOT = Path(__file__).resolve().parents[1]
EVERY = 3  # step checkpoint interval
#: Beyond the tiny presets (with the micro network): 12 steps per epoch, all trained, a checkpoint every
#: EVERY steps, the default config's loader (a worker process, prefetching), every sample recorded.
RUN = [
    "+experiment=stage1", "data.num_points=128", "data.train_size=24", "data.val_size=2", "data.test_size=2",
    "data.num_workers=1", "trainer.max_epochs=2", "~trainer.limit_train_batches",
    "trainer.log_every_n_steps=1", f"callbacks.step_checkpoint.every_n_train_steps={EVERY}", "test=false",
    "+callbacks.record._target_=helpers.record.RecordBatches",
]  # fmt: skip


def _overrides(tmp_path: Path, tiny: tuple[str, ...]) -> list[str]:
    return [*tiny, *RUN, f"paths.output_root={tmp_path / 'out'}", f"data.cache_root={tmp_path / 'cache'}"]


def _cfg(tmp_path: Path, tiny: tuple[str, ...], *extra: str):
    return compose_config([*_overrides(tmp_path, tiny), *extra], hydra_config=False)


def _step(path: Path) -> int:
    return int(torch.load(path, map_location="cpu", weights_only=True)["global_step"])


def _train_batches(record_file: Path) -> list[tuple[int, torch.Tensor]]:
    return torch.load(record_file, weights_only=False)["train"]


def test_sigkill_mid_epoch_then_resume_auto(tmp_path, tiny_micro_overrides):
    from arteq.train import train

    # Same thread count as the subprocess (subprocess_env: 1 thread): float sums in a different thread
    # split round differently, and the weights are compared bit for bit.
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        _killed_and_resumed_run_matches_uninterrupted(tmp_path, tiny_micro_overrides, train)
    finally:
        torch.set_num_threads(threads)


def _killed_and_resumed_run_matches_uninterrupted(tmp_path, tiny, train):
    # reference: the uninterrupted run
    ref = train(_cfg(tmp_path, tiny, f"paths.output_dir={tmp_path / 'ref'}"))
    ref_batches = _train_batches(tmp_path / "ref" / "record_rank0.pt")
    assert len(ref_batches) == 24

    # the same run, killed with SIGKILL in the middle of epoch 1 right after a step checkpoint
    cmd = [sys.executable, "-m", "arteq.train", *_overrides(tmp_path, tiny)]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env=subprocess_env(), stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    killed_after = None
    deadline = time.time() + 300
    try:
        while time.time() < deadline and proc.poll() is None:
            ckpts = list((tmp_path / "out" / "stage1").glob("*/checkpoints/step*.ckpt"))
            steps = [int(p.stem[4:]) for p in ckpts]
            if steps and max(steps) >= 15:  # step 15 = 3 batches into epoch 1 (12 per epoch)
                os.kill(proc.pid, signal.SIGKILL)
                killed_after = max(steps)
                break
            time.sleep(0.02)
    finally:
        if proc.poll() is None and killed_after is None:
            proc.kill()
        proc.wait()
    assert killed_after is not None, proc.stderr.read().decode()[-3000:]
    assert proc.returncode == -signal.SIGKILL
    (run,) = (tmp_path / "out" / "stage1").glob("*/")
    rows = list(csv.DictReader(next(run.glob("csv/metrics.csv")).open()))
    steps_done = max(int(r["step"]) for r in rows if r.get("train/loss")) + 1
    assert steps_done < 24, "the run finished before the kill: nothing was tested"
    # a checkpoint cut short by a kill must not be picked: a garbage file with a higher step number
    (run / "checkpoints" / "step9999999.ckpt").write_bytes(b"PK\x03\x04 truncated")

    resumed = train(_cfg(tmp_path, tiny, "resume=auto", f"paths.output_dir={tmp_path / 'fresh'}"))
    assert resumed["resumed_run"] == str(run)
    start = _step(Path(resumed["resumed_from"]))
    assert start >= steps_done - EVERY, (start, steps_done)  # at most N steps lost
    assert 12 < start < 24  # mid-epoch 1
    assert _step(run / "checkpoints" / "last.ckpt") == 24

    # the resumed segment saw exactly the samples the uninterrupted run saw from that step on
    tail = _train_batches(run / "record_rank0.pt")
    assert len(tail) == 24 - start
    for (e_ref, b_ref), (e, b) in zip(ref_batches[start:], tail):
        assert e_ref == e and torch.equal(b_ref, b)
    # ... and ends with the same weights (same samples, same optimizer state, deterministic CPU)
    w_ref = torch.load(ref["last_ckpt"], weights_only=True)["state_dict"]
    w = torch.load(run / "checkpoints" / "last.ckpt", weights_only=True)["state_dict"]
    for k in w_ref:
        torch.testing.assert_close(
            w[k], w_ref[k], rtol=0, atol=0, msg=lambda m, k=k: f"{k} (resumed from step {start}): {m}"
        )


def test_resume_auto_without_earlier_run_starts_fresh_and_explicit_folder_needs_a_checkpoint(
    tmp_path, tiny_micro_overrides
):
    from arteq.train import plan_run

    plan = plan_run(
        _cfg(tmp_path, tiny_micro_overrides, "resume=auto", f"paths.output_dir={tmp_path / 'new'}")
    )
    assert plan["resume"] == {} and plan["output_dir"] == str(tmp_path / "new")
    empty = tmp_path / "out" / "stage1" / "empty_run"
    empty.mkdir(parents=True)
    with pytest.raises(FileNotFoundError, match="no readable checkpoint"):
        plan_run(
            _cfg(tmp_path, tiny_micro_overrides, f"resume={empty}", f"paths.output_dir={tmp_path / 'new'}")
        )


def test_datamodule_resume_state_picks_the_next_sample(tmp_path):
    """The stream position saved in checkpoints: mid-epoch -> the rest of that epoch; end of epoch ->
    the next epoch from its start (also when the loader's worker prefetches before Lightning's set_epoch)."""
    from arteq.data import BodyScanDataModule
    from arteq.data.dataset import EpochSampler

    dm = BodyScanDataModule(
        body_model={"name": "toy"}, num_points=64, train_size=12, batch_size=2, cache=False
    )
    state = {"epoch": 1, "batches_done": 4, "batches_in_epoch": 6, "batch_size": 2, "world_size": 1}
    dm.load_state_dict(state)
    dm.train_dataloader()
    assert list(dm.train_sampler) == EpochSampler(12).epoch_indices(1)[8:]
    assert list(dm.train_sampler) == EpochSampler(12).epoch_indices(2)  # then on as usual
    dm.load_state_dict({**state, "batches_done": 6})  # saved at the end of epoch 1
    dm.train_dataloader()
    assert list(dm.train_sampler) == EpochSampler(12).epoch_indices(2)
    dm.load_state_dict(
        {**state, "batch_size": 3}
    )  # another batch size: restart the epoch, never skip wrongly
    dm.train_dataloader()
    assert list(dm.train_sampler) == EpochSampler(12).epoch_indices(1)


def test_stage2_run_killed_during_its_inner_stage1_resumes_stage1_first(tmp_path):
    from arteq.train import plan_run

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        cfg = compose("train", overrides=["+experiment=stage2", f"paths.output_root={tmp_path}",
                                          f"paths.output_dir={tmp_path / 'new'}", "resume=auto"])  # fmt: skip
    run = tmp_path / "stage2" / "2026-01-01_00-00-00_000000"
    (run / "stage1" / "checkpoints").mkdir(parents=True)
    torch.save({"global_step": 7}, run / "stage1" / "checkpoints" / "step0000007.ckpt")
    torch.save({"global_step": 5}, run / "stage1" / "checkpoints" / "epoch00.ckpt")
    plan = plan_run(cfg)
    assert plan["output_dir"] == str(run) and plan["stage1"]["how"] == "train"
    assert plan["resume"] == {"1": str(run / "stage1" / "checkpoints" / "step0000007.ckpt")}
    # once stage 2 has a checkpoint of its own, that one is resumed and stage 1 is not touched again
    (run / "checkpoints").mkdir()
    torch.save({"global_step": 3}, run / "checkpoints" / "step0000003.ckpt")
    plan = plan_run(cfg)
    assert plan["resume"] == {"2": str(run / "checkpoints" / "step0000003.ckpt")}
    assert plan["stage1"]["ckpt"] is None


def test_train_epoch_offset_draws_later_epochs_and_resumes_within_them():
    """``data.train_epoch_offset=k``: epoch e draws the clouds of epoch e + k of the unshifted stream (ones an
    earlier run of k epochs never drew); the saved epoch counters stay the run's own, so resuming keeps the
    shift; a negative offset is an error."""
    from arteq.data import BodyScanDataModule
    from arteq.data.dataset import EpochSampler

    assert EpochSampler(12, epoch_offset=3).epoch_indices(0) == EpochSampler(12).epoch_indices(3)
    assert min(EpochSampler(12, epoch_offset=3).epoch_indices(0)) >= 3 * 12  # past the first 3 epochs
    dm = BodyScanDataModule(
        body_model={"name": "toy"}, num_points=64, train_size=12, batch_size=2, cache=False,
        train_epoch_offset=3,
    )  # fmt: skip
    dm.train_dataloader()
    assert list(dm.train_sampler) == EpochSampler(12).epoch_indices(3)
    state = {"epoch": 1, "batches_done": 4, "batches_in_epoch": 6, "batch_size": 2, "world_size": 1}
    dm.load_state_dict(state)
    dm.train_dataloader()
    assert list(dm.train_sampler) == EpochSampler(12).epoch_indices(4)[8:]
    with pytest.raises(ValueError, match="train_epoch_offset"):
        BodyScanDataModule(body_model={"name": "toy"}, num_points=64, train_size=12, train_epoch_offset=-1)
