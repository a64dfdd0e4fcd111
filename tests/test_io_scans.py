"""Scan readers (arteq.io.scans) and atomic writers (arteq.io.fits): every format, every bad file."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from arteq.io.fits import AtomicFiles, obj_bytes, remove_stale_tmp
from arteq.io.scans import ScanError, check_body_size, clean_points, expand_inputs, read_scan


@pytest.fixture()
def cloud():
    rng = np.random.default_rng(0)
    return rng.normal(size=(500, 3)) * [0.2, 0.8, 0.1]


def test_reads_every_cloud_format(tmp_path, cloud):
    files = {
        "a.npy": lambda p: np.save(p, cloud),
        "b.npz": lambda p: np.savez(p, points=cloud),
        "c.xyz": lambda p: np.savetxt(p, cloud),
        "d.txt": lambda p: p.write_text(
            "# x y z r g b\n" + "\n".join(f"{a},{b},{c},1,2,3" for a, b, c in cloud)
        ),
        "e.ply": lambda p: p.write_bytes(trimesh.PointCloud(cloud).export(file_type="ply")),
        # a Leica-style .pts: the point count on the first line, then x y z intensity r g b
        "f.pts": lambda p: p.write_text(
            f"{len(cloud)}\n" + "\n".join(f"{a} {b} {c} -1200 80 90 100" for a, b, c in cloud)
        ),
    }
    for name, write in files.items():
        write(tmp_path / name)
        scan = read_scan(tmp_path / name)
        assert scan.kind == "cloud", name
        np.testing.assert_allclose(scan.points, cloud, atol=1e-5, err_msg=name)


@pytest.mark.parametrize("fmt", ["ply", "obj", "off", "stl", "glb"])
def test_reads_meshes_by_sampling_their_surface(tmp_path, fmt):
    box = trimesh.creation.box(extents=(0.4, 1.7, 0.3))
    path = tmp_path / f"m.{fmt}"
    data = box.export(file_type=fmt)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    scan = read_scan(path, mesh_samples=3000)
    assert scan.kind == "mesh" and scan.points.shape == (3000, 3) and scan.num_faces == 12
    # every sample lies on the box surface
    half = np.array([0.2, 0.85, 0.15])
    on_face = np.isclose(np.abs(scan.points), half, atol=1e-5).any(1)
    assert on_face.all() and (np.abs(scan.points) <= half + 1e-5).all()


def test_npz_key(tmp_path, cloud):
    np.savez(tmp_path / "k.npz", xyz=cloud)
    with pytest.raises(
        ScanError,
        match=r"k\.npz: no array 'points' in the \.npz \(it holds \['xyz'\]\); name the key with --key",
    ):
        read_scan(tmp_path / "k.npz")
    np.testing.assert_allclose(read_scan(tmp_path / "k.npz", key="xyz").points, cloud)


@pytest.mark.parametrize(
    ("name", "content", "message"),
    [
        ("empty.ply", b"", r"empty\.ply: empty file"),
        ("empty.xyz", b"", r"empty\.xyz: empty file"),
        ("garbage.ply", b"this is not a ply file\n" * 20, r"garbage\.ply: not a readable PLY file"),
        ("bad.npy", b"\x93NUMPY garbage", r"bad\.npy: not a readable \.npy file"),
        ("words.xyz", b"1 2 3\n4 5 x\n", r"words\.xyz: line 2 is not numbers"),
        ("short.xyz", b"1 2 3\n4 5\n", r"short\.xyz: line 2 has 2 values"),
        ("flat.xyz", b"1 2\n3 4\n", r"flat\.xyz: no points \(no 'x y z' lines\)"),
        ("scan.abc", b"1 2 3\n", r"scan\.abc: unknown file type '\.abc'"),
    ],
)
def test_bad_files_give_one_clear_line(tmp_path, name, content, message):
    (tmp_path / name).write_bytes(content)
    with pytest.raises(ScanError, match=message) as err:
        read_scan(tmp_path / name)
    assert "\n" not in str(err.value)


def test_truncated_ply(tmp_path, cloud):
    data = trimesh.PointCloud(cloud).export(file_type="ply")
    (tmp_path / "cut.ply").write_bytes(data[: len(data) // 2])
    with pytest.raises(ScanError, match=r"cut\.ply: not a readable PLY file"):
        read_scan(tmp_path / "cut.ply")


def test_wrong_array_shape(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros(30))
    with pytest.raises(ScanError, match=r"flat\.npy: array has shape \[30\], expected \[N, 3\]"):
        read_scan(tmp_path / "flat.npy")


def test_nan_rows_are_dropped_and_all_nan_is_an_error(cloud):
    bad = cloud.copy()
    bad[::10, 1] = np.nan
    bad[5, 0] = np.inf
    pts, keep = clean_points(bad, "x.ply")
    assert len(pts) == len(cloud) - 51 and np.isfinite(pts).all() and keep.sum() == len(pts)
    with pytest.raises(ScanError, match="x.ply: every point has NaN or inf"):
        clean_points(np.full((10, 3), np.nan), "x.ply")


def test_units_check_suggests_the_flag():
    rng = np.random.default_rng(1)
    body_mm = rng.normal(size=(2000, 3)) * [100, 450, 80]  # ~1.7 m tall body written in millimetres
    with pytest.raises(ScanError, match=r"s\.ply: the cloud is \d+ m across.*pass --units mm"):
        check_body_size(body_mm, "s.ply", "m")
    assert 1.2 < check_body_size(body_mm * 0.001, "s.ply", "mm") < 2.5
    with pytest.raises(ScanError, match="pass --units m"):
        check_body_size(body_mm * 0.001 * 0.01, "s.ply", "cm")  # metres given as cm: 100x too small
    # inches and feet (US scanners' and CAD exports' units): named in the hint, accepted with the flag
    for unit, scale in (("in", 0.0254), ("ft", 0.3048)):
        with pytest.raises(ScanError, match=rf"the cloud is [\d.]+ m across.*pass --units {unit}\b"):
            check_body_size(body_mm * 0.001 / scale, "s.ply", "m")
        assert 1.2 < check_body_size(body_mm * 0.001, "s.ply", unit) < 2.5
    # 80 units across: inches for an adult, centimetres for a child; both named, the nearer to 1.7 m first
    with pytest.raises(ScanError, match=r"pass --units in \(in cm: --units cm\)$"):
        check_body_size(body_mm * 0.001 / 0.0254, "s.ply", "m")


def test_expand_inputs_folders_globs_and_missing(tmp_path, cloud):
    (tmp_path / "a" / "b").mkdir(parents=True)
    np.save(tmp_path / "a" / "x.npy", cloud)
    np.save(tmp_path / "a" / "b" / "y.npy", cloud)
    (tmp_path / "a" / "notes.md").write_text("hi")
    files, problems = expand_inputs([tmp_path / "a", str(tmp_path / "a" / "*.npy"), tmp_path / "nope.ply"])
    assert [f.name for f in files] == ["y.npy", "x.npy"]
    assert problems == [(str(tmp_path / "nope.ply"), f"{tmp_path / 'nope.ply'}: no such file or folder")]


def test_atomic_group_leaves_nothing_on_failure(tmp_path):
    v = np.zeros((3, 3))
    f = np.array([[0, 1, 2]])
    with pytest.raises(RuntimeError, match="boom"):
        with AtomicFiles() as files:
            files.write_bytes(tmp_path / "a.obj", obj_bytes(v, f))
            files.write(tmp_path / "b.png", lambda tmp: (_ for _ in ()).throw(RuntimeError("boom")))
    assert list(tmp_path.iterdir()) == []
    with AtomicFiles() as files:
        files.write_bytes(tmp_path / "a.obj", obj_bytes(v, f))
        assert not (tmp_path / "a.obj").exists()  # only renamed into place at the end
    assert (tmp_path / "a.obj").read_text().count("\nf 1 2 3") == 1
    (tmp_path / ".x.obj.123.tmp").write_text("left by a killed run")
    assert remove_stale_tmp(tmp_path) == 1 and [p.name for p in tmp_path.iterdir()] == ["a.obj"]


def test_obj_bytes_is_savetxt_text_and_reads_back():
    """The fit's OBJ: the text ``np.savetxt`` writes for ``v %.6g`` / ``f %d`` rows (1-based faces), the
    header as comments; trimesh reads back the vertices (to 6 significant digits) and the faces."""
    import io

    import trimesh

    rng = np.random.default_rng(1)
    v = (rng.normal(size=(300, 3)) * 100).astype(np.float32)
    f = rng.integers(0, 300, (500, 3))
    ref = io.StringIO()
    ref.write("# fit of a\n# units m\n")
    np.savetxt(ref, v.astype(np.float64), fmt="v %.6g %.6g %.6g")
    np.savetxt(ref, f + 1, fmt="f %d %d %d")
    data = obj_bytes(v, f, "fit of a\nunits m")
    assert data == ref.getvalue().encode()
    mesh = trimesh.load(io.BytesIO(data), file_type="obj", process=False)
    np.testing.assert_allclose(mesh.vertices, v, rtol=1e-5)
    np.testing.assert_array_equal(mesh.faces, f)
