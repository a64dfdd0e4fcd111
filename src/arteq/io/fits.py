"""Writing fits: meshes (.obj), parameters (.npz), tables (.json / .csv), all atomically.

Every file is first written under a hidden temporary name in its destination folder and renamed into
place only when all the files of a group are complete (:class:`AtomicFiles`): an interrupted or failing
write leaves no partial file behind (at worst a ``.*.tmp`` that the next run removes).
"""

from __future__ import annotations

import csv
import io
import json
import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

import numpy as np


def _tmp_name(path: Path) -> Path:
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


class AtomicFiles:
    """Write several files so that they all appear, or none does.

    ``with AtomicFiles() as files: files.write(path, writer)`` where ``writer(tmp_path)`` writes the
    content; on a clean exit every temporary file is renamed to its final name, on an exception all
    of them are deleted and the exception propagates.
    """

    def __init__(self) -> None:
        self.pending: list[tuple[Path, Path]] = []

    def __enter__(self) -> AtomicFiles:
        return self

    def write(self, path: str | Path, writer: Callable[[Path], Any]) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = _tmp_name(path)
        self.pending.append((tmp, path))
        writer(tmp)
        return path

    def write_bytes(self, path: str | Path, data: bytes) -> Path:
        return self.write(path, lambda t: t.write_bytes(data))

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is None:
            for tmp, final in self.pending:
                os.replace(tmp, final)
        else:
            for tmp, _ in self.pending:
                tmp.unlink(missing_ok=True)
        self.pending = []
        return False


def write_atomic(path: str | Path, data: bytes | str) -> Path:
    """Write one file atomically."""
    with AtomicFiles() as files:
        files.write_bytes(path, data.encode() if isinstance(data, str) else data)
    return Path(path)


def remove_stale_tmp(folder: str | Path) -> int:
    """Delete ``.*.tmp`` leftovers of interrupted runs in ``folder``; returns how many."""
    n = 0
    for p in Path(folder).glob(".*.tmp"):
        p.unlink(missing_ok=True)
        n += 1
    return n


def obj_bytes(vertices: np.ndarray, faces: np.ndarray, header: str = "") -> bytes:
    """A Wavefront OBJ of a triangle mesh (``faces`` 0-based). The same text as ``np.savetxt`` with
    ``v %.6g %.6g %.6g`` / ``f %d %d %d`` rows, formatted in one ``%`` per block (5x faster)."""
    v = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
    f = np.asarray(faces, dtype=np.int64).reshape(-1, 3) + 1
    head = "".join(f"# {line}\n" for line in header.splitlines())
    rows_v = ("v %.6g %.6g %.6g\n" * len(v)) % tuple(v.ravel().tolist())
    rows_f = ("f %d %d %d\n" * len(f)) % tuple(f.ravel().tolist())
    return (head + rows_v + rows_f).encode()


def npz_bytes(arrays: dict[str, Any]) -> bytes:
    """A compressed ``.npz`` holding ``arrays`` (strings stored as 0-d unicode arrays)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return buf.getvalue()


def json_bytes(obj: Any) -> bytes:
    return (json.dumps(obj, indent=2, sort_keys=False, default=_json_default) + "\n").encode()


def _json_default(x: Any) -> Any:
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    if isinstance(x, Path):
        return str(x)
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")


def csv_bytes(rows: Iterable[dict[str, Any]], columns: list[str]) -> bytes:
    """CSV with the given columns (missing values empty; floats to 4 significant digits)."""
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for row in rows:
        w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in row.items()})
    return buf.getvalue().encode()
