"""Depth images in: a depth camera's image and intrinsics -> the person's points (camera frame, metres).

Formats: a 16-bit grayscale PNG in millimetres (``depth_scale`` metres per unit, default 0.001), or a
``.npy`` of float depths in metres (``[H, W]``, or ``[H, W, 1]``). Zero, negative and non-finite depths are
missing pixels. Depth is along the optical axis (z), pixel ``(row v, column u)`` at ``x = (u - cx) z / fx``,
``y = (v - cy) z / fy`` (OpenCV's pinhole convention: the first pixel's centre is at 0, 0).

Intrinsics ``fx, fy, cx, cy`` (pixels) come from the command line (``--fx --fy --cx --cy``) or a JSON file
beside the image: ``<name>.json``, else ``intrinsics.json`` in the same folder, with keys ``fx``, ``fy``,
``cx``, ``cy`` and optionally ``depth_scale`` and ``depth_range_m``; command-line values win.

The person is separated from the background by depth range: ``depth_range_m = [near, far]`` when given,
else automatically, taking the person as the nearest thing in the middle of the picture: ``d0``, the 15th
percentile of the depths in the image's central third (width and height), and the band
``[d0 - auto_band_m[0], d0 + auto_band_m[1]]`` (0.5 m in front, 1.5 m behind: a body, standing or lying,
and a floor around it that the clean-up removes). The fitter's clutter removal (:mod:`arteq.fit.clean`:
floor, walls, stray and flying pixels, other objects) runs on what remains, as for any scan, with the
camera as its viewpoint: plane bands that follow the depth noise's growth with distance, and the body's
parts beyond occlusion edges kept. The camera sits at the origin of the returned frame (``viewpoint``),
which the refinement uses for visibility.

PNGs are read with Pillow (installed with matplotlib). Every failure is a :class:`arteq.io.scans.ScanError`
naming the file.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from arteq.io.scans import ScanError

#: PNG signature; bytes 24 and 25 of a PNG are its bit depth and colour type (IHDR).
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
INTRINSIC_KEYS = ("fx", "fy", "cx", "cy")


@dataclass
class DepthOptions:
    """How depth images are read. ``intrinsics``: ``fx, fy, cx, cy`` given on the command line (``None``
    entries: from the JSON beside the file); ``depth_scale``: metres per PNG unit (``None``: the JSON's, else
    0.001); ``depth_range_m``: the person's ``(near, far)`` band (``None``: the JSON's, else automatic, with
    ``auto_band_m`` in front of and behind the nearest depths of the image's centre: module docstring)."""

    intrinsics: dict[str, float | None] = field(default_factory=dict)
    depth_scale: float | None = None
    depth_range_m: tuple[float, float] | None = None
    auto_band_m: tuple[float, float] = (0.5, 1.5)


@dataclass
class DepthScan:
    """A depth image turned into points: ``points [N, 3]`` metres in the camera frame (the person's band),
    ``viewpoint [3]`` the camera (the origin), ``intrinsics``, ``image_shape``, ``depth_range_m`` used, and
    ``pixels_valid`` / ``pixels_kept`` (with a depth / in the band), ``pixels [N, 2]`` each point's pixel
    ``(row v, column u)``."""

    path: Path
    points: np.ndarray
    viewpoint: np.ndarray
    intrinsics: dict[str, float]
    image_shape: tuple[int, int]
    depth_range_m: tuple[float, float]
    pixels_valid: int
    pixels_kept: int
    kind: str = "depth"
    pixels: np.ndarray | None = None


def png_format(path: Path) -> tuple[int, int] | None:
    """``(bit depth, colour type)`` from a PNG's header, or ``None`` when the file is not a PNG."""
    with open(path, "rb") as fh:
        head = fh.read(26)
    if len(head) < 26 or not head.startswith(PNG_SIGNATURE) or head[12:16] != b"IHDR":
        return None
    return head[24], head[25]


def is_depth_png(path: Path) -> bool:
    """Whether ``path`` is a 16-bit grayscale PNG (how depth cameras store millimetres)."""
    return png_format(path) == (16, 0)


def is_depth_file(path: Path) -> bool:
    """Whether :func:`read_depth` should read ``path``: any ``.png``, or a ``.npy`` holding a 2-D image (not
    an ``[N, 3]`` point list)."""
    suffix = path.suffix.lower()
    if suffix == ".png":
        return True
    if suffix != ".npy":
        return False
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except Exception:  # noqa: BLE001 - unreadable: the point reader says why
        return False
    shape = getattr(arr, "shape", ())
    return (len(shape) == 2 and shape[1] != 3) or (len(shape) == 3 and shape[2] == 1)


def _read_png(path: Path) -> np.ndarray:
    fmt = png_format(path)
    if fmt is None:
        raise ScanError(f"{path}: not a PNG file")
    bits, colour = fmt
    if (bits, colour) != (16, 0):
        kind = {0: "grayscale", 2: "RGB", 3: "palette", 4: "grayscale+alpha", 6: "RGBA"}.get(colour, "?")
        raise ScanError(
            f"{path}: a {bits}-bit {kind} PNG; a depth image is a 16-bit grayscale PNG in millimetres"
        )
    from PIL import Image

    try:
        with Image.open(path) as img:
            img.load()
            arr = np.asarray(img)
    except Exception as exc:  # noqa: BLE001 - a broken file
        raise ScanError(f"{path}: not a readable PNG ({type(exc).__name__}: {exc})") from None
    if arr.ndim != 2:
        raise ScanError(f"{path}: expected a one-channel depth image, got shape {list(arr.shape)}")
    return arr.astype(np.float64)


