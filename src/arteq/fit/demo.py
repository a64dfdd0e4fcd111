"""Scans to try ``arteq-fit`` on: ``python -m arteq.fit.demo --out demo``.

Writes generated body scans as ``.ply`` point clouds under ``<out>/scans/`` (in-distribution and
out-of-distribution poses, each with a random orientation and a random offset of up to a few metres,
5 mm noise; one with 10 % outliers; one as a mesh; one standing in a room: floor, wall, a box and 10 %
stray points, :func:`add_clutter`) and their ground truth under
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


#: Labels of :func:`add_clutter`'s points (the body's own points are 0).
CLUTTER_KINDS = {"body": 0, "stray": 1, "floor": 2, "wall": 3, "box": 4}


def _mesh_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    tri = vertices[faces]
    return float(0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())


def add_clutter(
    points: np.ndarray,
    vertices: np.ndarray,
    faces: np.ndarray,
    up: np.ndarray,
    kinds: tuple[str, ...] = ("stray", "floor", "wall", "box"),
    seed: int = 0,
    stray_frac: float = 0.1,
    stray_box_m: float = 4.0,
    plane_density: float = 0.5,
    noise: float = 0.005,
) -> tuple[np.ndarray, np.ndarray]:
    """A body scan with the clutter of a real room: returns ``(points [M, 3], kind [M])`` (kinds as in
    :data:`CLUTTER_KINDS`; the body's own points first, unchanged).

    ``up``: the room's up direction (the body stands, or lies, on the floor at its lowest point along it).
    ``stray``: ``stray_frac`` x the body's points, uniform in a ``stray_box_m`` cube centred on the body;
    ``floor``: a 2.5 m square under the body; ``wall``: 2.5 m wide, 2.2 m high, 0.4 m behind the body;
    ``box``: a 0.3 m cube on the floor 0.6 m beside the body. Floor and wall carry ``plane_density`` x the
    body's points per square metre, the box the body's density; all with ``noise`` (m, Gaussian).
    """
    rng = np.random.default_rng(seed)
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    density = len(points) / _mesh_area(vertices, faces)  # body points per m^2
    a = np.eye(3)[np.argmin(np.abs(up))]
    h1 = np.cross(up, a)
    h1 /= np.linalg.norm(h1)
    ang = rng.uniform(0, 2 * np.pi)
    h1, h2 = (
        np.cos(ang) * h1 + np.sin(ang) * np.cross(up, h1),
        -np.sin(ang) * h1 + np.cos(ang) * np.cross(up, h1),
    )
    centre = vertices.mean(0)
    floor_h = float((vertices @ up).min())
    base = centre + (floor_h - centre @ up) * up  # the centroid dropped onto the floor
    out, lab = [points], [np.zeros(len(points), dtype=np.int64)]

    def rect(origin, e1, e2, w1, w2, count):
        uv = rng.uniform(0, 1, (count, 2))
        return origin + uv[:, :1] * w1 * e1 + uv[:, 1:] * w2 * e2

    def noisy(p):
        return p + rng.normal(0, noise, p.shape)

    if "stray" in kinds:
        m = int(round(stray_frac * len(points)))
        out.append(centre + rng.uniform(-stray_box_m / 2, stray_box_m / 2, (m, 3)))
        lab.append(np.full(m, CLUTTER_KINDS["stray"]))
    if "floor" in kinds:
        m = int(plane_density * density * 2.5 * 2.5)
        out.append(noisy(rect(base - 1.25 * h1 - 1.25 * h2, h1, h2, 2.5, 2.5, m)))
        lab.append(np.full(m, CLUTTER_KINDS["floor"]))
    if "wall" in kinds:
        behind = float(((vertices - centre) @ h2).max()) + 0.4
        m = int(plane_density * density * 2.5 * 2.2)
        out.append(noisy(rect(base + behind * h2 - 1.25 * h1, h1, up, 2.5, 2.2, m)))
        lab.append(np.full(m, CLUTTER_KINDS["wall"]))
    if "box" in kinds:
        side = float(((vertices - centre) @ h1).max()) + 0.6
        corner = base + side * h1 - 0.15 * h2
        e = (h1, h2, up)
        faces_pts = []
        m_face = int(density * 0.3 * 0.3)
        for i in range(3):
            j, k = [x for x in range(3) if x != i]
            for off in (0.0, 0.3):
                faces_pts.append(rect(corner + off * e[i], e[j], e[k], 0.3, 0.3, m_face))
        box = noisy(np.concatenate(faces_pts))
        out.append(box)
        lab.append(np.full(len(box), CLUTTER_KINDS["box"]))
    return np.concatenate(out), np.concatenate(lab)


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
    jobs += [("id_room", "test_id", count + 1, 0.0, "room")]
    written = []
    for name, split, index, outl, kind in jobs:
        s = synthetic_scan(body, split, index, num_points, seed, outliers=outl)
        path = out / "scans" / f"{name}.ply"
        if kind == "mesh":
            data = trimesh.Trimesh(s["vertices"], s["faces"], process=False).export(file_type="ply")
        elif kind == "room":
            up = s["rotation"] @ np.array([0.0, 1.0, 0.0])
            pts, _ = add_clutter(s["points"], s["vertices"], s["faces"], up, seed=seed)
            data = trimesh.PointCloud(pts).export(file_type="ply")
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
