"""Collect runs into the paper's tables and plots: ``python -m arteq.report DIR... [--out DIR]``.

Every folder under the given ones that holds a ``metrics.json`` is a run (training runs of
``python -m arteq.train``, sweep jobs, and fitter evaluations of ``python -m arteq.optim_fit.evaluate``).
Its config comes from ``metrics.json["config"]`` (else ``.hydra/config.yaml``), its curves from
``csv/metrics.csv``. Method names come from the config: architecture (ArtEq / PointNet++), ``nc``
without parent conditioning, ``+ SO(3) aug`` / ``+ z aug`` with training augmentation; the point count
is a column. When several runs share a method and point count, the newest is used (the others are
listed in ``runs.csv``).

Outputs (Markdown ``report.md`` + one CSV per table, PNG plots):
- Tab. 1 part accuracy ID / OOD without and with augmentation,
- Tab. 2 V2V and MPJPE ID / OOD per method (plus the mean-pose floor),
- Tab. S1 ArtEq by point count,
- Tab. 3 parameters and inference time per method.
"""

from __future__ import annotations

import argparse
import csv
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from arteq.io.runs import Run, find_checkpoint, find_runs, latest_by, load_module, load_run
from arteq.results import PAPER_SPLITS, SPLIT_LABELS, TEST_SPLITS
from arteq.results import format_value as _fmt

#: The paper's two columns (ID, the hard OOD set) in Tab. 1, 2 and S1; Tab. G has every test set.
SPLITS = PAPER_SPLITS

__all__ = ["Table", "build_tables", "find_runs", "load_run", "main", "measure_inference_ms", "write_report"]

log = logging.getLogger("arteq.report")


