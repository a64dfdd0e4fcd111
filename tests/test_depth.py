"""Depth images in (arteq.fit.depth): 16-bit PNGs in millimetres and .npy in metres, intrinsics from the
command line or a JSON beside the image, the person's depth band, errors naming the file; and arteq-fit on
a depth image (partial mode from the file's camera, parts seen)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch
from PIL import Image

from arteq.data.single_view import look_at, rasterize
from arteq.fit.depth import DepthOptions, is_depth_file, read_depth, write_depth_png
from arteq.io.scans import ScanError

F, W, H = 200.0, 96, 128
#: OpenCV convention (first pixel centre at 0) for the rasteriser's image (first pixel centre at 0.5).
INTR = {"fx": F, "fy": F, "cx": W / 2 - 0.5, "cy": H / 2 - 0.5}


@pytest.fixture(scope="module")
def body_depth(anny22):
    """A depth image ``[H, W]`` metres of the rest body 2.5 m in front of the camera, and the body's points
    in the camera frame (each pixel's exact surface point)."""
    out = anny22(betas=torch.zeros(1, 10), pose=torch.eye(3).expand(1, 22, 3, 3))
    v = out.vertices[0].double()
    cam = torch.tensor([0.0, 0.0, 2.5], dtype=torch.float64) + out.joints[0, 0].double()
    rot = look_at(cam, out.joints[0, 0].double(), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    vc = (v - cam) @ rot.T
    face, bary, depth = rasterize(vc, anny22.faces, F, W, H, W / 2, H / 2)
    pts = (bary[..., None] * vc[anny22.faces[face.clamp_min(0)]]).sum(-2)[face >= 0]
    return depth.numpy(), pts.numpy()


def test_a_png_in_millimetres_back_projects_onto_the_surface(body_depth, tmp_path):
    depth, truth = body_depth
    path = tmp_path / "person.png"
    write_depth_png(path, np.where(np.isfinite(depth), depth, 0.0))
    assert is_depth_file(path)
    scan = read_depth(path, DepthOptions(intrinsics=INTR))
    assert scan.points.shape == truth.shape and scan.pixels_kept == len(truth)
    assert np.abs(scan.points - truth).max() < 0.0006  # millimetre rounding (0.5 mm), nothing else
    np.testing.assert_array_equal(scan.viewpoint, np.zeros(3))
    # each point's pixel: its depth there, and the image's surface pixels in row-major order
    v, u = scan.pixels.T
    assert np.abs(scan.points[:, 2] - depth[v, u]).max() < 0.0006
    np.testing.assert_array_equal(scan.pixels, np.argwhere(np.isfinite(depth)))


def test_npy_in_metres_with_intrinsics_from_a_json_beside_it(body_depth, tmp_path):
    depth, truth = body_depth
    img = np.where(np.isfinite(depth), depth, np.nan).astype(np.float32)
    wall = ~np.isfinite(depth)
    wall[5:] = False
    img[wall] = 6.0  # a far wall at the top of the image, around the head: outside the person's band
    np.save(tmp_path / "frame.npy", img)
    (tmp_path / "frame.json").write_text(json.dumps(INTR))
    assert is_depth_file(tmp_path / "frame.npy")
    scan = read_depth(tmp_path / "frame.npy")
    assert len(scan.points) == len(truth) and scan.depth_range_m[1] < 6.0
    assert np.abs(scan.points - truth).max() < 1e-5
    # a shared intrinsics.json, and command-line values winning over it
    (tmp_path / "frame.json").unlink()
    (tmp_path / "intrinsics.json").write_text(json.dumps(INTR | {"fx": 1.0}))
    scan2 = read_depth(tmp_path / "frame.npy", DepthOptions(intrinsics={"fx": F}))
    assert np.abs(scan2.points - truth).max() < 1e-5
    wide = read_depth(tmp_path / "frame.npy", DepthOptions(intrinsics=INTR, depth_range_m=(0.5, 7.0)))
    assert wide.pixels_kept == len(truth) + wall.sum() > len(truth)
    np.save(tmp_path / "cloud.npy", truth)  # an [N, 3] point list stays a point file
    assert not is_depth_file(tmp_path / "cloud.npy")


def test_bad_depth_images_say_what_is_wrong_and_name_the_file(tmp_path):
    good = np.full((8, 8), 1500, dtype=np.uint16)
    Image.fromarray(good).save(tmp_path / "nointr.png")
    with pytest.raises(ScanError, match=r"nointr\.png: camera intrinsics missing \(fx, fy, cx, cy\)"):
        read_depth(tmp_path / "nointr.png")
    with pytest.raises(ScanError, match=r"nointr\.png: camera intrinsics missing \(cy\)"):
        read_depth(tmp_path / "nointr.png", DepthOptions(intrinsics={"fx": 1, "fy": 1, "cx": 1}))
    opts = DepthOptions(intrinsics=INTR)
    Image.fromarray((good // 10).astype(np.uint8)).save(tmp_path / "eight.png")
    with pytest.raises(ScanError, match=r"eight\.png: a 8-bit grayscale PNG; a depth image is a 16-bit"):
        read_depth(tmp_path / "eight.png", opts)
    Image.fromarray(np.zeros((8, 8, 3), dtype=np.uint8)).save(tmp_path / "rgb.png")
    with pytest.raises(ScanError, match=r"rgb\.png: a 8-bit RGB PNG"):
        read_depth(tmp_path / "rgb.png", opts)
    Image.fromarray(np.zeros((8, 8), dtype=np.uint16)).save(tmp_path / "zero.png")
    with pytest.raises(ScanError, match=r"zero\.png: depth image has no valid pixels"):
        read_depth(tmp_path / "zero.png", opts)
    np.save(tmp_path / "ints.npy", good)
    with pytest.raises(
        ScanError, match=r"ints\.npy: depth \.npy has dtype uint16, expected floats in metres"
    ):
        read_depth(tmp_path / "ints.npy", opts)
    (tmp_path / "fake.png").write_bytes(b"not a png at all, not at all")
    with pytest.raises(ScanError, match=r"fake\.png: not a PNG file"):
        read_depth(tmp_path / "fake.png", opts)
    (tmp_path / "bad.json").write_text("{fx: 1")
    Image.fromarray(good).save(tmp_path / "bad.png")
    with pytest.raises(ScanError, match=r"bad\.json: camera intrinsics JSON is not readable"):
        read_depth(tmp_path / "bad.png")
    with pytest.raises(ScanError, match=r"nointr\.png: no pixel within the depth range 2-3 m"):
        read_depth(tmp_path / "nointr.png", DepthOptions(intrinsics=INTR, depth_range_m=(2.0, 3.0)))
    with pytest.raises(ScanError, match="fx and fy must be positive"):
        read_depth(tmp_path / "nointr.png", DepthOptions(intrinsics=INTR | {"fy": 0}))


def test_arteq_fit_reads_a_depth_image_and_fits_it_as_one_camera_s_view(body_depth, tmp_path):
    from omegaconf import OmegaConf

    from arteq.fit.cli import main as cli_main
    from conftest import compose_config
    from fit_helpers import write_tiny_checkpoint
    from test_single_view_parts import TINY

    net = OmegaConf.to_container(compose_config(["model=arteq", *TINY]).model.net, resolve=True)
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", net)
    depth, _ = body_depth
    scans = tmp_path / "scans"
    scans.mkdir()
    write_depth_png(scans / "kinect.png", np.where(np.isfinite(depth), depth, 0.0))
    Image.fromarray(np.zeros((4, 4, 3), dtype=np.uint8)).save(scans / "photo.png")  # not a depth image
    (scans / "broken.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 30)  # not a depth image either
    base = [str(scans), "--out", str(tmp_path / "fits"), "--ckpt", str(ckpt), "--no-check", "--no-preview",
            "--iters", "2", "--points", "1000", "--no-anny", "--no-progress"]  # fmt: skip
    intr = ["--fx", str(F), "--fy", str(F), "--cx", str(INTR["cx"]), "--cy", str(INTR["cy"])]
    assert cli_main(base + intr) == 0
    summary = json.loads((tmp_path / "fits" / "summary.json").read_text())
    assert [r["name"] for r in summary["inputs"]] == ["kinect"]  # the folder's one 16-bit PNG
    row = summary["inputs"][0]
    assert row["scan_mode"] == "partial" and isinstance(row["parts_seen"], int)
    npz = np.load(tmp_path / "fits" / "kinect.npz")
    assert str(npz["scan_mode"]) == "partial" and "camera" in str(npz["scan_mode_reason"])
    assert npz["parts_seen"].shape == (22,) and npz["part_points"].sum() == 1000
    assert npz["view_dir"] @ np.array([0.0, 0.0, -1.0]) > 0.9  # from the body back toward the camera
    fit = json.loads((tmp_path / "fits" / "kinect.json").read_text())
    assert set(fit["parts_seen"]) | set(fit["parts_unseen"]) == set(fit["parts_seen"] + fit["parts_unseen"])
    assert len(fit["parts_seen"]) + len(fit["parts_unseen"]) == 22
    # without intrinsics: an error naming the file, the batch goes on
    assert cli_main([*base, "--overwrite"]) == 1


def test_arteq_fit_takes_a_pcd_s_camera_organized_or_from_its_viewpoint(body_depth, tmp_path):
    """A depth camera's organized .pcd (NaN where a pixel saw nothing) is fitted as that camera's view; a
    VIEWPOINT inside the body is an error naming the file; --no-partial ignores the file's camera."""
    from omegaconf import OmegaConf

    from arteq.fit.cli import main as cli_main
    from conftest import compose_config
    from fit_helpers import write_tiny_checkpoint
    from test_io_pcd import write_pcd
    from test_single_view_parts import TINY

    net = OmegaConf.to_container(compose_config(["model=arteq", *TINY]).model.net, resolve=True)
    ckpt = write_tiny_checkpoint(tmp_path / "tiny.ckpt", net)
    depth, _ = body_depth
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    z = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    cols = {"x": (u - INTR["cx"]) * z / F, "y": (v - INTR["cy"]) * z / F, "z": z}
    xyz = [("x", "F", 4, 1), ("y", "F", 4, 1), ("z", "F", 4, 1)]
    scans = tmp_path / "scans"
    scans.mkdir()
    write_pcd(scans / "kinect.pcd", cols, "binary_compressed", W, H, fields=xyz)
    centre = np.nanmean(np.stack([cols[a] for a in "xyz"], -1).reshape(-1, 3), 0)
    write_pcd(tmp_path / "inside.pcd", cols, "binary", W, H, viewpoint=(*centre, 1, 0, 0, 0), fields=xyz)
    base = ["--out", str(tmp_path / "fits"), "--ckpt", str(ckpt), "--no-check", "--no-preview",
            "--iters", "2", "--points", "1000", "--no-anny", "--no-progress", "--overwrite"]  # fmt: skip
    assert cli_main([str(scans), *base]) == 0
    npz = np.load(tmp_path / "fits" / "kinect.npz")
    assert str(npz["scan_mode"]) == "partial" and "file's camera" in str(npz["scan_mode_reason"])
    assert npz["view_dir"] @ np.array([0.0, 0.0, -1.0]) > 0.9  # from the body back toward the camera
    assert cli_main([str(tmp_path / "inside.pcd"), *base]) == 1
    row = json.loads((tmp_path / "fits" / "summary.json").read_text())["inputs"][0]
    assert (
        row["status"] == "error"
        and "inside.pcd" in row["message"]
        and "from the body's centre" in row["message"]
    )
    assert not (tmp_path / "fits" / "inside.npz").exists()
    assert cli_main([str(tmp_path / "inside.pcd"), *base, "--no-partial"]) == 0
    assert "full" in str(np.load(tmp_path / "fits" / "inside.npz")["scan_mode_reason"])
