"""Scans to try ``arteq-fit`` on: ``python -m arteq.fit.demo --out demo``.

Writes generated body scans as ``.ply`` point clouds under ``<out>/scans/`` (in-distribution and
out-of-distribution poses, each with a random orientation and a random offset of up to a few metres,
5 mm noise; one with 10 % outliers; one as a mesh) and their ground truth under
``<out>/ground_truth/`` (``<name>.obj`` mesh in the scan's frame, ``<name>.npz`` parameters). Then:
``arteq-fit <out>/scans --out <out>/fits``.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np


def synthetic_scan(
    body,
    split: str = "test_ood",
    index: int = 0,
    num_points: int = 5000,
    seed: int = 0,
    rotate: bool = True,
    offset: float = 2.0,
    outliers: float = 0.0,
    noise: float = 0.005,
) -> dict:
    """One generated scan in a random frame: ``points [N, 3]`` (metres), ``vertices [V, 3]`` ground-truth
    mesh in the same frame, ``faces``, ``labels [N]`` (-1 for outliers), ``betas``, ``pose [22, 3, 3]``
    local, ``transl`` (scan frame), ``rotation``, ``offset``. ``split``: ``test_id`` (everyday upright
    motions) or ``test_ood`` (extreme poses); both then get a random orientation when ``rotate``."""
    import torch

    from arteq.data.dataset import BodyScanDataset
    from arteq.data.poses import SyntheticIDPoses, SyntheticOODPoses
    from arteq.geometry.rotations import random_rotmat

    src = SyntheticOODPoses() if split == "test_ood" else SyntheticIDPoses()
    ds = BodyScanDataset(src, body, f"demo_{split}", index + 1, seed=seed, num_points=num_points,
                         noise_std=noise, augment="so3" if split == "test_ood" else "none")  # fmt: skip
    s = ds[index]
    g = torch.Generator().manual_seed(10_000 * seed + index + (0 if split == "test_id" else 5000))
    rot = random_rotmat(1, g)[0] if rotate else torch.eye(3, dtype=torch.float64)
    off = (torch.rand(3, generator=g, dtype=torch.float64) * 2 - 1) * offset
    with torch.no_grad():
        gt = body(betas=s["betas"][None], pose=s["pose"][None], transl=s["transl"][None])
    verts = gt.vertices[0].double() @ rot.T + off
    pts = s["points"].double() @ rot.T + off
    labels = s["labels"].numpy().astype(np.int64)
    pts = pts.numpy()
    if outliers > 0:
        m = int(round(outliers * len(pts)))
        rng = np.random.default_rng(index + 17)
        lo, hi = pts.min(0) - 0.2, pts.max(0) + 0.2
        pts[:m] = rng.uniform(lo, hi, size=(m, 3))
        labels[:m] = -1
    # pose in the scan frame: the rotation applies to the root (about the pelvis) plus a translation
    pose = s["pose"].double().clone()
    pose[0] = rot @ pose[0]
    with torch.no_grad():
        moved = body(betas=s["betas"][None], pose=pose[None].float())
    transl = verts[0].numpy() - moved.vertices[0, 0].double().numpy()
    return {
        "points": pts,
        "vertices": verts.numpy(),
        "faces": body.faces.numpy(),
        "labels": labels,
        "betas": s["betas"].numpy(),
        "pose": pose.numpy(),
        "transl": transl,
        "rotation": rot.numpy(),
        "offset": off.numpy(),
    }


def write_demo(out: str | Path, count: int = 2, seed: int = 0, num_points: int = 5000) -> list[Path]:
    """Write the demo scans (see module docstring); returns the scan files."""
    import trimesh

    from arteq.body import load_body_model
    from arteq.io.fits import npz_bytes, obj_bytes, write_atomic

    body = load_body_model("anny22")
    out = Path(out)
    (out / "scans").mkdir(parents=True, exist_ok=True)
    (out / "ground_truth").mkdir(parents=True, exist_ok=True)
    jobs = [(f"id_{i + 1:02d}", "test_id", i, 0.0, "cloud") for i in range(count)]
    jobs += [(f"ood_{i + 1:02d}", "test_ood", i, 0.0, "cloud") for i in range(count)]
    jobs += [("ood_outliers", "test_ood", count, 0.1, "cloud"), ("id_mesh", "test_id", count, 0.0, "mesh")]
    written = []
    for name, split, index, outl, kind in jobs:
        s = synthetic_scan(body, split, index, num_points, seed, outliers=outl)
        path = out / "scans" / f"{name}.ply"
        if kind == "mesh":
            data = trimesh.Trimesh(s["vertices"], s["faces"], process=False).export(file_type="ply")
        else:
            data = trimesh.PointCloud(s["points"]).export(file_type="ply")
        write_atomic(path, data)
        write_atomic(
            out / "ground_truth" / f"{name}.obj",
            obj_bytes(s["vertices"], s["faces"], f"ground truth of {name}"),
        )
        keys = ("vertices", "betas", "pose", "transl", "rotation", "offset")
        write_atomic(out / "ground_truth" / f"{name}.npz", npz_bytes({k: s[k] for k in keys}))
        written.append(path)
    return written


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m arteq.fit.demo", description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", required=True, help="output folder (scans/ and ground_truth/ inside)")
    ap.add_argument("--count", type=int, default=2, help="scans per split (2)")
    ap.add_argument("--points", type=int, default=5000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    files = write_demo(args.out, args.count, args.seed, args.points)
    scans = Path(args.out) / "scans"
    print(f"wrote {len(files)} scans to {scans} (ground truth in {Path(args.out) / 'ground_truth'})")
    print(f"now run: arteq-fit {scans} --out {Path(args.out) / 'fits'}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
