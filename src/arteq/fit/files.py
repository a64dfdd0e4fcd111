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
    "scan_mode", "parts_seen", "parts_unseen", "start", "crossing", "retry", "clothing_cm", "removed_plane",
    "removed_outlier", "removed_cluster", "removed_object", "stature_cm", "waist_cm", "mass_kg", "bmi",
    "age_years", "anny_rebuild_mm", "seconds", "anny_seconds",
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


def _fit_batch(
    fitter: Fitter,
    chunk: list[tuple[Path, str]],
    out: Path,
    units: str,
    key: str | None,
    preview: bool,
    depth: DepthOptions | None,
) -> tuple[list[dict[str, Any]], list[str]]:
    """Fit and write one batch of ``(file, output name)``: the summary rows (in ``chunk``'s order of the
    fitted ones, failures first) and the lines to log."""
    prepared, rows, done, msgs = [], [], [], []

    def fail(row: dict[str, Any], msg: str) -> None:
        row.update(status="error", message=msg)
        done.append(row)
        msgs.append(msg)

    for f, name in chunk:
        row = {"input": str(f), "name": name}
        try:
            scan = read_input(f, key, max(20000, fitter.points), depth)
            if scan.kind == "depth":  # metres in the camera frame, the camera at the origin
                item = fitter.prepare(scan.points, units="m", name=str(f), viewpoint=scan.viewpoint)
            else:  # a .pcd's camera (organized, or its VIEWPOINT), unless told the scans are full
                known = scan.viewpoint is not None and fitter.partial is not False
                camera = {"viewpoint": scan.viewpoint} if known else {}
                item = fitter.prepare(scan.points, units=units, name=str(f), **camera)
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
            msgs.append(res.message)
        done.append(row)
    return done, msgs


#: the worker process's Fitter (``jobs`` > 1)
_WORKER_FITTER: Fitter | None = None


def _init_worker(fitter_kwargs: dict[str, Any], threads: int) -> None:
    import torch

    global _WORKER_FITTER
    torch.set_num_threads(threads)
    _WORKER_FITTER = Fitter(**fitter_kwargs)


def _worker_batch(args: tuple) -> tuple[list[dict[str, Any]], list[str]]:
    return _fit_batch(_WORKER_FITTER, *args)


def _fit_side_by_side(
    fitter: Fitter, args: list[tuple], batches: list[list], jobs: int, per: int,
    fitter_kwargs: dict[str, Any], collect: Callable[[int, tuple], None],
) -> None:  # fmt: skip
    """Batches ``args`` fitted by this process and ``jobs - 1`` spawned workers, each taking the next batch
    not yet taken when it is free (a scan that is refitted several times holds up only its own process);
    ``collect(i, (rows, messages))`` receives batch ``i``'s results, in this process, one at a time."""
    import multiprocessing
    import threading
    from concurrent.futures import ProcessPoolExecutor
    from concurrent.futures.process import BrokenProcessPool

    import torch

    lock = threading.Lock()
    order = iter(range(len(args)))
    stop = threading.Event()  # this process failed: the feeders take nothing more

    def take() -> int | None:
        with lock:
            return None if stop.is_set() else next(order, None)

    def done(i: int, result: tuple) -> None:
        with lock:
            collect(i, result)

    def failed(i: int, exc: BaseException) -> tuple:
        why = f"a worker process failed ({type(exc).__name__}: {exc})"
        rows = [{"input": str(f), "name": name, "status": "error", "message": f"{f}: {why}"}
                for f, name in batches[i]]  # fmt: skip
        return rows, [r["message"] for r in rows]

    def feed(pool: ProcessPoolExecutor) -> None:  # one per worker: its next batch as soon as it is free
        while (i := take()) is not None:
            try:
                result = pool.submit(_worker_batch, args[i]).result()
            except BrokenProcessPool as exc:  # the workers died or never started: this process goes on alone
                done(i, failed(i, exc))
                return
            except Exception as exc:  # noqa: BLE001 - an error the worker raised: its batch's inputs say so
                result = failed(i, exc)
            done(i, result)

    ctx = multiprocessing.get_context("spawn")  # no forked torch thread pools
    before = torch.get_num_threads()
    torch.set_num_threads(per)  # this process's share too, for the run only
    try:
        with ProcessPoolExecutor(jobs - 1, mp_context=ctx, initializer=_init_worker,
                                 initargs=(fitter_kwargs, per)) as pool:  # fmt: skip
            feeders = [threading.Thread(target=feed, args=(pool,), daemon=True) for _ in range(jobs - 1)]
            for t in feeders:
                t.start()
            try:
                while (i := take()) is not None:  # this process's batches, taken the same way
                    done(i, _fit_batch(fitter, *args[i]))
            except BaseException:
                stop.set()
                raise
            for t in feeders:
                t.join()
    finally:
        torch.set_num_threads(before)


