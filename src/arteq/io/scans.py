"""Reading scans: point clouds and meshes from common file formats -> ``[N, 3]`` points.

Formats: ``.ply`` (point cloud or mesh), ``.obj``, ``.off``, ``.stl``, ``.glb`` / ``.gltf`` (through
trimesh; a mesh's surface is sampled, a cloud's points are used as they are), ``.xyz`` / ``.txt`` /
``.pts`` / ``.csv`` (``x y z`` per line, extra columns ignored, ``#`` comments), ``.npy`` (``[N, 3]``)
and ``.npz`` (key ``points`` or the one given).

Every failure is a :class:`ScanError` whose message starts with the file name and says what is wrong.
Units are not converted here (see :data:`UNITS`); non-finite rows are reported, not removed (the caller
decides: :func:`clean_points`).
"""

from __future__ import annotations

import glob
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: File suffixes read as point clouds or meshes.
MESH_SUFFIXES = (".ply", ".obj", ".off", ".stl", ".glb", ".gltf")
TEXT_SUFFIXES = (".xyz", ".txt", ".pts", ".csv")
ARRAY_SUFFIXES = (".npy", ".npz")
SUFFIXES = MESH_SUFFIXES + TEXT_SUFFIXES + ARRAY_SUFFIXES
#: Metres per unit.
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254, "ft": 0.3048}
_UNIT_WORDS = {"in": "inches", "ft": "feet"}
#: Fewest usable points a scan may have.
MIN_POINTS = 200


class ScanError(ValueError):
    """A scan that cannot be read or used; ``str(err)`` is one line naming the file and the problem."""


@dataclass
class Scan:
    """A scan as read from disk (file units, not centred).

    ``points [N, 3]`` float64; ``kind`` ``"cloud"`` or ``"mesh"`` (points sampled on its surface);
    ``num_vertices`` / ``num_faces`` of the mesh (0 for a cloud).
    """

    path: Path
    points: np.ndarray
    kind: str = "cloud"
    num_vertices: int = 0
    num_faces: int = 0


def expand_inputs(inputs: list[str | Path]) -> tuple[list[Path], list[tuple[str, str]]]:
    """Files named by ``inputs``: files as given, folders searched recursively for known suffixes,
    glob patterns expanded. Returns ``(files, problems)`` with ``problems`` a list of ``(input,
    message)`` for inputs that match nothing. Order is kept; duplicates are dropped."""
    files: list[Path] = []
    problems: list[tuple[str, str]] = []
    for item in inputs:
        text = str(item)
        p = Path(text).expanduser()
        if p.is_dir():
            found = sorted(f for f in p.rglob("*") if f.is_file() and f.suffix.lower() in SUFFIXES)
            if not found:
                problems.append((text, f"{text}: folder holds no scan files ({', '.join(SUFFIXES)})"))
            files.extend(found)
        elif p.is_file():
            files.append(p)
        elif any(c in text for c in "*?["):
            found = sorted(Path(f) for f in glob.glob(os.path.expanduser(text), recursive=True))
            found = [f for f in found if f.is_file() and f.suffix.lower() in SUFFIXES]
            if not found:
                problems.append((text, f"{text}: pattern matches no scan files"))
            files.extend(found)
        else:
            problems.append((text, f"{text}: no such file or folder"))
    seen: set[Path] = set()
    unique = []
    for f in files:
        key = f.resolve()
        if key not in seen:
            seen.add(key)
            unique.append(f)
    return unique, problems


def _as_points(arr: np.ndarray, path: Path, what: str) -> np.ndarray:
    arr = np.asarray(arr)
    if arr.dtype.kind not in "fiu":
        raise ScanError(f"{path}: {what} has dtype {arr.dtype}, expected numbers")
    if arr.ndim != 2 or arr.shape[1] < 3:
        raise ScanError(f"{path}: {what} has shape {list(arr.shape)}, expected [N, 3]")
    return np.ascontiguousarray(arr[:, :3], dtype=np.float64)


def _read_text(path: Path) -> np.ndarray:
    rows = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, 1):
            line = line.split("#", 1)[0].strip()
            if not line:
                continue
            fields = line.replace(",", " ").replace(";", " ").split()
            if len(fields) < 3:
                if not rows:  # a header line: a .pts file's point count, a column name
                    continue
                raise ScanError(f"{path}: line {lineno} has {len(fields)} values, expected x y z")
            try:
                rows.append([float(f) for f in fields[:3]])
            except ValueError:
                if not rows:  # a header line
                    continue
                raise ScanError(f"{path}: line {lineno} is not numbers: {line[:60]!r}") from None
    if not rows:
        raise ScanError(f"{path}: no points (no 'x y z' lines)")
    return np.asarray(rows, dtype=np.float64)


def _read_array(path: Path, key: str | None) -> np.ndarray:
    try:
        data = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - any failure of the reader is a bad file
        raise ScanError(f"{path}: not a readable {path.suffix} file ({type(exc).__name__}: {exc})") from None
    if isinstance(data, np.ndarray):
        return _as_points(data, path, "array")
    with data:
        name = key or "points"
        if name not in data.files:
            raise ScanError(
                f"{path}: no array {name!r} in the .npz (it holds {sorted(data.files)}); "
                "name the key with --key"
            )
        return _as_points(data[name], path, f"array {name!r}")


