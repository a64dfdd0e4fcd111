"""Reading scans: point clouds and meshes from common file formats -> ``[N, 3]`` points.

Formats: ``.ply`` (point cloud or mesh), ``.obj``, ``.off``, ``.stl``, ``.glb`` / ``.gltf`` (through
trimesh; a mesh's surface is sampled, a cloud's points are used as they are), ``.xyz`` / ``.txt`` /
``.pts`` / ``.csv`` (``x y z`` per line, extra columns ignored, ``#`` comments), ``.pcd`` (the Point Cloud
Library's format, as depth-camera tools write it: ``ascii``, ``binary`` and ``binary_compressed`` data; its
``x y z`` fields), ``.npy`` (``[N, 3]``) and ``.npz`` (key ``points`` or the one given).

A ``.pcd`` file can say where its camera was: an organized cloud (``HEIGHT`` > 1, one point per pixel of a
depth image) was seen from its ``VIEWPOINT`` (the origin unless the file says otherwise), and so was any
cloud whose ``VIEWPOINT`` is not the origin; :attr:`Scan.viewpoint` then holds that position (file units).

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
PCD_SUFFIXES = (".pcd",)
SUFFIXES = MESH_SUFFIXES + TEXT_SUFFIXES + ARRAY_SUFFIXES + PCD_SUFFIXES
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
    ``num_vertices`` / ``num_faces`` of the mesh (0 for a cloud); ``viewpoint [3]`` the camera's position
    when the file gives it (a ``.pcd``'s, see the module docstring; file units), else None.
    """

    path: Path
    points: np.ndarray
    kind: str = "cloud"
    num_vertices: int = 0
    num_faces: int = 0
    viewpoint: np.ndarray | None = None


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


#: PCD ``(TYPE, SIZE)`` -> numpy dtype (PCD data are little-endian).
_PCD_DTYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "i1", ("I", 2): "<i2", ("I", 4): "<i4",
               ("I", 8): "<i8", ("U", 1): "u1", ("U", 2): "<u2", ("U", 4): "<u4",
               ("U", 8): "<u8"}  # fmt: skip


def lzf_decompress(data: bytes, size: int) -> bytes:
    """LZF-decompress ``data`` to exactly ``size`` bytes (``binary_compressed`` PCD data). A stream of
    literal runs (``000LLLLL`` then ``L + 1`` bytes) and back references (``LLLooooo oooooooo``: ``L + 2``
    bytes from ``o + 1`` back; ``L`` = 7 takes one more length byte). :class:`ValueError` when the stream
    is corrupt or does not decode to ``size`` bytes."""
    out = bytearray(size)
    ip = op = 0
    n = len(data)
    while ip < n:
        ctrl = data[ip]
        ip += 1
        if ctrl < 32:  # a literal run
            length = ctrl + 1
            if ip + length > n or op + length > size:
                raise ValueError(f"a literal run of {length} bytes overruns the data at byte {ip}")
            out[op : op + length] = data[ip : ip + length]
            ip += length
            op += length
            continue
        length = ctrl >> 5
        if length == 7:
            if ip >= n:
                raise ValueError("the data end inside a back reference")
            length += data[ip]
            ip += 1
        if ip >= n:
            raise ValueError("the data end inside a back reference")
        ref = op - ((ctrl & 0x1F) << 8) - data[ip] - 1
        ip += 1
        length += 2
        if ref < 0 or op + length > size:
            raise ValueError(f"a back reference at output byte {op} points outside the output")
        while length:  # an overlapping reference repeats its last op - ref bytes
            chunk = min(length, op - ref)
            out[op : op + chunk] = out[ref : ref + chunk]
            op, ref, length = op + chunk, ref + chunk, length - chunk
    if op != size:
        raise ValueError(f"decodes to {op} bytes, the header says {size}")
    return bytes(out)


