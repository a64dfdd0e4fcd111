"""AMASS downloads of both releases as they unpack: names, folders, keys, dtypes, frame rates, the split.

The writers below generate small files with the names, folder structure, keys, dtypes and shapes of the
two AMASS releases (from AMASS's / MoSh++'s public documentation, code and file listings; no AMASS data):

- SMPL+H G: ``DFaust_67/<subject>/<subject>_<motion>_poses.npz`` (``poses [N,156]``, ``trans``,
  ``betas [16]``, ``gender``, ``mocap_framerate``, ``dmpls [N,8]``; DFaust also ``marker_data`` /
  ``marker_labels``) and a ``shape.npz`` per subject; ``MPI_Limits/<subject>/<motion>_poses.npz``
  (gender stored as bytes there).
- SMPL-X G: ``DFaust/<subject>/[<subject>_]<motion>_stageii.npz`` (``poses [N,165]`` = root, body, jaw, eyes,
  hands; the same parts as ``root_orient``, ``pose_body``, ``pose_jaw``, ``pose_eye``, ``pose_hand``;
  ``trans``, ``betas``, ``num_betas``, ``gender``, ``surface_model_type``, ``mocap_frame_rate``,
  ``mocap_time_length``, ``markers_latent``, ``latent_labels``, a pickled ``markers_latent_vids``) beside
  ``shape.npz`` / MoSh++'s ``<gender>_stagei.npz``; ``PosePrior/<subject>/<motion>_stageii.npz``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from arteq.data.amass import (
    AmassError,
    AmassNotFoundError,
    AmassPoses,
    amass_source,
    check_amass_root,
    frame_stride,
    motion_key,
    motion_name,
    read_amass_npz,
)

#: The 14 DFaust motions (every subject performs most of them).
DFAUST_MOTIONS = (
    "chicken_wings", "hips", "jiggle_on_toes", "jumping_jacks", "knees", "light_hopping_loose",
    "light_hopping_stiff", "one_leg_jump", "one_leg_loose", "punching", "running_on_spot", "shake_arms",
    "shake_hips", "shake_shoulders",
)  # fmt: skip
TEST_MOTIONS = {"one_leg_jump", "punching", "chicken_wings"}
VAL_MOTIONS = {"shake_shoulders"}
SUBJECTS = {"50002": "male", "50004": "female"}
POSEPRIOR = {"03099": ("op2", "lar1"), "03100": ("op3",)}
DFAUST_FRAMES, DFAUST_FPS = 40, 60.0
POSEPRIOR_FRAMES, POSEPRIOR_FPS = 60, 120.0


def _rng(*key) -> np.random.Generator:
    return np.random.default_rng(abs(hash(key)) % 2**32)


def write_smplh_motion(path: Path, n: int, fps: float, gender, markers: bool = False) -> dict:
    """One SMPL+H G ``*_poses.npz`` (float64 arrays, 0-d gender / framerate)."""
    rng = _rng(str(path))
    data = {
        "trans": rng.normal(0, 0.5, (n, 3)),
        "gender": gender,
        "mocap_framerate": np.array(fps),
        "betas": rng.normal(0, 1, 16),
        "dmpls": rng.normal(0, 1, (n, 8)),
        "poses": rng.normal(0, 0.3, (n, 156)),
    }
    if markers:
        data["marker_data"] = rng.normal(0, 1, (n, 5, 3))
        data["marker_labels"] = np.array(["C7", "CLAV", "LANK", "RANK", "STRN"], dtype=object)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **data)  # object arrays are pickled, as in the real files; the reader never loads them
    return data


def write_smplx_motion(path: Path, n: int, fps: float, gender: str) -> dict:
    """One SMPL-X G ``*_stageii.npz`` as MoSh++ writes it."""
    rng = _rng(str(path))
    poses = rng.normal(0, 0.3, (n, 165))
    labels = ["C7", "CLAV", "LANK", "RANK", "STRN"]
    data = {
        "gender": np.array(gender),
        "surface_model_type": np.array("smplx"),
        "mocap_frame_rate": np.array(fps),
        "mocap_time_length": np.array(n / fps),
        "markers_latent": rng.normal(0, 1, (len(labels), 3)),
        "latent_labels": np.array(labels),
        "markers_latent_vids": np.array({k: i for i, k in enumerate(labels)}, dtype=object),
        "trans": rng.normal(0, 0.5, (n, 3)),
        "poses": poses,
        "betas": rng.normal(0, 1, 16),
        "num_betas": np.array(16),
        "root_orient": poses[:, :3],
        "pose_body": poses[:, 3:66],
        "pose_hand": poses[:, 75:],
        "pose_jaw": poses[:, 66:69],
        "pose_eye": poses[:, 69:75],
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **data)
    return data


def write_smplh_release(root: Path) -> Path:
    """``DFaust_67/`` + ``MPI_Limits/`` of the SMPL+H G release."""
    for subj, gender in SUBJECTS.items():
        for m in DFAUST_MOTIONS:
            f = root / "DFaust_67" / subj / f"{subj}_{m}_poses.npz"
            write_smplh_motion(f, DFAUST_FRAMES, DFAUST_FPS, np.array(gender), markers=True)
        np.savez(root / "DFaust_67" / subj / "shape.npz", betas=np.zeros(16), gender=np.array(gender))
    for subj, motions in POSEPRIOR.items():
        for m in motions:
            f = root / "MPI_Limits" / subj / f"{m}_poses.npz"
            write_smplh_motion(f, POSEPRIOR_FRAMES, POSEPRIOR_FPS, np.array(b"male"))
        np.savez(root / "MPI_Limits" / subj / "shape.npz", betas=np.zeros(16), gender=np.array(b"male"))
    return root


def write_smplx_release(root: Path) -> Path:
    """``DFaust/`` + ``PosePrior/`` of the SMPL-X G release. Subject 50002's files carry the subject prefix
    (as public listings show), 50004's do not (as other copies have them): both are read."""
    for subj, gender in SUBJECTS.items():
        for m in DFAUST_MOTIONS:
            name = f"{subj}_{m}_stageii.npz" if subj == "50002" else f"{m}_stageii.npz"
            write_smplx_motion(root / "DFaust" / subj / name, DFAUST_FRAMES, DFAUST_FPS, gender)
        np.savez(root / "DFaust" / subj / "shape.npz", betas=np.zeros(16), gender=np.array(gender))
        np.savez(root / "DFaust" / subj / f"{gender}_stagei.npz", betas=np.zeros(16), gender=np.array(gender))
    for subj, motions in POSEPRIOR.items():
        for m in motions:
            write_smplx_motion(
                root / "PosePrior" / subj / f"{m}_stageii.npz", POSEPRIOR_FRAMES, POSEPRIOR_FPS, "male"
            )
    return root


