"""arteq.report on hand-made run folders: table values, newest-run rule, CSV, plots, bad input."""

import csv
import json
import os

import pytest

from arteq.body.skeleton import JOINT_NAMES
from arteq.report import build_tables, find_runs, load_run, main, write_report


def _metrics(acc, v2v, mpjpe):
    per = {j: float(i) for i, j in enumerate(JOINT_NAMES)}
    return {
        "part_acc": acc,
        "v2v_cm": v2v,
        "mpjpe_cm": mpjpe,
        "rot_err_deg": 10.5,
        "rot_err_deg_per_part": per,
    }


def make_run(root, name, arch="arteq", pc=True, augment="none", points=500, acc=(90.0, 80.0),
             v2v=(2.0, 5.0), params=1000, mtime=None, curves=True, floor=None):  # fmt: skip
    d = root / name
    d.mkdir(parents=True)
    net = {"arch": arch} if arch != "arteq" else {"parent_conditioning": pc}
    cfg = {"model": {"net": net}, "data": {"augment": augment, "num_points": points}}
    summary = {
        "metrics": {s: _metrics(acc[i], v2v[i], v2v[i] * 0.8) for i, s in enumerate(("test_id", "test_ood"))},
        "parameters": params,
        "train_seconds": 12.0,
        "config": cfg,
    }  # fmt: skip
    if floor:
        summary["mean_pose_baseline"] = floor
    (d / "metrics.json").write_text(json.dumps(summary))
    if curves:
        (d / "csv").mkdir()
        with (d / "csv" / "metrics.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["epoch", "step", "train/loss", "val/v2v_cm", "val/mpjpe_cm", "val/part_acc"])
            w.writerow([0, 5, 3.0, "", "", ""])
            w.writerow([0, 9, "", 9.0, 7.0, 40.0])
            w.writerow([1, 19, "", 6.0, 5.0, 60.0])
    if mtime is not None:
        os.utime(d / "metrics.json", (mtime, mtime))
    return d


@pytest.fixture()
def runs_root(tmp_path):
    root = tmp_path / "runs"
    floor = {"test_id": {"v2v_cm": 20.0, "mpjpe_cm": 15.0}, "test_ood": {"v2v_cm": 40.0, "mpjpe_cm": 30.0}}
    make_run(root, "old_arteq", acc=(10.0, 10.0), mtime=1_000_000)  # superseded by "arteq"
    make_run(root, "sweep/0_arteq", acc=(91.0, 81.0), v2v=(2.0, 5.0), floor=floor)
    make_run(root, "sweep/1_arteq_so3", augment="so3", acc=(89.0, 88.0), v2v=(2.5, 3.0))
    make_run(root, "sweep/2_nc", pc=False, acc=(85.0, 70.0), v2v=(3.0, 7.0))
    make_run(root, "sweep/3_pn2", arch="pointnet2", acc=(70.0, 20.0), v2v=(4.0, 30.0), params=5000)
    make_run(root, "sweep/4_pts1000", points=1000, acc=(93.0, 84.0), v2v=(1.5, 4.0))
    (root / "sweep" / "0_arteq" / "stage1").mkdir()  # a stage-1 sub-run: no metrics.json, not a run
    fit = root / "fit"
    fit.mkdir()
    (fit / "metrics.json").write_text(json.dumps({
        "method": "Optimisation (Chamfer)", "parameters": 0,
        "metrics": {"test_id": _metrics(50.0, 10.0, 8.0), "test_ood": _metrics(20.0, 30.0, 25.0)},
        "fit": {"test_id": {"seconds_per_sample": 2.0}, "test_ood": {"seconds_per_sample": 4.0}},
        "config": {"data": {"num_points": 1000}},
    }))  # fmt: skip
    return root


def _table(tables, name):
    return next(t for t in tables if t.name == name)


def test_tables_from_hand_made_runs(runs_root):
    runs = find_runs([runs_root])
    assert len(runs) == 7
    tables = build_tables(runs)
    t1 = {(r[0], r[1]): r[2:] for r in _table(tables, "tab1_part_accuracy").rows}
    assert t1[("ArtEq", "500")] == ["91.00", "81.00", "89.00", "88.00"]  # newest plain run + the so3 run
    assert t1[("ArtEq nc", "500")] == ["85.00", "70.00", "–", "–"]
    assert t1[("PointNet++", "500")] == ["70.00", "20.00", "–", "–"]
    assert t1[("Optimisation (Chamfer)", "1000")] == ["50.00", "20.00", "–", "–"]
    t2 = {(r[0], r[1]): r[2:] for r in _table(tables, "tab2_v2v_mpjpe").rows}
    assert t2[("ArtEq + SO(3) aug", "500")] == ["2.50", "3.00", "2.00", "2.40"]
    assert t2[("PointNet++", "500")] == ["4.00", "30.00", "3.20", "24.00"]
    assert t2[("mean pose (floor)", "–")] == ["20.00", "40.00", "15.00", "30.00"]
    s1 = {r[0]: r[1:] for r in _table(tables, "tabS1_points").rows}
    assert list(s1) == ["500", "1000"]  # only ArtEq, parent conditioning on, no augmentation
    assert s1["1000"][:2] == ["93.00", "84.00"]
    t3 = {(r[0], r[1]): r[2:] for r in _table(tables, "tab3_params_time").rows}
    assert t3[("PointNet++", "500")][0] == "5,000"
    assert t3[("Optimisation (Chamfer)", "1000")][1] == "3000.0"  # mean of 2 s and 4 s per sample


def test_write_report_outputs(runs_root, tmp_path):
    out = tmp_path / "report"
    path = write_report(find_runs([runs_root]), out, notes="hardware: test")
    text = path.read_text()
    assert "Tab. 1" in text and "Tab. S1" in text and "hardware: test" in text
    for name in ("tab1_part_accuracy", "tab2_v2v_mpjpe", "tabS1_points", "tab3_params_time"):
        rows = list(csv.reader((out / f"{name}.csv").open()))
        assert len(rows) >= 2
    assert len(list(csv.reader((out / "runs.csv").open()))) == 8
    for png in ("convergence.png", "per_part_rot_err.png"):
        assert (out / png).read_bytes()[:4] == b"\x89PNG"


def test_cli(runs_root, tmp_path, capsys):
    main([str(runs_root / "sweep"), "--out", str(tmp_path / "r"), "--no-plots"])
    assert "PointNet++" in capsys.readouterr().out
    assert not (tmp_path / "r" / "convergence.png").exists()


def test_curves_keep_only_validation_rows(runs_root):
    run = load_run(runs_root / "sweep" / "0_arteq")
    assert [c["val/v2v_cm"] for c in run.curves] == [9.0, 6.0]


def test_bad_input(tmp_path):
    with pytest.raises(FileNotFoundError, match="no such run"):
        find_runs([tmp_path / "missing"])
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "metrics.json").write_text("{not json")
    with pytest.raises(ValueError, match=r"bad/metrics.json: not valid JSON"):
        find_runs([tmp_path])
    (bad / "metrics.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match="'metrics' mapping"):
        load_run(bad)
    with pytest.raises(ValueError, match="no runs"):
        write_report([], tmp_path / "out")


def test_tab2_says_why_a_network_is_above_the_floor_on_id(tmp_path):
    floor = {"test_id": {"v2v_cm": 19.0, "mpjpe_cm": 13.0}, "test_ood": {"v2v_cm": 71.0, "mpjpe_cm": 58.0}}
    make_run(tmp_path, "a", acc=(37.9, 28.3), v2v=(20.9, 44.0), floor=floor)
    make_run(tmp_path, "b", arch="pointnet2", acc=(48.1, 11.8), v2v=(24.1, 73.9))
    make_run(tmp_path, "c", pc=False, acc=(60.0, 30.0), v2v=(12.0, 40.0))  # below the floor: not named
    tab2 = _table(build_tables(find_runs([tmp_path])), "tab2_v2v_mpjpe")
    assert tab2.note.startswith("ID V2V above the mean-pose floor's 19.00 cm: ArtEq")
    assert "PointNet++ 24.10" in tab2.note and "nc" not in tab2.note
    assert "ground-truth part labels" in tab2.note and "label 37.90-48.10 % of the ID points" in tab2.note
    assert "PointNet++ 73.90 against the floor's 71.00 cm" in tab2.note
    assert tab2.markdown().endswith(tab2.note)
    # no note when every network is below the floor on ID
    make_run(tmp_path / "low", "a", v2v=(2.0, 5.0), floor=floor)
    assert _table(build_tables(find_runs([tmp_path / "low"])), "tab2_v2v_mpjpe").note == ""


def test_points_table_keeps_the_network_trained_at_several_counts(tmp_path):
    # a sweep of the part-local network (parent-conditioning rows at 500 points only, its own network also
    # at 1000) beside the default network at 500: Tab. S1 is the network with two point counts
    root = tmp_path / "runs"
    local = {"backbone": {"normalize": True}}
    for name, pc, pts, acc in (("l_inv", "invariant", 500, 40.0), ("l_al", "aligned", 500, 46.0),
                               ("l_1000", "invariant", 1000, 44.0), ("old", True, 500, 38.0)):  # fmt: skip
        d = make_run(root, name, pc=pc, points=pts, acc=(acc, acc / 2))
        if name.startswith("l_"):
            m = json.loads((d / "metrics.json").read_text())
            m["config"]["model"]["net"].update(local)
            (d / "metrics.json").write_text(json.dumps(m))
    s1 = _table(build_tables(find_runs([root])), "tabS1_points")
    assert s1.title == "Tab. S1: ArtEq part-local invariant-parent by number of input points"
    assert [r[:2] for r in s1.rows] == [["500", "40.00"], ["1000", "44.00"]]