def _read_pcd(path: Path) -> Scan:
    """A ``.pcd`` file's ``x y z`` (and its camera: module docstring)."""
    raw = path.read_bytes()
    head: dict[str, list[str]] = {}
    pos = 0
    while "DATA" not in head:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise ScanError(f"{path}: not a PCD file (its header has no DATA line)")
        line = raw[pos:end].decode("ascii", errors="replace").strip()
        pos = end + 1
        if line and not line.startswith("#"):
            key, *values = line.split()
            head[key.upper()] = values
    for key in ("FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "DATA"):
        if not head.get(key):
            raise ScanError(f"{path}: the PCD header has no {key} line")
    names = [f.lower() for f in head["FIELDS"]]
    k = len(names)
    counts = head.get("COUNT") or ["1"] * k
    if not (len(head["SIZE"]) == len(head["TYPE"]) == len(counts) == k):
        raise ScanError(f"{path}: the PCD header's FIELDS, SIZE, TYPE and COUNT differ in length")
    try:
        sizes, counts = [int(v) for v in head["SIZE"]], [int(v) for v in counts]
        width, height = int(head["WIDTH"][0]), int(head["HEIGHT"][0])
        count = int(head["POINTS"][0]) if head.get("POINTS") else width * height
        view = [float(v) for v in head.get("VIEWPOINT", ["0", "0", "0", "1", "0", "0", "0"])]
    except ValueError:
        raise ScanError(f"{path}: the PCD header holds a value that is not a number") from None
    types = [t.upper() for t in head["TYPE"]]
    if any((t, s) not in _PCD_DTYPES for t, s in zip(types, sizes)):
        bad = [f"{t}{s}" for t, s in zip(types, sizes) if (t, s) not in _PCD_DTYPES]
        raise ScanError(f"{path}: PCD field types {bad} are not TYPE F/I/U with SIZE 1/2/4/8")
    if any(c < 1 for c in counts) or count < 0:
        raise ScanError(f"{path}: the PCD header gives a COUNT below 1 or a negative POINTS")
    missing = [a for a in "xyz" if a not in names]
    if missing:
        raise ScanError(
            f"{path}: the PCD file has no {', '.join(missing)} field (its fields: {' '.join(names)})"
        )
    if len(view) != 7:
        raise ScanError(
            f"{path}: the PCD VIEWPOINT has {len(view)} values, expected 7 (tx ty tz qw qx qy qz)"
        )
    dtypes = [np.dtype(_PCD_DTYPES[t, s]) for t, s in zip(types, sizes)]
    mode = head["DATA"][0].lower()
    cols = {}
    if mode == "ascii":
        text = raw[pos:].decode("ascii", errors="replace").split()
        per = sum(counts)
        if len(text) < count * per:
            raise ScanError(
                f"{path}: the PCD data hold {len(text)} values, {count} points need {count * per}"
            )
        try:
            table = np.asarray(text[: count * per], dtype=np.float64).reshape(count, per)
        except ValueError:
            raise ScanError(f"{path}: the PCD ascii data hold a value that is not a number") from None
        starts = np.cumsum([0] + counts)
        cols = {a: table[:, starts[names.index(a)]] for a in "xyz"}
    elif mode == "binary":
        record = np.dtype([(f"f{i}", d, (c,)) for i, (d, c) in enumerate(zip(dtypes, counts))])
        if len(raw) - pos < count * record.itemsize:
            raise ScanError(f"{path}: the PCD binary data are {len(raw) - pos} bytes, {count} points need "
                            f"{count * record.itemsize}")  # fmt: skip
        table = np.frombuffer(raw, dtype=record, count=count, offset=pos)
        cols = {a: table[f"f{names.index(a)}"][:, 0] for a in "xyz"}
    elif mode == "binary_compressed":
        if len(raw) - pos < 8:
            raise ScanError(f"{path}: the PCD compressed data are missing")
        packed, size = (int(v) for v in np.frombuffer(raw, "<u4", count=2, offset=pos))
        need = count * sum(d.itemsize * c for d, c in zip(dtypes, counts))
        if size != need or len(raw) - pos - 8 < packed:
            raise ScanError(f"{path}: the PCD compressed data say {packed} -> {size} bytes; the file holds "
                            f"{len(raw) - pos - 8}, {count} points need {need}")  # fmt: skip
        try:
            data = lzf_decompress(raw[pos + 8 : pos + 8 + packed], size)
        except ValueError as exc:
            raise ScanError(f"{path}: the PCD compressed data are corrupt ({exc})") from None
        offset = 0  # field after field: all points' values of one field, then the next field's
        for name, d, c in zip(names, dtypes, counts):
            if name in ("x", "y", "z"):
                cols[name] = np.frombuffer(data, d, count=count * c, offset=offset).reshape(count, c)[:, 0]
            offset += count * c * d.itemsize
    else:
        raise ScanError(f"{path}: PCD DATA {mode!r} is not ascii, binary or binary_compressed")
    points = np.stack([cols[a] for a in "xyz"], axis=1).astype(np.float64)
    viewpoint = np.asarray(view[:3], dtype=np.float64)
    seen_from = height > 1 or bool(np.any(viewpoint != 0))
    return Scan(path, points, "cloud", viewpoint=viewpoint if seen_from else None)


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
    elif suffix in PCD_SUFFIXES:
        scan = _read_pcd(path)
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
