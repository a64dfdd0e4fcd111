"""Fit scan files and write the outputs: what ``arteq-fit`` runs.

Per fitted scan ``<name>.obj`` / ``<name>.npz`` / ``<name>.json`` / ``<name>.png`` (written together and
atomically: all appear or none), and for the run ``summary.json`` / ``summary.csv`` (rewritten after each
batch). An input that fails gets a status and one message line; the batch goes on.

Depth images (a 16-bit PNG in millimetres, a ``[H, W]`` ``.npy`` in metres) are read by
:mod:`arteq.fit.depth` with their intrinsics (``depth=DepthOptions(...)`` or a JSON beside each image) into
the person's points in the camera frame, in metres whatever ``units`` says, with the camera as viewpoint;
folders given as inputs contribute their 16-bit grayscale PNGs too.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from arteq.fit.api import WRITTEN_STATUSES, FitResult, Fitter
from arteq.fit.depth import DepthOptions, depth_files_in, is_depth_file, read_depth
from arteq.io.fits import (
    AtomicFiles,
    csv_bytes,
    json_bytes,
    npz_bytes,
    obj_bytes,
    remove_stale_tmp,
    write_atomic,
)
from arteq.io.scans import ScanError, expand_inputs, read_scan

#: Statuses counted as failed (exit code 1): nothing was written for them.
FAILED_STATUSES = ("error", "not_single_body", "refused")

SUMMARY_COLUMNS = [
    "input", "name", "status", "message", "uncertain_reason", "inlier_frac", "rmse_in_cm", "mean_dist_cm",
    "coverage", "label_agree", "parts_covered", "max_abs_beta", "extent_m", "noise_mm", "denoised", "flags",
    "scan_mode", "parts_seen", "parts_unseen", "start", "crossing", "removed_plane",
    "removed_outlier", "removed_cluster", "stature_cm", "waist_cm", "mass_kg", "bmi", "age_years",
    "anny_rebuild_mm", "seconds", "anny_seconds",
]  # fmt: skip


@dataclass
class RunSummary:
    """What :func:`fit_files` did: one row per input plus totals."""

    rows: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0
    out_dir: Path | None = None

    def count(self, status: str) -> int:
        return sum(r["status"] == status for r in self.rows)

    @property
    def failed(self) -> int:
        return sum(r["status"] in FAILED_STATUSES for r in self.rows)

    def line(self) -> str:
        fitted = self.count("ok") + self.count("uncertain")
        done = [r for r in self.rows if r["status"] in WRITTEN_STATUSES]
        per = [r["seconds"] for r in done if r.get("seconds") is not None]
        t = f"; {sum(per) / len(per):.2f} s per fitted scan" if per else ""
        skipped = self.count("skipped")
        sk = f", {skipped} skipped (exist; --overwrite)" if skipped else ""
        unc = self.count("uncertain")
        un = f" ({unc} uncertain: written and flagged)" if unc else ""
        where = f" -> {self.out_dir / 'summary.csv'}" if self.out_dir else ""
        return f"arteq-fit: {fitted} fitted{un}, {self.failed} failed{sk} in {self.seconds:.1f} s{t}{where}"

    def to_json(self) -> dict[str, Any]:
        return {
            "fitted": self.count("ok") + self.count("uncertain"),
            "uncertain": self.count("uncertain"),
            "failed": self.failed,
            "skipped": self.count("skipped"),
            "seconds": self.seconds,
            "inputs": self.rows,
        }


def output_paths(out_dir: Path, name: str) -> dict[str, Path]:
    return {ext: out_dir / f"{name}.{ext}" for ext in ("obj", "npz", "json", "png")}


def write_result(res: FitResult, out_dir: Path, preview: bool = True, source: str = "") -> list[Path]:
    """Write ``<name>.obj``, ``<name>.npz``, ``<name>.json`` (and ``<name>.png``) of a fitted scan, all or
    nothing."""
    paths = output_paths(out_dir, res.name)
    header = (
        f"arteq fit of {source or res.name}\nbody model {res.body_model}; checkpoint {res.checkpoint}\n"
        f"units {res.units}; status {res.status}"
    )
    written = []
    with AtomicFiles() as files:
        written.append(files.write_bytes(paths["obj"], obj_bytes(res.vertices, res.faces, header)))
        arrays = res.arrays()
        arrays["source"] = source
        written.append(files.write_bytes(paths["npz"], npz_bytes(arrays)))
        written.append(files.write_bytes(paths["json"], json_bytes(res.to_json(source))))
        if preview:
            from arteq.fit.preview import render_preview

            written.append(files.write(paths["png"], lambda tmp: render_preview(res, tmp)))
    return written


def _unique_names(files: list[Path]) -> list[str]:
    names, seen = [], {}
    for f in files:
        base = f.stem
        n = seen.get(base, 0)
        seen[base] = n + 1
        names.append(base if n == 0 else f"{base}_{n + 1}")
    return names


def expand_scan_inputs(inputs: list[str | Path]) -> tuple[list[Path], list[tuple[str, str]]]:
    """:func:`arteq.io.scans.expand_inputs` plus the depth PNGs of folder inputs (:func:`depth_files_in`);
    a folder that holds only depth images is not a problem."""
    files, problems = expand_inputs(list(inputs))
    for item in inputs:
        p = Path(str(item)).expanduser()
        if p.is_dir():
            found = depth_files_in(p)
            if found:
                files.extend(found)
                problems = [pr for pr in problems if pr[0] != str(item)]
    seen: set[Path] = set()
    unique = []
    for f in files:
        if f.resolve() not in seen:
            seen.add(f.resolve())
            unique.append(f)
    return unique, problems


def read_input(path: Path, key: str | None, mesh_samples: int, depth: DepthOptions | None):
    """A scan file's points: a depth image through :func:`arteq.fit.depth.read_depth`, anything else
    through :func:`arteq.io.scans.read_scan`."""
    if is_depth_file(path):
        return read_depth(path, depth)
    return read_scan(path, key=key, mesh_samples=mesh_samples)


def fit_files(
    inputs: list[str | Path],
    out_dir: str | Path,
    fitter: Fitter | None = None,
    units: str = "m",
    key: str | None = None,
    preview: bool = True,
    overwrite: bool = False,
    batch_size: int = 4,
    progress: bool | None = None,
    log: Callable[[str], None] | None = None,
    depth: DepthOptions | None = None,
    **fitter_kwargs: Any,
) -> RunSummary:
    """Fit every scan named by ``inputs`` (files, folders searched recursively, globs) into ``out_dir``.

    ``fitter``: a loaded :class:`Fitter` (else one is built from ``fitter_kwargs``: ``ckpt``, ``device``,
    ``refine``, ``points``, ``check``...). ``log`` receives one line per failed input (default: stderr).
    ``depth``: how depth images are read (:class:`arteq.fit.depth.DepthOptions`: intrinsics, depth range).
    Returns a :class:`RunSummary`; ``summary.failed`` > 0 means some input failed.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    remove_stale_tmp(out)
    log = log or (lambda msg: print(msg, file=sys.stderr))
    summary = RunSummary(out_dir=out)
    files, problems = expand_scan_inputs(list(inputs))
    for text, msg in problems:
        summary.rows.append({"input": text, "name": "", "status": "error", "message": msg})
        log(msg)
    names = _unique_names(files)
    todo = []
    for f, name in zip(files, names):
        existing = [p for p in output_paths(out, name).values() if p.exists()]
        if existing and not overwrite:
            summary.rows.append({"input": str(f), "name": name, "status": "skipped",
                                 "message": f"{f}: outputs exist in {out} (use --overwrite)"})  # fmt: skip
            continue
        todo.append((f, name))
    if todo and fitter is None:
        fitter = Fitter(**fitter_kwargs)
    bar = None
    if progress is None:
        progress = sys.stderr.isatty()
    if progress and todo:
        from tqdm.auto import tqdm

        bar = tqdm(total=len(todo), desc="arteq-fit", unit="scan")

    def write_summary() -> None:
        summary.seconds = time.perf_counter() - t0
        write_atomic(out / "summary.json", json_bytes(summary.to_json()))
        write_atomic(out / "summary.csv", csv_bytes(summary.rows, SUMMARY_COLUMNS))

    def fail(row: dict[str, Any], msg: str) -> None:
        row.update(status="error", message=msg)
        summary.rows.append(row)
        log(msg)

    for start in range(0, len(todo), max(1, batch_size)):
        chunk = todo[start : start + max(1, batch_size)]
        prepared, rows = [], []
        for f, name in chunk:
            row = {"input": str(f), "name": name}
            try:
                scan = read_input(f, key, max(20000, fitter.points), depth)
                if scan.kind == "depth":  # metres in the camera frame, the camera at the origin
                    item = fitter.prepare(scan.points, units="m", name=str(f), viewpoint=scan.viewpoint)
                else:
                    item = fitter.prepare(scan.points, units=units, name=str(f))
                item["out_name"] = name
                prepared.append(item)
                rows.append(row)
            except ScanError as exc:
                fail(row, str(exc))
        try:
            results = fitter.fit_prepared(prepared)
        except Exception as exc:  # noqa: BLE001 - the batch goes on; each input says why
            results = [None] * len(prepared)
            err = f"{type(exc).__name__}: {exc}"
        for item, row, res in zip(prepared, rows, results):
            if res is None:
                fail(row, f"{item['name']}: fitting failed ({err})")
                continue
            res.name = item["out_name"]
            row.update(res.summary_row(), input=item["name"])
            if res.written:
                try:
                    write_result(res, out, preview=preview, source=item["name"])
                except Exception as exc:  # noqa: BLE001
                    fail(row, f"{item['name']}: writing the outputs failed ({type(exc).__name__}: {exc})")
                    continue
            if res.message and res.status != "ok":
                log(res.message)
            summary.rows.append(row)
        if bar is not None:
            bar.update(len(chunk))
        write_summary()
    if bar is not None:
        bar.close()
    write_summary()
    return summary