def _md(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|---|" + "---:|" * (len(header) - 1)]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


@dataclass
class Table:
    name: str
    title: str
    header: list[str]
    rows: list[list[str]]
    note: str = ""  # a reading of the table, printed under it in report.md (not in the CSV)

    def markdown(self) -> str:
        text = f"### {self.title}\n\n" + _md(self.header, self.rows)
        return f"{text}\n\n{self.note}" if self.note else text

    def write_csv(self, out: Path) -> None:
        with (out / f"{self.name}.csv").open("w", newline="") as f:
            w = csv.writer(f)
            w.writerow(self.header)
            w.writerows(self.rows)


def _pts(r: Run) -> str:
    return str(r.num_points) if r.num_points is not None else "–"


def _below_floor_note(learned: list[Run], floor: dict) -> str:
    """Why a network's ID V2V can be worse than the mean-pose floor's, from the runs' own numbers ("" when
    none is): the floor is placed with the ground-truth parts, the networks with their predicted ones."""
    id_split, ood_split = SPLITS[:2]
    fid, food = floor.get(id_split, {}).get("v2v_cm"), floor.get(ood_split, {}).get("v2v_cm")
    worse = sorted(
        (r for r in learned if fid is not None and (r.metric(id_split, "v2v_cm") or -1) > fid),
        key=lambda r: (r.method, r.num_points or 0),
    )
    if not worse:
        return ""
    several_sizes = len({r.num_points for r in worse}) > 1
    label = {id(r): f"{r.method} ({_pts(r)} points)" if several_sizes else r.method for r in worse}
    ids = ", ".join(f"{label[id(r)]} {_fmt(r.metric(id_split, 'v2v_cm'))}" for r in worse)
    accs = [r.metric(id_split, "part_acc") for r in worse if r.metric(id_split, "part_acc") is not None]
    acc = f"{_fmt(min(accs))}-{_fmt(max(accs))} %" if len(accs) > 1 else f"{_fmt(accs[0])} %" if accs else "?"
    oods = ", ".join(f"{label[id(r)]} {_fmt(r.metric(ood_split, 'v2v_cm'))}" for r in worse)
    return (
        f"ID V2V above the mean-pose floor's {_fmt(fid)} cm: {ids}. The floor is the training set's mean "
        f"pose, close to the everyday ID motions ({_fmt(fid)} cm ID against {_fmt(food)} cm OOD), placed on "
        "the cloud with the ground-truth part labels (arteq/training/floor.py); a network places its body "
        f"with its own predicted parts, and these label {acc} of the ID points correctly (Tab. 1). On the "
        f"OOD poses, far from the mean: {oods} against the floor's {_fmt(food)} cm."
    )


def build_tables(runs: list[Run]) -> list[Table]:
    """Tab. 1, Tab. 2, Tab. S1, Tab. G (the graded OOD scale), Tab. 3 from the runs (newest run per method
    and point count)."""
    learned = [r for r in runs if r.arch != "fitter"]
    fitters = [r for r in runs if r.arch == "fitter"]
    tables = []

    # Tab. 1: part accuracy, without / with augmentation, per (base method, points).
    by = latest_by(learned, lambda r: (r.base_name, r.num_points, r.augment))
    keys = sorted({(k[0], k[1]) for k in by}, key=lambda k: (k[0], k[1] or 0))
    rows = []
    for name, n in keys:
        no, so3 = by.get((name, n, "none")), by.get((name, n, "so3"))
        cells = [
            _fmt(x.metric(s, "part_acc") if x else None) for x in (no, so3) for s in SPLITS
        ]  # fmt: skip
        rows.append([name, str(n) if n is not None else "–", *cells])
    for r in latest_by(fitters, lambda r: r.method).values():
        rows.append([r.method, _pts(r), _fmt(r.metric("test_id", "part_acc")),
                     _fmt(r.metric("test_ood", "part_acc")), "–", "–"])  # fmt: skip
    tables.append(
        Table("tab1_part_accuracy", "Tab. 1: part segmentation accuracy (%)",
              ["method", "points", "ID w/o aug", "OOD w/o aug", "ID w/ SO(3) aug", "OOD w/ SO(3) aug"], rows)
    )  # fmt: skip

    # Tab. 2: V2V / MPJPE per method.
    rows = []
    chosen = latest_by(runs, lambda r: (r.method, r.num_points))
    for (method, _n), r in sorted(chosen.items(), key=lambda kv: (kv[0][0], kv[0][1] or 0)):
        rows.append(
            [method, _pts(r)] + [_fmt(r.metric(s, m)) for m in ("v2v_cm", "mpjpe_cm") for s in SPLITS]
        )
    floors = [r for r in learned if r.summary.get("mean_pose_baseline")]
    note = ""
    if floors:
        f = latest_by(floors, lambda r: 0)[0].summary["mean_pose_baseline"]
        rows.append(["mean pose (floor)", "–"] + [_fmt(f.get(s, {}).get(m)) for m in ("v2v_cm", "mpjpe_cm")
                                                  for s in SPLITS])  # fmt: skip
        note = _below_floor_note([r for r in chosen.values() if r.arch != "fitter"], f)
    tables.append(
        Table("tab2_v2v_mpjpe", "Tab. 2: vertex and joint errors (cm, no alignment)",
              ["method", "points", "V2V ID", "V2V OOD", "MPJPE ID", "MPJPE OOD"], rows, note)
    )  # fmt: skip

    # Tab. S1: ArtEq (parent conditioning, no augmentation) by point count.
    # The networks trained at more than one point count (the ablation's own network; a sweep that mixes
    # networks, e.g. model=arteq_local's parent-conditioning rows at 500 points only, keeps them apart).
    base = [r for r in learned if r.arch == "arteq" and r.parent_conditioning and r.augment == "none"]
    counts: dict[str, set] = {}
    for r in base:
        counts.setdefault(r.base_name, set()).add(r.num_points)
    names = sorted(n for n, pts in counts.items() if len(pts) > 1) or sorted(counts)
    several = len(names) > 1
    rows = []
    for (name, _n), r in sorted(
        latest_by([r for r in base if r.base_name in names], lambda r: (r.base_name, r.num_points)).items(),
        key=lambda kv: (kv[0][0], kv[0][1] or 0),
    ):
        cells = [_fmt(r.metric(s, m)) for m in ("part_acc", "v2v_cm", "mpjpe_cm") for s in SPLITS]
        rows.append(([name] if several else []) + [_pts(r)] + cells)
    title = "Tab. S1: " + (names[0] if len(names) == 1 else "ArtEq") + " by number of input points"
    tables.append(
        Table("tabS1_points", title,
              (["method"] if several else []) + ["points", "part acc ID", "part acc OOD", "V2V ID", "V2V OOD",
                                                 "MPJPE ID", "MPJPE OOD"], rows)
    )  # fmt: skip

    # Tab. G: every test set (the graded OOD scale between ID and the hard set), for the runs that have it.
    graded = [s for s in TEST_SPLITS[2:] if any(s in r.metrics for r in chosen.values())]
    if graded:
        cols = [*SPLITS, *graded]
        rows = []
        for (method, _n), r in sorted(chosen.items(), key=lambda kv: (kv[0][0], kv[0][1] or 0)):
            if any(s in r.metrics for s in graded):
                rows.append(
                    [method, _pts(r)] + [_fmt(r.metric(s, m)) for m in ("part_acc", "v2v_cm") for s in cols]
                )
        tables.append(
            Table("tabG_graded_ood",
                  "Tab. G: every test set (part acc %, then V2V cm): ID, the hard OOD set, one / two OOD "
                  "limbs, OOD without self-contact",
                  ["method", "points"] + [f"{SPLIT_LABELS[s]} {m}" for m in ("acc", "V2V") for s in cols],
                  rows)
        )  # fmt: skip

    # Tab. 3: parameters and time.
    rows = []
    for (method, _n), r in sorted(chosen.items(), key=lambda kv: (kv[0][0], kv[0][1] or 0)):
        p = r.summary.get("parameters")
        train_s = r.summary.get("train_seconds")
        rows.append([method, _pts(r), f"{int(p):,}" if p is not None else "–", _fmt(r.inference_ms, 1),
                     _fmt(float(train_s), 0) if train_s is not None else "–"])  # fmt: skip
    tables.append(
        Table("tab3_params_time", "Tab. 3: parameters and time per sample",
              ["method", "points", "parameters", "inference ms / sample", "train s"], rows)
    )  # fmt: skip
    return tables


def measure_inference_ms(run: Run, repeats: int = 5, batch: int = 1) -> float | None:
    """Median forward time (ms per cloud, CPU, batch 1) of a run's checkpoint on a random cloud."""
    try:
        ckpt = find_checkpoint(run.path)
    except FileNotFoundError:
        return None
    import torch

    try:
        module = load_module(ckpt)
    except Exception as e:  # a checkpoint of an older code version: report without its time
        log.warning("%s: cannot load (%s: %s); no inference time", ckpt, type(e).__name__, e)
        return None
    pts = torch.randn(batch, run.num_points or 1000, 3) * 0.3
    times = []
    with torch.no_grad():
        module(pts)
        for _ in range(repeats):
            t0 = time.perf_counter()
            module(pts)
            times.append((time.perf_counter() - t0) * 1000 / batch)
    return sorted(times)[len(times) // 2]


def write_report(runs: list[Run], out: Path, plots: bool = True, qualitative: int = 0,
                 notes: str = "") -> Path:  # fmt: skip
    """Write ``report.md``, the table CSVs, ``runs.csv`` and (``plots``) the PNG figures into ``out``."""
    if not runs:
        raise ValueError("no runs found (no metrics.json under the given folders)")
    out.mkdir(parents=True, exist_ok=True)
    tables = build_tables(runs)
    for t in tables:
        t.write_csv(out)
    with (out / "runs.csv").open("w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["method", "points", "augment", "path", "parameters", "train_seconds"])
        for r in runs:
            w.writerow([r.method, _pts(r), r.augment, str(r.path), r.summary.get("parameters"),
                        r.summary.get("train_seconds")])  # fmt: skip
    md = ["# ArtEq reproduction: report", ""]
    if notes:
        md += [notes, ""]
    md += [f"{len(runs)} runs: " + ", ".join(f"`{r.path}`" for r in runs), ""]
    for t in tables:
        md += [t.markdown(), ""]
    md.append("Part accuracy in %, V2V / MPJPE in cm (22 body joints), no alignment; OOD = extreme poses "
              "with random root orientation. Newest run per method and point count.")  # fmt: skip
    if plots:
        from arteq.viz import report_plots

        figs = []
        if any(r.curves for r in runs):
            figs.append(report_plots.convergence_plot(runs, out / "convergence.png"))
        if any("rot_err_deg_per_part" in r.metrics.get("test_ood", {}) for r in runs):
            figs.append(report_plots.per_part_plot(runs, out / "per_part_rot_err.png"))
        if qualitative:
            q = report_plots.qualitative_figure(runs, out / "qualitative_ood.png", samples=qualitative)
            if q is not None:
                figs.append(q)
        md += [""] + [f"![{p.stem}]({p.name})" for p in figs]
    (out / "report.md").write_text("\n".join(md) + "\n")
    return out / "report.md"


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(prog="python -m arteq.report", description=__doc__.split("\n\n")[0])
    ap.add_argument("dirs", nargs="+", type=Path, help="run or sweep folders (searched recursively)")
    ap.add_argument("--out", type=Path, default=Path("experiments/report"))
    ap.add_argument("--no-plots", action="store_true")
    ap.add_argument("--qualitative", type=int, default=0, metavar="N", help="N OOD samples in a figure")
    ap.add_argument("--time", action="store_true", help="measure network forward time from checkpoints")
    ap.add_argument("--notes", default="", help="text put under the title (commands, hardware, times)")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(name)s: %(message)s")
    runs = find_runs(args.dirs)
    if args.time:
        for r in runs:
            if r.arch != "fitter" and r.summary.get("inference_ms") is None:
                r.summary["inference_ms"] = measure_inference_ms(r)
    path = write_report(
        runs, args.out, plots=not args.no_plots, qualitative=args.qualitative, notes=args.notes
    )
    print(path.read_text())
    return path


if __name__ == "__main__":
    main()
