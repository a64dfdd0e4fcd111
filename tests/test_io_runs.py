"""arteq.io.runs and arteq.results: run folders, metrics files, method names; the committed
experiments/ results still read back."""

import json
from pathlib import Path

import pytest

from arteq.io import runs
from arteq.results import TEST_SPLITS, method_name, metric_values, metrics_markdown, summary_rows

ROOT = Path(__file__).resolve().parents[1]


def test_committed_default_run_reads_back_and_its_table_is_reproduced():
    run = runs.load_run(ROOT / "experiments" / "cpu_default")
    # made before the graded OOD sets and the invariant parent conditioning existed
    assert run.method == "ArtEq" and set(TEST_SPLITS[:2]) <= set(run.metrics)
    text = metrics_markdown(run.summary["task_name"], summary_rows(run.summary, "ArtEq"))
    assert text + "\n" == (ROOT / "experiments" / "cpu_default" / "metrics.md").read_text()


def test_write_read_metrics_atomic(tmp_path):
    summary = {"task_name": "t", "metrics": {"test_id": {"v2v_cm": 1.0}, "test_ood": {"v2v_cm": 2.0}}}
    md = runs.write_metrics(tmp_path / "run", summary, "# t")
    assert md.read_text() == "# t\n"
    assert runs.read_metrics(tmp_path / "run") == summary
    assert json.loads((tmp_path / "run" / "metrics.json").read_text()) == summary
    assert not list((tmp_path / "run").glob(".*.tmp"))


def test_find_checkpoint_and_config(tmp_path):
    run = tmp_path / "run"
    with pytest.raises(FileNotFoundError, match="no checkpoints"):
        runs.find_checkpoint(run)
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "last.ckpt").write_bytes(b"")
    assert runs.find_checkpoint(run) == run / "checkpoints" / "last.ckpt"
    (run / "checkpoints" / "epoch03.ckpt").write_bytes(b"")
    (run / "checkpoints" / "epoch07.ckpt").write_bytes(b"")
    assert runs.find_checkpoint(run).name == "epoch07.ckpt"
    assert runs.find_checkpoint(run, "last").name == "last.ckpt"
    assert runs.run_dir_of(runs.find_checkpoint(run)) == run
    assert runs.newest_last_checkpoints(tmp_path) == [run / "checkpoints" / "last.ckpt"]
    with pytest.raises(FileNotFoundError, match="config.yaml"):
        runs.read_config(run)
    (run / ".hydra").mkdir()
    cfg = {
        "data": {"_target_": "x", "num_points": 5, "body_model": 1},
        "body_model": {"_target_": "y", "name": "toy"},
    }
    (run / ".hydra" / "config.yaml").write_text(json.dumps(cfg))  # JSON is YAML
    read = runs.read_config(run)
    assert runs.data_kwargs(read) == {"num_points": 5} and runs.body_config(read) == {"name": "toy"}


def test_method_names_from_config():
    assert method_name({}) == "ArtEq"
    assert method_name({"model": {"net": {"parent_conditioning": False}}}) == "ArtEq nc"
    local = {"model": {"net": {"parent_conditioning": "invariant", "backbone": {"normalize": True}}}}
    assert method_name(local) == "ArtEq part-local invariant-parent"
    assert method_name({"model": {"net": {"arch": "pointnet2"}}, "data": {"augment": "so3"}}) == (
        "PointNet++ + SO(3) aug"
    )


def test_metric_values_from_metric_object():
    import torch

    from arteq.training.metrics import BodyFitMetrics

    m = BodyFitMetrics()
    v = torch.zeros(2, 5, 3)
    r = torch.eye(3).expand(2, 22, 3, 3)
    m.update(
        v, v + 0.01, torch.zeros(2, 22, 3), torch.zeros(2, 22, 3), r, r, torch.zeros(2, 4), torch.zeros(2, 4)
    )
    out = metric_values(m.compute())
    assert out["v2v_cm"] == pytest.approx(100 * 0.01 * 3**0.5) and out["part_acc"] == 100.0
    assert len(out["rot_err_deg_per_part"]) == 22 and out["rot_err_deg_per_part"]["pelvis"] == 0.0
