"""The PCD reader (arteq.io.scans): ascii, binary and LZF-compressed data, fields of any type and count, the
camera a file gives (organized clouds, VIEWPOINT), and one clear line naming the file for each kind of bad
file."""

from __future__ import annotations

import numpy as np
import pytest

from arteq.io.scans import ScanError, lzf_decompress, read_scan


def lzf_compress(data: bytes) -> bytes:
    """A greedy LZF encoder (3-byte prefixes, the last position of each), to make compressed test files."""
    out, lit, table, i, n = bytearray(), bytearray(), {}, 0, len(data)

    def flush() -> None:
        while lit:
            out.append(min(32, len(lit)) - 1)
            out.extend(lit[:32])
            del lit[:32]

    while i < n:
        ref = table.get(data[i : i + 3]) if i + 3 <= n else None
        if i + 3 <= n:
            table[data[i : i + 3]] = i
        if ref is not None and i - ref - 1 < 8192:
            length = 3
            while length < min(264, n - i) and data[ref + length] == data[i + length]:
                length += 1
            flush()
            off, code = i - ref - 1, length - 2
            out.append((min(code, 7) << 5) | (off >> 8))
            if code >= 7:
                out.append(code - 7)
            out.append(off & 0xFF)
            i += length
        else:
            lit.append(data[i])
            i += 1
    flush()
    return bytes(out)


#: (name, TYPE, SIZE, COUNT): what depth-camera tools write around x y z
FIELDS = [("x", "F", 4, 1), ("y", "F", 4, 1), ("z", "F", 4, 1), ("rgb", "U", 4, 1), ("normal", "F", 4, 3),
          ("label", "U", 1, 1)]  # fmt: skip
DTYPES = {("F", 4): "<f4", ("U", 4): "<u4", ("U", 1): "u1", ("F", 8): "<f8", ("I", 2): "<i2"}


def write_pcd(path, cols, mode, width, height=1, viewpoint=None, fields=FIELDS) -> None:
    n = width * height
    head = [
        "# .PCD v0.7 - Point Cloud Data file format", "VERSION 0.7",
        "FIELDS " + " ".join(f[0] for f in fields), "SIZE " + " ".join(str(f[2]) for f in fields),
        "TYPE " + " ".join(f[1] for f in fields), "COUNT " + " ".join(str(f[3]) for f in fields),
        f"WIDTH {width}", f"HEIGHT {height}",
        "VIEWPOINT " + " ".join(str(v) for v in (viewpoint or (0, 0, 0, 1, 0, 0, 0))), f"POINTS {n}",
        f"DATA {mode}",
    ]  # fmt: skip
    arrays = [np.asarray(cols[f[0]], dtype=DTYPES[f[1], f[2]]).reshape(n, f[3]) for f in fields]
    if mode == "ascii":
        body = "\n".join(" ".join(repr(float(v)) if a.dtype.kind == "f" else str(int(v)) for a in arrays
                                  for v in a[i]) for i in range(n)).encode()  # fmt: skip
    elif mode == "binary":
        rec = np.dtype([(f[0], DTYPES[f[1], f[2]], (f[3],)) for f in fields])
        table = np.zeros(n, rec)
        for f, a in zip(fields, arrays):
            table[f[0]] = a
        body = table.tobytes()
    else:
        raw = b"".join(a.tobytes() for a in arrays)  # field after field
        packed = lzf_compress(raw)
        body = np.array([len(packed), len(raw)], "<u4").tobytes() + packed
    path.write_bytes(("\n".join(head) + "\n").encode() + body)


@pytest.fixture()
def cols():
    rng = np.random.default_rng(0)
    n = 600
    xyz = rng.normal(size=(n, 3)).astype(np.float32)
    xyz[::7] = xyz[3]  # repeats, so the compressor finds back references
    return {"x": xyz[:, 0], "y": xyz[:, 1], "z": xyz[:, 2], "rgb": rng.integers(0, 2**24, n),
            "normal": rng.normal(size=(n, 3)), "label": rng.integers(0, 255, n)}  # fmt: skip


def test_lzf_decodes_literal_runs_and_overlapping_back_references():
    # by hand from the format: a literal 'a', then 9 bytes from 1 back (length code 7 + 0 extra)
    assert lzf_decompress(b"\x00a\xe0\x00\x00", 10) == b"a" * 10
    # 'abc', then 6 bytes from 3 back (length code 4, offset 2)
    assert lzf_decompress(b"\x02abc\x80\x02", 9) == b"abcabcabc"
    rng = np.random.default_rng(1)
    for data in (bytes(rng.integers(0, 4, 5000, dtype=np.uint8)), bytes(300) + b"xyz" * 200, b"q"):
        packed = lzf_compress(data)
        assert lzf_decompress(packed, len(data)) == data
    assert len(lzf_compress(bytes(3000))) < 50  # the encoder does compress, so references are exercised
    with pytest.raises(ValueError, match="outside the output"):
        lzf_decompress(b"\x20\x05", 8)  # a reference before the first byte
    with pytest.raises(ValueError, match="header says"):
        lzf_decompress(b"\x00a", 2)
    with pytest.raises(ValueError, match="overruns"):
        lzf_decompress(b"\x05ab", 6)


