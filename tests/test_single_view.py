"""Single-view depth scans (arteq.data.single_view): the z-buffer, the sensor effects, the datasets and
the cached view test sets."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from arteq.data import BodyScanDataModule
from arteq.data.dataset import BodyScanDataset, seeded_generator
from arteq.data.poses import SyntheticIDPoses
from arteq.data.single_view import (
    VIEW_SPLITS,
    SingleViewConfig,
    SingleViewDataset,
    rasterize,
    single_view_scan,
)

CLEAN = {"noise_base_m": 0.0, "noise_quad": 0.0, "dropout": 0.0, "edge_dropout": 0.0, "flying": 0.0}


def _square(z: float, half: float) -> tuple[torch.Tensor, torch.Tensor]:
    v = torch.tensor(
        [[-half, -half, z], [half, -half, z], [half, half, z], [-half, half, z]], dtype=torch.float64
    )
    return v, torch.tensor([[0, 1, 2], [0, 2, 3]])


def test_zbuffer_keeps_the_nearest_surface_and_its_exact_depth():
    far_v, far_f = _square(2.0, 1.0)
    near_v, near_f = _square(1.0, 0.2)
    verts = torch.cat([far_v, near_v])
    faces = torch.cat([far_f, near_f + 4])
    face, bary, depth = rasterize(verts, faces, focal=50.0, width=64, height=64, cx=32.0, cy=32.0, cull=False)
    # culling keeps the triangles seen counter-clockwise in the image (x right, y down): these are clockwise
    culled, _, _ = rasterize(verts, faces, focal=50.0, width=64, height=64, cx=32.0, cy=32.0)
    assert (culled == -1).all()
    flipped, _, flipped_depth = rasterize(verts, faces.flip(1), 50.0, 64, 64, 32.0, 32.0)
    assert torch.equal(flipped >= 0, face >= 0)
    torch.testing.assert_close(flipped_depth, depth, rtol=0, atol=1e-12)
    centre = (32, 32)  # ray along z: both squares are on it, the near one wins
    assert face[centre] in (2, 3) and depth[centre] == pytest.approx(1.0, abs=1e-9)
    # 18.5 px off centre: x = 0.37 z, outside the near square (0.2 m at 1 m), inside the far one (1 m at 2 m)
    assert face[32, 50] in (0, 1) and depth[32, 50] == pytest.approx(2.0, abs=1e-9)
    assert face[0, 0] == -1 and math.isinf(depth[0, 0])  # the far square spans 25 px at 2 m: not the corner
    # the barycentric point lies on the pixel's ray at the returned depth
    i, j = 20, 36
    p = (bary[i, j, :, None] * verts[faces[face[i, j]]]).sum(0)
    ray = torch.tensor([(j + 0.5 - 32) / 50, (i + 0.5 - 32) / 50, 1.0], dtype=torch.float64)
    torch.testing.assert_close(p, ray * depth[i, j])


def _posed(body):
    out = body(betas=torch.zeros(1, body.num_betas), pose=torch.eye(3).expand(1, 22, 3, 3).clone())
    return out.vertices[0], out.joints[0, 0]


def _scan(body, view, seed=0, n=800, **cfg):
    verts, pelvis = _posed(body)
    config = SingleViewConfig(**cfg)
    return single_view_scan(verts, body.faces, body.lbs_weights, pelvis, torch.eye(3), n,
                            seeded_generator(seed), config, view)  # fmt: skip


def test_a_front_view_sees_the_front_and_a_back_view_the_back(anny22):
    from scipy.spatial import cKDTree

    from arteq.geometry.normals import vertex_normals

    front, back = _scan(anny22, "front", **CLEAN), _scan(anny22, "back", **CLEAN)
    verts, _ = _posed(anny22)
    normals = vertex_normals(verts[None].double(), anny22.faces)[0]
    assert front["camera"][2] > 0.9 and back["camera"][2] < -0.9  # the body faces +z
    for scan in (front, back):
        p = scan["points"]
        assert p.shape == (800, 3) and torch.isfinite(p).all()
        assert scan["labels"].min() >= 0 and scan["labels"].max() < 22
        d, nn = cKDTree(verts.numpy()).query(p.numpy())
        assert d.max() < 0.04 and float(np.median(d)) < 0.008  # on the surface (vertices ~1-4 cm apart)
        facing = ((scan["camera"] - p) * normals[nn]).sum(-1) > 0
        assert facing.float().mean() > 0.97  # only surfaces turned toward the camera
    assert front["labels"].bincount(minlength=22)[15] > 10  # the head (index 15) is seen from both sides
    assert (front["points"][:, 2].mean() - back["points"][:, 2].mean()) > 0.05


def test_a_sensor_frame_cuts_off_what_falls_outside_it(anny22):
    """frame_px: the image is the sensor's, centred on the pelvis; at 1 m a 640 x 480 frame (1.3 x 1.0 m)
    loses the feet and the head of a standing body, which the default crop (and a 4 m camera) keeps."""
    from arteq.data.single_view import look_at

    cut = _scan(anny22, "front", distance_m=(1.0, 1.0), frame_px=(640, 480), **CLEAN)
    whole = _scan(anny22, "front", distance_m=(1.0, 1.0), **CLEAN)
    far = _scan(anny22, "front", distance_m=(4.0, 4.0), frame_px=(640, 480), **CLEAN)
    head, feet = 15, (10, 11)
    for scan in (whole, far):
        seen = scan["labels"].bincount(minlength=22)
        assert seen[head] > 5 and all(seen[f] > 0 for f in feet)
    seen = cut["labels"].bincount(minlength=22)
    assert seen[head] == 0 and all(seen[f] == 0 for f in feet) and seen[0] > 20  # the pelvis stays
    _, pelvis = _posed(anny22)
    rot = look_at(cut["camera"], pelvis.double(), torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
    pc = (cut["points"] - cut["camera"]) @ rot.T
    uv = pc[:, :2] / pc[:, 2:3] * 500.0
    assert (uv[:, 0].abs() <= 320 + 1).all() and (uv[:, 1].abs() <= 240 + 1).all()  # inside the frame
    assert SingleViewConfig().to_dict() == SingleViewConfig(frame_px=None).to_dict()
    # the view sets cached before the option keep their keys
    assert "frame_px" not in SingleViewConfig().to_dict()
    for bad in ((640,), (0, 480), (640.5, 480)):
        with pytest.raises(ValueError, match="frame_px"):
            SingleViewConfig(frame_px=bad)
    # frame_prob: a share of the views framed, each its own draw
    cuts = [
        _scan(anny22, "front", seed=s, distance_m=(1.0, 1.0), frame_px=(640, 480), frame_prob=0.5, **CLEAN)[
            "labels"].bincount(minlength=22)[head] == 0
        for s in range(8)
    ]  # fmt: skip
    assert 0 < sum(cuts) < 8, cuts
    with pytest.raises(ValueError, match="frame_prob"):
        SingleViewConfig(frame_prob=1.5)


def test_noise_grows_with_depth(anny22):
    def spread(dist):
        exact = _scan(anny22, "front", seed=3, distance_m=(dist, dist), **CLEAN)["points"]
        noisy = _scan(anny22, "front", seed=3, distance_m=(dist, dist),
                      **(CLEAN | {"noise_base_m": 0.001, "noise_quad": 0.001}))["points"]  # fmt: skip
        return float((noisy - exact).norm(dim=-1).median())

    near, far = spread(1.0), spread(4.0)
    # sigma = 1 mm + 1 mm * z^2: 2 mm at 1 m, 17 mm at 4 m (median |N(0, s^2)| = 0.67 s)
    assert 0.0008 < near < 0.0025 and 0.007 < far < 0.02, (near, far)


def test_sensor_effects_drop_pixels_and_make_flying_pixels(anny22):
    clean = _scan(anny22, "side", seed=1, **CLEAN)
    drop = _scan(anny22, "side", seed=1, **(CLEAN | {"dropout": 0.5}))
    assert drop["pixels"] < 0.6 * clean["pixels"]
    fly = _scan(anny22, "side", seed=1, n=4000, **(CLEAN | {"flying": 1.0, "flying_max_m": 0.2}))
    ref = _scan(anny22, "side", seed=1, n=4000, **CLEAN)
    cam = ref["camera"]
    # flying pixels lie behind the surface along the ray: the cloud's farthest points move away
    assert (fly["points"] - cam).norm(dim=-1).max() > (ref["points"] - cam).norm(dim=-1).max() + 0.05


def test_scans_are_deterministic_and_resampled_to_the_point_count(toy_body):
    a, b = _scan(toy_body, "any", seed=5, n=300), _scan(toy_body, "any", seed=5, n=300)
    torch.testing.assert_close(a["points"], b["points"], rtol=0, atol=0)
    c = _scan(toy_body, "any", seed=6, n=300)
    assert not torch.allclose(a["camera"], c["camera"])
    many = _scan(toy_body, "front", seed=5, n=20000, distance_m=(4.0, 4.0), focal_px=100.0)
    assert many["points"].shape == (20000, 3) and many["pixels"] < 20000  # repeats, jittered apart
    assert torch.unique(many["points"], dim=0).shape[0] == 20000


def test_views_place_the_camera_where_they_say(toy_body):
    for view, (lo, hi) in {"top": (60, 90), "front": (-10, 30)}.items():
        for seed in range(4):
            cam = _scan(toy_body, view, seed=seed, n=50)["camera"]
            _, pelvis = _posed(toy_body)
            d = cam - pelvis
            el = math.degrees(math.asin(float(d[1] / d.norm())))
            assert lo - 1e-6 <= el <= hi + 1e-6 and 1.0 <= float(d.norm()) <= 4.0
    with pytest.raises(ValueError, match="view"):
        _scan(toy_body, "below", n=50)
    with pytest.raises(ValueError, match="unknown keys"):
        SingleViewConfig.from_mapping({"focal": 3})
    with pytest.raises(ValueError, match="dropout"):
        SingleViewConfig(dropout=1.5)


def test_a_single_view_dataset_sample_has_the_full_samplers_keys_and_ground_truth(toy_body):
    kw = {"num_points": 200, "seed": 1}
    full = BodyScanDataset(SyntheticIDPoses(), toy_body, "test_id", 4, **kw)
    view = SingleViewDataset(SyntheticIDPoses(), toy_body, "test_id", 4, view="front", **kw)
    a, b = full[2], view[2]
    assert set(a) == set(b)
    for k in ("pose", "betas", "global_rotmats"):
        torch.testing.assert_close(a[k], b[k], rtol=0, atol=0)  # same body, another cloud
    assert b["points"].shape == (200, 3)
    torch.testing.assert_close(b["points"].mean(0), torch.zeros(3), rtol=0, atol=1e-5)  # centred
    # ground truth in the centred frame: transl + center is the scan frame's translation in both
    torch.testing.assert_close(a["transl"] + a["center"], b["transl"] + b["center"], rtol=0, atol=1e-5)
    mixed = SingleViewDataset(SyntheticIDPoses(), toy_body, "train", 40,
                              config=SingleViewConfig(prob=0.5), **kw)  # fmt: skip
    plain = BodyScanDataset(SyntheticIDPoses(), toy_body, "train", 40, **kw)
    same = [torch.equal(mixed[i]["points"], plain[i]["points"]) for i in range(40)]
    assert 8 <= sum(same) <= 32  # about half the clouds are the full sampler's, unchanged


def test_view_test_sets_are_cached_and_off_by_default(toy_body, tmp_path):
    kw = {"body_model": toy_body, "num_points": 64, "test_size": 3, "val_size": 2, "train_size": 4,
          "batch_size": 3, "cache_root": str(tmp_path)}  # fmt: skip
    plain = BodyScanDataModule(**kw)
    assert plain.view_splits == () and plain.view_dataloaders() == {}
    id_path = plain.cache_path("test_id")
    dm = BodyScanDataModule(**kw, view_splits=["test_view_top", "test_view_front"],
                            single_view={"prob": 0.3, "focal_px": 400.0})  # fmt: skip
    assert dm.cache_path("test_id") == id_path  # single-view options leave the other sets' files alone
    assert dm.view_splits == ("test_view_front", "test_view_top")  # VIEW_SPLITS order
    loaders = dm.view_dataloaders()
    assert sorted(dm.generated) == ["test_view_front", "test_view_top"]
    front, top = (next(iter(loaders[s])) for s in dm.view_splits)
    assert front["points"].shape == (3, 64, 3)
    torch.testing.assert_close(front["pose"], top["pose"], rtol=0, atol=0)  # the same bodies
    assert not torch.allclose(front["points"], top["points"])
    again = BodyScanDataModule(**kw, view_splits=["test_view_front"], single_view={"focal_px": 400.0})
    again.view_dataloaders()
    assert again.generated == []  # loaded from the cache (prob does not define a view set)
    assert isinstance(dm.make_dataset("train"), SingleViewDataset)
    assert not isinstance(plain.make_dataset("train"), SingleViewDataset)
    with pytest.raises(ValueError, match="view_splits"):
        BodyScanDataModule(body_model=toy_body, view_splits=["test_view_under"])
    assert set(VIEW_SPLITS) == {f"test_view_{v}" for v in ("front", "side", "back", "top", "near")}


def test_the_data_config_builds_view_sets():
    from conftest import compose_config

    cfg = compose_config(["data.view_splits=[test_view_side]", "data.single_view.prob=0.25"])
    assert list(cfg.data.view_splits) == ["test_view_side"] and cfg.data.single_view.prob == 0.25
    assert list(compose_config([]).data.view_splits) == [] and compose_config([]).data.single_view.prob == 0


@pytest.mark.slow
def test_a_training_run_on_single_view_clouds_runs_end_to_end(tmp_path):
    """``data.single_view.prob=1``: every training cloud a single-view scan, through the training command."""
    import subprocess
    import sys

    from conftest import subprocess_env

    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "arteq.train", "+experiment=stage1", "+scale=tiny", "+tiny_net=arteq",
           "data.single_view.prob=1.0", f"paths.output_dir={out}", f"hydra.run.dir={tmp_path / 'hydra'}",
           f"data.cache_root={tmp_path / 'cache'}"]  # fmt: skip
    res = subprocess.run(cmd, env=subprocess_env(), capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert (out / "metrics.json").is_file()


def test_a_limb_reaching_past_the_camera_is_cut_at_the_minimum_range(toy_body):
    # A limb of a wide pose can reach the camera or pass behind it (a crash in training: projecting a
    # vertex at depth ~0 asked for a 2 TB image). Nearer than NEAR_M nothing is measured, and the crop
    # stays bounded.
    from arteq.body.skeleton import JOINT_NAMES
    from arteq.data.single_view import MAX_IMAGE_PX, NEAR_M

    verts, pelvis = _posed(toy_body)
    verts = verts.double().clone()
    cfg = SingleViewConfig(distance_m=(1.0, 1.0))

    def scan_of(v):
        return single_view_scan(v, toy_body.faces, toy_body.lbs_weights, pelvis, torch.eye(3), 300,
                                seeded_generator(1), cfg, "front")  # fmt: skip

    cam = scan_of(verts)["camera"]  # the same seed puts the camera at the same place
    axis = (pelvis.double() - cam) / (pelvis.double() - cam).norm()
    hand = toy_body.lbs_weights.argmax(1) == JOINT_NAMES.index("left_wrist")
    # the hand moved onto the camera's plane (depth 1 um: its projection ~1e8 px away) and half of it past
    depth = (verts[hand] - cam) @ axis
    shift = torch.where(torch.arange(int(hand.sum())) % 2 == 0, 1e-6, -0.2) - depth
    verts[hand] += shift[:, None] * axis
    scan = scan_of(verts)
    assert float(((verts - cam) @ axis).min()) < 0
    assert scan["points"].shape == (300, 3) and bool(torch.isfinite(scan["points"]).all())
    assert float(((scan["points"] - cam) @ axis).min()) > NEAR_M - 0.01
    assert 0 < int(scan["pixels"]) <= MAX_IMAGE_PX**2
