"""AMASS ``.npz`` pose source (SMPL / SMPL-H / SMPL-X parameter files, 22 body joints).

Each file needs the keys ``poses`` (``[N, >=66]``: 72 SMPL, 156 SMPL-H, 165 SMPL-X; the first 66 values
are the root orientation and the 21 body joints), ``betas`` and ``trans`` (``[N, 3]``); ``gender`` and
``mocap_framerate`` are read when present. Files are loaded with ``allow_pickle=False``. AMASS is z-up;
with ``to_y_up`` (default) the root orientation and translation are rotated by ``Rx(-90 deg)`` into
the SMPL / arteq frame (y up).

Split of the paper's protocol (our choice, the paper's list is not published with it): in DFaust_67,
sequences whose motion name (file name without ``_poses.npz``) is in ``test_motions`` are the test
split (all subjects), those in ``val_motions`` the validation split, all others train. Test and val
sequences are cropped to the middle 50% of their frames and subsampled every ``eval_stride`` (5) frames.
MPI_Limits (PosePrior) gives the OOD test set, every ``ood_stride`` frames.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import roma
import torch

from arteq.data.poses import PoseSource

REQUIRED_KEYS = ("poses", "betas", "trans")
#: Default motions held out of DFaust_67 (every subject performs them).
DFAUST_TEST_MOTIONS = ("one_leg_jump", "punching", "chicken_wings")
DFAUST_VAL_MOTIONS = ("shake_shoulders",)


def read_amass_npz(path: str | Path) -> dict[str, np.ndarray]:
    """Read one AMASS file: ``poses [N,22,3]`` float32 axis-angle, ``trans [N,3]``, ``betas [nb]``.

    Raises:
        FileNotFoundError / ValueError naming the file and the problem.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"AMASS file not found: {path}")
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, EOFError, ValueError) as e:  # not a zip / npy, or a pickle we refuse to load
        raise ValueError(f"{path}: cannot read as an .npz archive ({e})") from e
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{path}: is a single .npy array, not an .npz archive with poses/betas/trans")
    with z:
        keys = set(z.files)
        missing = [k for k in REQUIRED_KEYS if k not in keys]
        if missing:
            raise ValueError(
                f"{path}: not an AMASS pose file, missing keys {missing} (has {sorted(keys)}; "
                f"needs poses, betas, trans)"
            )
        poses = np.asarray(z["poses"], dtype=np.float64)
        trans = np.asarray(z["trans"], dtype=np.float64)
        betas = np.asarray(z["betas"], dtype=np.float64).reshape(-1)
        try:  # some releases store gender as a pickled object array: not needed, not unpickled
            gender = str(z["gender"]) if "gender" in keys else "unknown"
        except ValueError:
            gender = "unknown"
        fps = float(z["mocap_framerate"]) if "mocap_framerate" in keys else float("nan")
    if poses.ndim != 2 or poses.shape[1] < 66:
        raise ValueError(f"{path}: 'poses' must be [N, 72|156|165] (>= 66 columns), got {poses.shape}")
    if trans.shape != (poses.shape[0], 3):
        raise ValueError(f"{path}: 'trans' must be [N, 3] with N={poses.shape[0]}, got {trans.shape}")
    if not (np.isfinite(poses[:, :66]).all() and np.isfinite(trans).all() and np.isfinite(betas).all()):
        raise ValueError(f"{path}: NaN or Inf in poses / trans / betas")
    return {
        "poses": poses[:, :66].reshape(-1, 22, 3).astype(np.float32),
        "trans": trans.astype(np.float32),
        "betas": betas.astype(np.float32),
        "gender": np.array(gender),
        "fps": np.array(fps),
    }


def find_dataset_dir(root: str | Path, names: list[str] | tuple[str, ...]) -> Path:
    """First existing ``root/name`` among ``names`` (AMASS renamed some folders between releases)."""
    root = Path(root).expanduser()
    if not root.is_dir():
        raise FileNotFoundError(f"AMASS root folder not found: {root} (set data.amass_root)")
    for n in names:
        if (root / n).is_dir():
            return root / n
    raise FileNotFoundError(f"none of {list(names)} found under AMASS root {root}")


def motion_name(path: Path) -> str:
    stem = path.stem
    return stem[: -len("_poses")] if stem.endswith("_poses") else stem


_Y_UP = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64)  # Rx(-90)