def _read_npy(path: Path) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001
        raise ScanError(f"{path}: not a readable .npy file ({type(exc).__name__}: {exc})") from None
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim != 2:
        raise ScanError(f"{path}: a depth .npy is [H, W] metres, got shape {list(arr.shape)}")
    if arr.dtype.kind != "f":
        raise ScanError(
            f"{path}: depth .npy has dtype {arr.dtype}, expected floats in metres "
            "(millimetre integers: save a 16-bit PNG)"
        )
    return arr.astype(np.float64)


def _sidecar(path: Path) -> tuple[Path | None, dict]:
    for cand in (path.with_suffix(".json"), path.parent / "intrinsics.json"):
        if cand.is_file():
            try:
                data = json.loads(cand.read_text())
            except (OSError, ValueError) as exc:
                raise ScanError(f"{cand}: camera intrinsics JSON is not readable ({exc})") from None
            if not isinstance(data, dict):
                raise ScanError(f"{cand}: camera intrinsics JSON must be an object with fx, fy, cx, cy")
            return cand, data
    return None, {}


def _number(value: object, where: str, key: str) -> float:
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise ScanError(f"{where}: {key} must be a number, got {value!r}") from None
    if not np.isfinite(x):
        raise ScanError(f"{where}: {key} must be finite, got {value!r}")
    return x


def read_depth(path: str | Path, options: DepthOptions | None = None) -> DepthScan:
    """Read a depth image and back-project the person's depth band (module docstring)."""
    path = Path(path)
    opts = options or DepthOptions()
    if not path.is_file():
        raise ScanError(f"{path}: no such file")
    if path.stat().st_size == 0:
        raise ScanError(f"{path}: empty file")
    side_path, side = _sidecar(path)
    where = str(side_path) if side_path else str(path)
    intr = {}
    for k in INTRINSIC_KEYS:
        v = (opts.intrinsics or {}).get(k)
        if v is None:
            v = side.get(k)
        if v is None:
            missing = [k for k in INTRINSIC_KEYS if (opts.intrinsics or {}).get(k) is None and k not in side]
            raise ScanError(
                f"{path}: camera intrinsics missing ({', '.join(missing)}): pass --fx --fy --cx --cy or put "
                f"{path.with_suffix('.json').name} (or intrinsics.json) with fx, fy, cx, cy beside it"
            )
        intr[k] = _number(v, where, k)
    if intr["fx"] <= 0 or intr["fy"] <= 0:
        raise ScanError(f"{where}: fx and fy must be positive pixels, got {intr['fx']}, {intr['fy']}")

    if path.suffix.lower() == ".png":
        raw = _read_png(path)
        scale = opts.depth_scale if opts.depth_scale is not None else side.get("depth_scale", 0.001)
        scale = _number(scale, where, "depth_scale")
        if scale <= 0:
            raise ScanError(f"{where}: depth_scale must be > 0 metres per unit, got {scale}")
        depth = raw * scale
    else:
        depth = _read_npy(path)
    valid = np.isfinite(depth) & (depth > 0)
    if not valid.any():
        raise ScanError(f"{path}: depth image has no valid pixels (all zero, negative or NaN)")

    band = opts.depth_range_m if opts.depth_range_m is not None else side.get("depth_range_m")
    if band is not None:
        if len(band) != 2:
            raise ScanError(f"{where}: depth_range_m must be [near, far] metres, got {band!r}")
        near, far = (_number(b, where, "depth_range_m") for b in band)
        if not 0 <= near < far:
            raise ScanError(f"{where}: depth_range_m must have 0 <= near < far, got {near}, {far}")
    else:
        h, w = depth.shape
        centre = depth[h // 3 : h - h // 3, w // 3 : w - w // 3]
        centre = centre[np.isfinite(centre) & (centre > 0)]
        d0 = float(np.percentile(centre if len(centre) else depth[valid], 15))
        near, far = max(0.0, d0 - opts.auto_band_m[0]), d0 + opts.auto_band_m[1]
    keep = valid & (depth >= near) & (depth <= far)
    if not keep.any():
        raise ScanError(f"{path}: no pixel within the depth range {near:.3g}-{far:.3g} m")
    v, u = np.nonzero(keep)
    z = depth[v, u]
    x = (u - intr["cx"]) * z / intr["fx"]
    y = (v - intr["cy"]) * z / intr["fy"]
    return DepthScan(
        path=path,
        points=np.stack([x, y, z], 1),
        viewpoint=np.zeros(3),
        intrinsics=intr,
        image_shape=(int(depth.shape[0]), int(depth.shape[1])),
        depth_range_m=(float(near), float(far)),
        pixels_valid=int(valid.sum()),
        pixels_kept=int(keep.sum()),
        pixels=np.stack([v, u], 1).astype(np.int32),
    )


def depth_files_in(folder: Path) -> list[Path]:
    """The 16-bit grayscale PNGs under ``folder`` (recursive): the depth images a folder input holds (8-bit
    pictures, such as earlier fits' previews, are not depth images and are left out)."""
    pngs = (p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() == ".png")
    return sorted(p for p in pngs if is_depth_png(p))


def write_depth_png(path: str | Path, depth_m: np.ndarray, scale: float = 0.001) -> None:
    """Write ``depth_m [H, W]`` metres as a 16-bit grayscale PNG (units of ``scale`` metres; 0 = missing)."""
    from PIL import Image

    d = np.nan_to_num(np.asarray(depth_m, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    units = np.clip(np.round(d / scale), 0, 65535).astype(np.uint16)
    Image.fromarray(units).save(str(path))