@pytest.fixture(params=["smplh", "smplx"])
def release(request, tmp_path) -> tuple[str, Path]:
    writer = write_smplh_release if request.param == "smplh" else write_smplx_release
    return request.param, writer(tmp_path / f"amass_{request.param}")


# ---------------------------------------------------------------------------------------------- names
@pytest.mark.parametrize(
    "path, motion",
    [
        ("DFaust_67/50002/50002_chicken_wings_poses.npz", "chicken_wings"),
        ("DFaust/50002/50002_chicken_wings_stageii.npz", "chicken_wings"),
        ("DFaust/50002/chicken_wings_stageii.npz", "chicken_wings"),
        ("MPI_Limits/03099/op2_poses.npz", "op2"),
        ("PosePrior/03099/lar1_stageii.npz", "lar1"),
        ("ACCAD/Female1General_c3d/A10 - lie to crouch_poses.npz", "A10 - lie to crouch"),
        ("EyesJapanDataset/Eyes_Japan_Dataset/aita/accident-02-dodge fast-aita_poses.npz",
         "accident-02-dodge fast-aita"),
        ("SFU/0005/0005_2FeetJump001_poses.npz", "2FeetJump001"),
        ("CMU/01/01_01_stageii.npz", "01"),
        ("mine/walk.npz", "walk"),
    ],
)  # fmt: skip
def test_motion_names_of_real_file_names(path, motion):
    assert motion_name(Path(path)) == motion


def test_motion_keys_match_across_releases():
    # SMPL+H G keeps spaces, MoSh++ (SMPL-X G) writes them as underscores: one motion
    assert motion_key("A10 - lie to crouch") == motion_key("A10_-_lie_to_crouch") == "a10_lie_to_crouch"
    assert motion_key("accident-02-dodge fast-aita") == "accident_02_dodge_fast_aita"
    assert motion_key("Chicken_Wings") == "chicken_wings"