def _read_trimesh(path: Path, mesh_samples: int, seed: int) -> Scan:
    import trimesh

    try:
        obj = trimesh.load(str(path), process=False)
    except Exception as exc:  # noqa: BLE001 - trimesh raises many kinds on bad files
        msg = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise ScanError(f"{path}: not a readable {path.suffix.lstrip('.').upper()} file ({msg})") from None
    if isinstance(obj, trimesh.Scene):
        geoms = list(obj.dump()) if obj.geometry else []
        meshes = [g for g in geoms if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        clouds = [g for g in geoms if isinstance(g, trimesh.PointCloud)]
        if meshes:
            obj = trimesh.util.concatenate(meshes)
        elif clouds:
            obj = trimesh.PointCloud(np.concatenate([np.asarray(c.vertices) for c in clouds]))
        else:
            raise ScanError(f"{path}: the file holds no mesh or point cloud")
    if isinstance(obj, trimesh.Trimesh) and len(obj.faces) > 0:
        verts = np.asarray(obj.vertices, dtype=np.float64)
        if not np.isfinite(verts).all():
            raise ScanError(f"{path}: mesh vertices contain NaN or inf")
        area = float(obj.area)
        if not area > 0:
            raise ScanError(f"{path}: mesh has zero surface area")
        pts, _ = trimesh.sample.sample_surface(obj, mesh_samples, seed=seed)
        return Scan(path, np.asarray(pts, dtype=np.float64), "mesh", len(verts), len(obj.faces))
    verts = getattr(obj, "vertices", None)
    if verts is None:
        raise ScanError(f"{path}: the file holds no points ({type(obj).__name__})")
    return Scan(path, _as_points(np.asarray(verts), path, "vertex list"), "cloud")


def read_scan(path: str | Path, key: str | None = None, mesh_samples: int = 20000, seed: int = 0) -> Scan:
    """Read one scan file (see module docstring). Meshes are sampled uniformly by area
    (``mesh_samples`` points, seeded). Raises :class:`ScanError` on any problem."""
    path = Path(path)
    if not path.is_file():
        raise ScanError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix not in SUFFIXES:
        raise ScanError(f"{path}: unknown file type {suffix or '(none)'!r}; readable: {' '.join(SUFFIXES)}")
    if path.stat().st_size == 0:
        raise ScanError(f"{path}: empty file")
    if suffix in MESH_SUFFIXES:
        scan = _read_trimesh(path, mesh_samples, seed)
    elif suffix in TEXT_SUFFIXES:
        scan = Scan(path, _read_text(path), "cloud")
    else:
        scan = Scan(path, _read_array(path, key), "cloud")
    if len(scan.points) == 0:
        raise ScanError(f"{path}: no points")
    return scan


def clean_points(points: np.ndarray, path: str | Path = "points") -> tuple[np.ndarray, np.ndarray]:
    """Drop rows with NaN / inf. Returns ``(finite_points, keep_mask)``; error when none is finite."""
    keep = np.isfinite(points).all(axis=1)
    if not keep.any():
        raise ScanError(f"{path}: every point has NaN or inf coordinates")
    return points[keep], keep


def robust_extent(points: np.ndarray, lo: float = 1.0, hi: float = 99.0) -> float:
    """Largest extent of the cloud along its principal axes between the ``lo`` and ``hi`` percentiles
    (so a few stray points do not count): the body's height for a standing or lying body."""
    c = points - np.median(points, axis=0)
    sub = c if len(c) <= 20000 else c[np.random.default_rng(0).choice(len(c), 20000, replace=False)]
    _, _, vt = np.linalg.svd(sub - sub.mean(0), full_matrices=False)
    proj = sub @ vt.T
    q = np.percentile(proj, [lo, hi], axis=0)
    return float((q[1] - q[0]).max())


def check_body_size(
    points_m: np.ndarray, path: str | Path, units: str, limits_m: tuple[float, float] = (0.4, 3.5)
) -> float:
    """Robust extent in metres of a cloud already scaled to metres; :class:`ScanError` if it cannot be
    one human body in the stated units (``limits_m``, 0.4 m .. 3.5 m; wider for a scan with its room
    still in it), suggesting the ``--units`` flag that fits."""
    ext = robust_extent(points_m)
    if limits_m[0] <= ext <= limits_m[1]:
        return ext
    in_units = ext / UNITS[units]
    fits = sorted(
        (abs(np.log(in_units * scale / 1.7)), name)
        for name, scale in UNITS.items()
        if name != units and 0.8 <= in_units * scale <= 2.5
    )  # the units that make it body-sized, the nearest to 1.7 m first (80 in or 80 cm: a child either way)
    hint = ""
    if fits:
        first, *others = [name for _, name in fits]
        hint = f"; if the file is in {_UNIT_WORDS.get(first, first)}, pass --units {first}"
        hint += "".join(f" (in {_UNIT_WORDS.get(n, n)}: --units {n})" for n in others)
    raise ScanError(
        f"{path}: the cloud is {in_units:.4g} {units} across, a human body is about 1.7 m "
        f"(expected {limits_m[0]:g}-{limits_m[1]:g} m with --units {units}){hint}"
    )