class AmassPoses(PoseSource):
    """Frames of an AMASS sub-dataset as a finite pose source.

    Args:
        root: AMASS root folder (holding e.g. ``DFaust_67/`` and ``MPI_Limits/``).
        datasets: candidate sub-folder names, the first existing is used.
        split: ``train`` | ``val`` | ``test`` (DFaust-style motion split) or ``all``.
        test_motions, val_motions: motion names held out for test / val.
        eval_stride: frame stride of val / test (middle 50% of each sequence).
        train_stride: frame stride of train; ``all_stride`` of ``all`` (whole sequences).
        use_betas: return the files' betas (only meaningful with an SMPL body); else ``None`` and the
            dataset samples betas from the body's shape space.
        to_y_up: rotate AMASS's z-up world into arteq's y-up frame.
    """

    def __init__(
        self,
        root: str | Path,
        datasets: list[str] | tuple[str, ...] = ("DFaust_67", "DFaust"),
        split: str = "train",
        test_motions: list[str] | tuple[str, ...] = DFAUST_TEST_MOTIONS,
        val_motions: list[str] | tuple[str, ...] = DFAUST_VAL_MOTIONS,
        eval_stride: int = 5,
        train_stride: int = 1,
        all_stride: int = 5,
        use_betas: bool = False,
        to_y_up: bool = True,
    ) -> None:
        if split not in ("train", "val", "test", "all"):
            raise ValueError(f"split must be train|val|test|all, got {split!r}")
        self.dir = find_dataset_dir(root, list(datasets))
        files = sorted(p for p in self.dir.rglob("*.npz") if p.name != "shape.npz")
        if not files:
            raise FileNotFoundError(f"no AMASS .npz pose files under {self.dir}")
        test_m, val_m = set(test_motions), set(val_motions)
        poses, trans, betas, self.frames = [], [], [], []
        self.files = []
        for f in files:
            m = motion_name(f)
            kind = "test" if m in test_m else "val" if m in val_m else "train"
            if split != "all" and kind != split:
                continue
            d = read_amass_npz(f)
            n = d["poses"].shape[0]
            if split in ("val", "test"):
                idx = np.arange(n // 4, n - n // 4)[::eval_stride]
            else:
                idx = np.arange(n)[:: train_stride if split == "train" else all_stride]
            if len(idx) == 0:
                continue
            self.files.append(f)
            poses.append(d["poses"][idx])
            trans.append(d["trans"][idx])
            betas.append(np.repeat(d["betas"][None, :16], len(idx), 0))
            self.frames += [(len(self.files) - 1, int(i)) for i in idx]
        if not poses:
            raise ValueError(
                f"AMASS split {split!r} of {self.dir} is empty (motions {sorted(test_m | val_m)})"
            )
        nb = min(b.shape[1] for b in betas)
        self.poses = torch.from_numpy(np.concatenate(poses)).double()
        self.trans = torch.from_numpy(np.concatenate(trans)).double()
        self.betas = torch.from_numpy(np.concatenate([b[:, :nb] for b in betas])).double()
        if to_y_up:
            root_rot = _Y_UP @ roma.rotvec_to_rotmat(self.poses[:, 0])
            self.poses[:, 0] = roma.rotmat_to_rotvec(root_rot)
            self.trans = self.trans @ _Y_UP.T
        self.split, self.use_betas, self.to_y_up = split, use_betas, to_y_up
        self._args = {
            "datasets": list(datasets),
            "split": split,
            "test_motions": sorted(test_m),
            "val_motions": sorted(val_m),
            "eval_stride": eval_stride,
            "train_stride": train_stride,
            "all_stride": all_stride,
        }
        self.num_poses = self.poses.shape[0]

    def fingerprint(self) -> dict:
        h = hashlib.sha256()
        for f in self.files:
            st = f.stat()
            h.update(f"{f.relative_to(self.dir)}:{st.st_size}:{int(st.st_mtime)};".encode())
        return {
            "class": "AmassPoses",
            "dir": str(self.dir.resolve()),
            "files": h.hexdigest(),
            "use_betas": self.use_betas,
            "to_y_up": self.to_y_up,
            "args": json.loads(json.dumps(self._args)),
        }

    def sample(self, index: int, generator: torch.Generator) -> dict:
        i = index % self.num_poses
        return {
            "pose": self.poses[i].clone(),
            "betas": self.betas[i].clone() if self.use_betas else None,
            "transl": self.trans[i].clone(),
        }