@pytest.mark.parametrize(
    "fps, target, stride",
    [(60, 60, 1), (120, 60, 2), (60, 12, 5), (120, 12, 10), (100, 12, 8), (59.94, 12, 5), (30, 60, 1),
     (60, 24, 3), (120, None, 1)],
)  # fmt: skip
def test_frame_stride_from_each_sequence_rate(fps, target, stride):
    assert frame_stride(fps, target) == stride


# ---------------------------------------------------------------------------------------------- reading
def test_read_both_releases_same_frames(tmp_path):
    rng = np.random.default_rng(0)
    poses = rng.normal(0, 0.3, (7, 165))
    common = {"trans": rng.normal(size=(7, 3)), "betas": rng.normal(size=16)}
    np.savez(tmp_path / "a_stageii.npz", poses=poses, mocap_frame_rate=np.array(120.0),
             gender=np.array("female"), surface_model_type=np.array("smplx"), **common)  # fmt: skip
    parts = {"root_orient": poses[:, :3], "pose_body": poses[:, 3:66], "pose_hand": poses[:, 75:]}
    np.savez(tmp_path / "b_stageii.npz", mocap_frame_rate=np.array(120.0), **parts, **common)
    np.savez(tmp_path / "c_poses.npz", poses=np.concatenate([poses[:, :66], poses[:, 75:]], 1),
             mocap_framerate=np.array(120.0), gender=np.array(b"female"), **common)  # fmt: skip
    a, b, c = (read_amass_npz(tmp_path / f) for f in ("a_stageii.npz", "b_stageii.npz", "c_poses.npz"))
    for out in (a, b, c):
        assert out["poses"].shape == (7, 22, 3) and out["poses"].dtype == np.float32
        np.testing.assert_allclose(out["poses"].reshape(7, 66), poses[:, :66], rtol=1e-6)
        assert out["fps"] == 120.0
    assert (a["gender"], c["gender"], b["gender"]) == ("female", "female", "unknown")
    assert (a["surface_model"], c["surface_model"], b["surface_model"]) == ("smplx", "smplh", "unknown")


@pytest.mark.parametrize(
    "gender", [np.array("female"), np.array(b"female"), np.array(["female"]), np.array([b"female"]),
               np.array("Female "), "female"],
)  # fmt: skip
def test_gender_as_str_or_bytes(tmp_path, gender):
    write_smplh_motion(tmp_path / "s" / "x_poses.npz", 3, 60.0, gender)
    assert read_amass_npz(tmp_path / "s" / "x_poses.npz")["gender"] == "female"


def test_pickled_gender_is_not_loaded(tmp_path):
    write_smplh_motion(tmp_path / "s" / "x_poses.npz", 3, 60.0, np.array("female", dtype=object))
    assert read_amass_npz(tmp_path / "s" / "x_poses.npz")["gender"] == "unknown"


def test_missing_keys_named_with_what_was_found(tmp_path):
    np.savez(tmp_path / "x_stageii.npz", trans=np.zeros((3, 3)), betas=np.zeros(16))
    with pytest.raises(AmassError) as e:
        read_amass_npz(tmp_path / "x_stageii.npz")
    msg = str(e.value)
    assert "x_stageii.npz" in msg and "poses (or root_orient + pose_body)" in msg
    assert "mocap_framerate or mocap_frame_rate" in msg and "found keys ['betas', 'trans']" in msg
    assert "\n" not in msg
    np.savez(tmp_path / "r_poses.npz", poses=np.zeros((3, 156)), trans=np.zeros((3, 3)),
             mocap_framerate=np.array(0.0))  # fmt: skip
    with pytest.raises(AmassError, match=r"r_poses\.npz: 'mocap_framerate' must be one positive number"):
        read_amass_npz(tmp_path / "r_poses.npz")