@pytest.mark.parametrize("mode", ["ascii", "binary", "binary_compressed"])
def test_reads_the_xyz_of_every_data_mode(tmp_path, cols, mode):
    write_pcd(tmp_path / "scan.pcd", cols, mode, width=600)
    scan = read_scan(tmp_path / "scan.pcd")
    want = np.stack([cols[a] for a in "xyz"], 1).astype(np.float64)
    assert scan.points.dtype == np.float64 and scan.kind == "cloud"
    np.testing.assert_array_equal(scan.points, want)
    assert scan.viewpoint is None  # an unorganized cloud seen from the default viewpoint: no camera known


def test_an_organized_cloud_keeps_its_nan_pixels_and_gives_its_camera(tmp_path, cols):
    cols = dict(cols)
    cols["x"] = cols["x"].copy()
    cols["x"][::5] = np.nan  # pixels without depth
    write_pcd(tmp_path / "kinect.pcd", cols, "binary_compressed", width=30, height=20)
    scan = read_scan(tmp_path / "kinect.pcd")
    assert np.isnan(scan.points[::5, 0]).all() and len(scan.points) == 600
    np.testing.assert_array_equal(scan.viewpoint, [0.0, 0.0, 0.0])  # the origin of the camera's frame
    write_pcd(tmp_path / "posed.pcd", cols, "binary", width=600, viewpoint=(1.5, -2, 0.25, 1, 0, 0, 0))
    np.testing.assert_array_equal(read_scan(tmp_path / "posed.pcd").viewpoint, [1.5, -2.0, 0.25])


def test_x_y_z_in_other_types_and_orders(tmp_path):
    fields = [("intensity", "F", 8, 1), ("z", "F", 8, 1), ("y", "I", 2, 1), ("x", "F", 4, 1)]
    rng = np.random.default_rng(2)
    cols = {"intensity": rng.random(50), "z": rng.random(50), "y": rng.integers(-900, 900, 50),
            "x": rng.random(50).astype(np.float32)}  # fmt: skip
    for mode in ("ascii", "binary", "binary_compressed"):
        write_pcd(tmp_path / f"{mode}.pcd", cols, mode, width=50, fields=fields)
        got = read_scan(tmp_path / f"{mode}.pcd").points
        np.testing.assert_allclose(got, np.stack([cols["x"], cols["y"], cols["z"]], 1), rtol=1e-15)


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda b: b.replace(b"DATA binary", b"DATA gzip"), "is not ascii, binary or binary_compressed"),
        (lambda b: b.split(b"DATA")[0], "no DATA line"),
        (lambda b: b.replace(b"FIELDS x y z", b"FIELDS x y w"), "has no z field"),
        (lambda b: b.replace(b"SIZE 4 4 4 4", b"SIZE 4 4 3 4"), "not TYPE F/I/U"),
        (lambda b: b.replace(b"WIDTH 600", b"WIDTH many"), "not a number"),
        (lambda b: b.replace(b"TYPE F F F U F U\n", b""), "no TYPE line"),
        (lambda b: b.replace(b"COUNT 1 1 1 1 3 1", b"COUNT 1 1 1 1 3"), "differ in length"),
        (lambda b: b[:-100], "600 points need"),
        (lambda b: b.replace(b"VIEWPOINT 0 0 0 1 0 0 0", b"VIEWPOINT 0 0 0"), "expected 7"),
    ],
)
def test_bad_pcd_files_say_what_is_wrong(tmp_path, cols, edit, message):
    write_pcd(tmp_path / "ok.pcd", cols, "binary", width=600)
    (tmp_path / "bad.pcd").write_bytes(edit((tmp_path / "ok.pcd").read_bytes()))
    with pytest.raises(ScanError, match=message) as err:
        read_scan(tmp_path / "bad.pcd")
    assert str(err.value).startswith(str(tmp_path / "bad.pcd"))


def test_corrupt_compressed_data_and_ascii_words(tmp_path, cols):
    write_pcd(tmp_path / "c.pcd", cols, "binary_compressed", width=600)
    raw = bytearray((tmp_path / "c.pcd").read_bytes())
    start = raw.index(b"binary_compressed\n") + len(b"binary_compressed\n")
    raw[start + 4 : start + 8] = np.array(
        [1234], "<u4"
    ).tobytes()  # an uncompressed size the fields cannot have
    (tmp_path / "size.pcd").write_bytes(bytes(raw))
    with pytest.raises(ScanError, match="600 points need"):
        read_scan(tmp_path / "size.pcd")
    raw = bytearray((tmp_path / "c.pcd").read_bytes())
    raw[start + 8] = 0x20  # the first token turned into a back reference before the first byte
    (tmp_path / "corrupt.pcd").write_bytes(bytes(raw))
    with pytest.raises(ScanError, match="compressed data are corrupt"):
        read_scan(tmp_path / "corrupt.pcd")
    write_pcd(tmp_path / "a.pcd", cols, "ascii", width=600)
    text = (tmp_path / "a.pcd").read_bytes()
    head, body = text.split(b"DATA ascii\n")
    (tmp_path / "words.pcd").write_bytes(head + b"DATA ascii\n" + body.replace(b" ", b" oops ", 1))
    with pytest.raises(ScanError, match="not a number"):
        read_scan(tmp_path / "words.pcd")