#: at most this many processes by default (``auto_jobs``), and one per this much available memory (GB):
#: a worker holds about 0.6 GB once its Fitter is built (the network, the bodies, anny for the export)
AUTO_JOBS_MAX = 8
AUTO_JOBS_GB = 1.5


def _available_gb() -> float | None:
    try:
        with open("/proc/meminfo") as f:
            for line in f:
                if line.startswith("MemAvailable:"):
                    return int(line.split()[1]) / 2**20
    except OSError:
        pass
    return None


def _usable_cores() -> int:
    """The cores this process may run on (its CPU affinity, e.g. a container's share; else the CPU count)."""
    import os

    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def auto_jobs(device: str = "auto", threads: int | None = None) -> int:
    """The processes ``arteq-fit`` fits with by default: on the CPU one per usable core (per ``threads``
    cores when each process is given that many threads), at most :data:`AUTO_JOBS_MAX` and one per
    :data:`AUTO_JOBS_GB` of available memory; one on a GPU."""
    from arteq.fit.api import resolve_device

    if resolve_device(device).type != "cpu":
        return 1
    cores = _usable_cores()
    gb = _available_gb()
    by_memory = int(gb // AUTO_JOBS_GB) if gb is not None else cores
    return max(1, min(cores // max(1, threads or 1), AUTO_JOBS_MAX, by_memory))


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
    jobs: int = 1,
    threads: int | None = None,
    **fitter_kwargs: Any,
) -> RunSummary:
    """Fit every scan named by ``inputs`` (files, folders searched recursively, globs) into ``out_dir``.

    ``fitter``: a loaded :class:`Fitter` (else one is built from ``fitter_kwargs``: ``ckpt``, ``device``,
    ``refine``, ``points``, ``check``...). ``log`` receives one line per failed input (default: stderr).
    ``depth``: how depth images are read (:class:`arteq.fit.depth.DepthOptions`: intrinsics, depth range).
    ``jobs`` > 1: this process and ``jobs - 1`` worker processes fit the batches side by side (each
    process takes the next batch when it is free; workers that die or cannot start leave the rest to this
    process, their batch in hand reported as failed), the workers with a Fitter of their own built from
    ``fitter_kwargs`` (which must then be given; this process uses ``fitter`` or builds one from them too),
    each process with ``threads`` torch threads (default: the usable cores divided among them). The outputs
    are those of one process; on two cores two one-thread processes fitted 28 scans in 38 s against 50 s for
    one two-thread process (the fit's steps are too small to share threads well;
    experiments/fitting/speed.md).
    Returns a :class:`RunSummary`; ``summary.failed`` > 0 means some input failed.
    """
    if jobs < 1:
        raise ValueError(f"jobs must be >= 1, got {jobs}")
    if jobs > 1 and not fitter_kwargs:
        raise ValueError("fit_files: jobs > 1 builds each worker's Fitter from fitter_kwargs; give them")
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
    size = max(1, batch_size)
    batches = [todo[s : s + size] for s in range(0, len(todo), size)]
    jobs = max(1, min(jobs, len(batches)))
    per = threads or max(1, _usable_cores() // jobs)
    if batches and fitter is None:
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

    first = list(summary.rows)  # input problems and skipped files
    done: dict[int, list[dict[str, Any]]] = {}

    def collect(i: int, rows_msgs) -> None:
        """Batch ``i``'s rows into the summary (in input order) and its lines into the log."""
        rows, msgs = rows_msgs
        done[i] = rows
        summary.rows = first + [r for j in sorted(done) for r in done[j]]
        for m in msgs:
            log(m)
        if bar is not None:
            bar.update(len(batches[i]))
        write_summary()

    args = [(chunk, out, units, key, preview, depth) for chunk in batches]
    if jobs == 1:
        for i, a in enumerate(args):
            collect(i, _fit_batch(fitter, *a))
    else:
        _fit_side_by_side(fitter, args, batches, jobs, per, fitter_kwargs, collect)
    if bar is not None:
        bar.close()
    write_summary()
    return summary