# ---------------------------------------------------------------------------------------------- the split
def test_paper_split_on_both_releases(release):
    kind, root = release
    train = AmassPoses(root, split="train")
    val = AmassPoses(root, split="val")
    test = AmassPoses(root, split="test")
    ood = amass_source(root, "test_ood")
    # which motions are train / val / test_id (all subjects), which files make test_ood
    assert set(test.motions) == TEST_MOTIONS and set(val.motions) == VAL_MOTIONS
    assert set(train.motions) == set(DFAUST_MOTIONS) - TEST_MOTIONS - VAL_MOTIONS
    assert {f.parent.name for f in test.files} == set(SUBJECTS) and len(test.files) == 2 * 3
    assert {f.parent.parent.name for f in train.files} == {"DFaust_67" if kind == "smplh" else "DFaust"}
    suffix = "_poses.npz" if kind == "smplh" else "_stageii.npz"
    want_ood = {f"{s}/{m}{suffix}" for s, ms in POSEPRIOR.items() for m in ms}
    assert {f"{f.parent.name}/{f.name}" for f in ood.files} == want_ood
    assert ood.dirs[0].name == ("MPI_Limits" if kind == "smplh" else "PosePrior")
    for src in (train, val, test, ood):  # shape.npz / *_stagei.npz are never motions
        assert not any(f.name == "shape.npz" or f.name.endswith("_stagei.npz") for f in src.files)
    # frames: 60 fps DFaust: train every frame, val / test middle 50% (frames 10..29) at 12 Hz (every 5th);
    # 120 fps PosePrior at 24 Hz (every 5th)
    assert len(train) == 2 * 10 * DFAUST_FRAMES
    assert len(test) == 2 * 3 * 4 and len(val) == 2 * 4
    assert [j for i, j in test.frames if i == 0] == [10, 15, 20, 25]
    assert len(ood) == 3 * POSEPRIOR_FRAMES // 5
    assert test.surface_models == {kind}


def test_the_two_releases_give_the_same_split(tmp_path):
    a, b = write_smplh_release(tmp_path / "h"), write_smplx_release(tmp_path / "x")
    for split in ("train", "val", "test"):
        sa, sb = AmassPoses(a, split=split), AmassPoses(b, split=split)
        assert sa.motions == sb.motions and len(sa) == len(sb)


def test_target_rates_not_fixed_strides(release):
    _, root = release
    # a 120 fps copy of one DFaust sequence: half the stride's frames per second, same target rate
    d = next((root / n) for n in ("DFaust_67", "DFaust") if (root / n).is_dir())
    write_smplh_motion(d / "50009" / "50009_knees_poses.npz", 80, 120.0, np.array("male"))
    write_smplh_motion(d / "50009" / "50009_punching_poses.npz", 80, 120.0, np.array("male"))
    train = AmassPoses(root, split="train", train_fps=60)
    test = AmassPoses(root, split="test", eval_fps=12)
    i = [k for k, f in enumerate(train.files) if f.parent.name == "50009"][0]
    assert [j for k, j in train.frames if k == i][:3] == [0, 2, 4] and train.motions["knees"] == 2 * 40 + 40
    i = [k for k, f in enumerate(test.files) if f.parent.name == "50009"][0]
    assert [j for k, j in test.frames if k == i] == [20, 30, 40, 50]  # middle 50% (20..59) every 10th
    every = AmassPoses(root, split="train", train_fps=None)
    assert every.motions["knees"] == 2 * 40 + 80


def test_extra_training_datasets(release):
    kind, root = release
    # the full download has more sub-datasets; CMU (120 fps) and BMLmovi added as training poses
    write_smplh_motion(root / "CMU" / "01" / "01_01_poses.npz", 120, 120.0, np.array("male"))
    write_smplh_motion(root / "CMU" / "01" / "01_02_poses.npz", 60, 120.0, np.array("male"))
    write_smplx_motion(
        root / "BMLmovi" / "Subject_11_F_MoSh" / "Subject_11_F_10_stageii.npz", 30, 120.0, "female"
    )
    np.savez(root / "BMLmovi" / "Subject_11_F_MoSh" / "shape.npz", betas=np.zeros(16))
    base = AmassPoses(root, split="train")
    more = amass_source(root, "train", {"datasets": ["DFaust", "CMU", "BMLmovi"]})
    assert len(more) == len(base) + (60 + 30) + 15  # at train_fps 60: every 2nd frame of 120 fps
    assert {f.parts[-3] for f in more.files} >= {"CMU", "BMLmovi"}
    # val / test / test_ood are unchanged by the extra sets
    for split in ("val", "test_id", "test_ood"):
        extra = amass_source(root, split, {"datasets": ["DFaust", "CMU", "BMLmovi"]})
        assert extra.files == amass_source(root, split).files
    # the OOD set cannot be a training set, under either of its names
    for name in ("PosePrior", "MPI_Limits"):
        with pytest.raises(
            AmassError, match=r"\['PosePrior'\] would be both training data and the OOD test set"
        ):
            amass_source(root, "train", {"datasets": ["DFaust", name]})
    with pytest.raises(
        AmassNotFoundError, match=r"no folder of sub-dataset KIT \(expected one of \['KIT'\]\)"
    ):
        amass_source(root, "train", {"datasets": ["DFaust", "KIT"]})


