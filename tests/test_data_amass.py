"""AMASS reader and AMASS-backed data module on small synthetic .npz files with AMASS's keys (files named
without the subject prefix, as a user's own conversions may be; the real layouts: test_amass_layouts.py)."""

import numpy as np
import pytest
import roma
import torch

from arteq.data import AmassPoses, BodyScanDataModule, read_amass_npz


def _write(
    path, n, seed=0, keys=("poses", "betas", "trans", "gender", "mocap_framerate"), cols=156, fps=60.0
):
    rng = np.random.default_rng(seed)
    data = {
        "poses": rng.normal(0, 0.3, (n, cols)),
        "betas": rng.normal(0, 1, 16),
        "trans": rng.normal(0, 0.5, (n, 3)),
        "gender": np.array("female"),
        "mocap_framerate": np.array(fps),
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **{k: v for k, v in data.items() if k in keys})
    return data


@pytest.fixture()
def amass_root(tmp_path):
    for subj in ("50002", "50004"):
        for m, n in (
            ("jumping_jacks", 40),
            ("punching", 100),
            ("shake_shoulders", 20),
            ("chicken_wings", 60),
        ):
            _write(tmp_path / "DFaust_67" / subj / f"{m}_poses.npz", n, seed=hash((subj, m)) % 1000)
        np.savez(tmp_path / "DFaust_67" / subj / "shape.npz", betas=np.zeros(16), gender=np.array("male"))
    _write(tmp_path / "MPI_Limits" / "03099" / "op2_poses.npz", 50, cols=72, fps=120.0)
    return tmp_path


def test_read_amass_npz(tmp_path):
    d = _write(tmp_path / "a_poses.npz", 7)
    out = read_amass_npz(tmp_path / "a_poses.npz")
    assert out["poses"].shape == (7, 22, 3) and out["trans"].shape == (7, 3) and out["betas"].shape == (16,)
    assert np.allclose(out["poses"].reshape(7, -1), d["poses"][:, :66])
    assert out["gender"] == "female" and out["fps"] == 60.0 and out["surface_model"] == "smplh"


def test_bad_files_give_clear_errors(tmp_path):
    _write(tmp_path / "nokeys_poses.npz", 5, keys=("poses", "betas", "mocap_framerate"))
    with pytest.raises(ValueError, match=r"nokeys_poses\.npz: not an AMASS motion file, missing trans "):
        read_amass_npz(tmp_path / "nokeys_poses.npz")
    _write(tmp_path / "short_poses.npz", 5, cols=30)
    with pytest.raises(ValueError, match=r"short_poses\.npz.*poses"):
        read_amass_npz(tmp_path / "short_poses.npz")
    (tmp_path / "junk_poses.npz").write_bytes(b"not a zip")
    with pytest.raises(ValueError, match="junk_poses.npz"):
        read_amass_npz(tmp_path / "junk_poses.npz")
    with pytest.raises(FileNotFoundError, match="missing_poses.npz"):
        read_amass_npz(tmp_path / "missing_poses.npz")
    with pytest.raises(FileNotFoundError, match="AMASS root folder not found"):
        AmassPoses(tmp_path / "nope")
    with pytest.raises(FileNotFoundError, match=r"no folder of sub-dataset DFaust .*DFaust_67"):
        AmassPoses(tmp_path)  # root exists, no DFaust folder


def test_splits_crop_and_stride(amass_root):
    train = AmassPoses(amass_root, split="train")
    test = AmassPoses(amass_root, split="test")
    val = AmassPoses(amass_root, split="val")
    # train: jumping_jacks only (punching, chicken_wings test; shake_shoulders val), every frame
    assert len(train) == 2 * 40
    # test: middle 50% every 5th frame: punching 100 -> frames 25..74 -> 10; chicken_wings 60 -> 15..44 -> 6
    assert len(test) == 2 * (10 + 6)
    assert len(val) == 2 * 2  # 20 frames -> 5..14 -> 2
    assert {f.stem for f in test.files} == {"punching_poses", "chicken_wings_poses"}
    assert all(f.name != "shape.npz" for f in train.files)
    ood = AmassPoses(amass_root, datasets=["MPI_Limits", "PosePrior"], split="all", all_fps=24)
    assert len(ood) == 10  # 50 frames at 120 fps, every 5th


def test_y_up_conversion_and_betas(amass_root):
    raw = read_amass_npz(amass_root / "DFaust_67" / "50002" / "jumping_jacks_poses.npz")
    src = AmassPoses(amass_root, split="train", use_betas=True)
    zsrc = AmassPoses(amass_root, split="train", to_y_up=False)
    s = src.sample(0, torch.Generator())
    assert torch.allclose(
        zsrc.sample(0, torch.Generator())["pose"], torch.from_numpy(raw["poses"][0]).double()
    )
    rz = roma.rotvec_to_rotmat(torch.from_numpy(raw["poses"][0, 0]).double())
    ry = roma.rotvec_to_rotmat(s["pose"][0])
    q = ry @ rz.T  # the fixed world change z-up -> y-up
    assert torch.allclose(
        q @ torch.tensor([0.0, 0, 1], dtype=torch.float64),
        torch.tensor([0.0, 1, 0], dtype=torch.float64),
        atol=1e-6,
    )
    assert torch.allclose(s["pose"][1:], torch.from_numpy(raw["poses"][0, 1:]).double())
    assert s["betas"].shape == (16,) and zsrc.sample(0, torch.Generator())["betas"] is None


def test_datamodule_on_amass(amass_root, tmp_path):
    dm = BodyScanDataModule(
        source="amass",
        amass_root=str(amass_root),
        body_model={"name": "toy"},
        num_points=500,
        train_size=None,
        val_size=None,
        test_size=None,
        batch_size=4,
        cache_root=str(tmp_path / "cache"),
    )
    dm.setup("fit")
    assert len(dm.datasets["train"]) == 80 and len(dm.datasets["val"]) == 4
    assert len(dm.fixed_set("test_id")) == 32 and len(dm.fixed_set("test_ood")) == 10
    b = next(iter(dm.train_dataloader()))
    assert b["points"].shape == (4, 500, 3) and b["betas"].shape == (4, 2)
    with pytest.raises(ValueError, match="amass_root"):
        BodyScanDataModule(source="amass", body_model={"name": "toy"})