def test_nested_archive_folders_and_either_name(tmp_path):
    # archives unpacked into a folder of their own name: <root>/DFaust_67/DFaust_67/<subject>/...
    inner = write_smplh_release(tmp_path / "x")
    root = tmp_path / "nested"
    for name in ("DFaust_67", "MPI_Limits"):
        (root / name).mkdir(parents=True)
        (inner / name).rename(root / name / name)
    for names in (["DFaust"], ["DFaust_67"], ["dfaust"]):
        assert set(AmassPoses(root, datasets=names, split="test").motions) == TEST_MOTIONS
    assert len(amass_source(root, "test_ood", ood_datasets=["PosePrior"])) == 3 * 12


# ---------------------------------------------------------------------------------------------- betas
def test_betas_only_where_they_fit_the_body(release):
    kind, root = release
    auto_smpl = AmassPoses(root, split="val", use_betas=None, body_name="smpl")
    auto_anny = AmassPoses(root, split="val", use_betas=None, body_name="anny22")
    forced = AmassPoses(root, split="val", use_betas=True, body_name="anny22")
    g = torch.Generator()
    # SMPL+H G betas fit an SMPL body; SMPL-X G betas (SMPL-X's shape space) do not; anny22 never
    assert (auto_smpl.sample(0, g)["betas"] is not None) == (kind == "smplh")
    assert auto_anny.sample(0, g)["betas"] is None
    b = forced.sample(0, g)["betas"]
    assert b is not None and b.shape == (16,)
    raw = read_amass_npz(forced.files[0])
    torch.testing.assert_close(b, torch.from_numpy(raw["betas"]).double())


# ---------------------------------------------------------------------------------------------- errors
def test_layout_errors_name_root_expected_and_found(tmp_path):
    with pytest.raises(AmassNotFoundError, match="AMASS root folder not found: .*nope"):
        check_amass_root(tmp_path / "nope")
    root = tmp_path / "r"
    (root / "CMU").mkdir(parents=True)
    (root / "SFU").mkdir()
    with pytest.raises(AmassNotFoundError) as e:
        check_amass_root(root)
    msg = str(e.value)
    assert str(root) in msg and "no folder of sub-dataset DFaust" in msg
    assert "['DFaust', 'DFaust_67']" in msg and "found folders [CMU, SFU]" in msg and "\n" not in msg
    (root / "DFaust" / "50002").mkdir(parents=True)
    np.savez(root / "DFaust" / "50002" / "shape.npz", betas=np.zeros(16))
    (root / "DFaust" / "50002" / "README.txt").write_text("x")
    with pytest.raises(
        AmassNotFoundError, match=r"DFaust: no motion files \(expected .*_stageii\.npz.*found 2 "
    ):
        check_amass_root(root)
    write_smplx_motion(root / "DFaust" / "50002" / "50002_hips_stageii.npz", 5, 60.0, "male")
    with pytest.raises(AmassNotFoundError, match=r"no folder of sub-dataset PosePrior \(expected one of "
                                                 r"\['PosePrior', 'MPI_Limits'\]\)"):  # fmt: skip
        check_amass_root(root)
    write_smplx_motion(root / "PosePrior" / "03099" / "op2_stageii.npz", 5, 120.0, "male")
    np.savez(root / "DFaust" / "50002" / "50002_knees_stageii.npz", poses=np.zeros((5, 165)))
    with pytest.raises(
        AmassError, match=r"50002_knees_stageii\.npz: not an AMASS motion file, missing trans"
    ):
        check_amass_root(root)
    (root / "DFaust" / "50002" / "50002_knees_stageii.npz").unlink()
    assert set(check_amass_root(root)) == {"DFaust", "PosePrior"}
    # a split whose motions are not there says which motions it found
    with pytest.raises(
        AmassError, match=r"split 'test' .* no motion of \['chicken_wings', .*found: \[hips\]"
    ):
        AmassPoses(root, split="test")
