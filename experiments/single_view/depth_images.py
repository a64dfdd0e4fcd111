"""Depth images to try ``arteq-fit`` on: a person in a room seen by a Kinect-like camera, as 16-bit PNGs.

Each image is the z-buffer (:func:`arteq.data.single_view.rasterize`) of a body from the project's
everyday poses (a fixed stream, not the training one) standing on a floor in front of a wall, seen by a
640 x 480 camera (fx = fy = 525 px, cx = 319.5, cy = 239.5; OpenCV convention) 2-3.5 m away at chest
height, slightly from above; depth noise as the simulator's (1 mm + 1 mm/m^2 z^2), 5 % missing pixels,
stored in millimetres. Written: ``<out>/person_<i>.png``, ``<out>/intrinsics.json`` (read by arteq-fit
beside the images) and ``<out>_truth/person_<i>.npz`` (ground-truth vertices and joints in the camera
frame, metres; outside ``<out>``, which arteq-fit reads whole).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/depth_images.py --out depth_demo
    OMP_NUM_THREADS=1 .venv/bin/arteq-fit depth_demo --out depth_fits --threads 1
    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/depth_images.py --out depth_demo \
        --score depth_fits
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
import roma
import torch

INTRINSICS = {"fx": 525.0, "fy": 525.0, "cx": 319.5, "cy": 239.5}
WIDTH, HEIGHT = 640, 480
#: depth noise sigma(z) = 1 mm + NOISE_QUAD * z^2 (a time-of-flight camera; the simulator's default is 1e-3)
NOISE_QUAD = 0.0002


def truth_dir(out: Path) -> Path:
    return out.parent / f"{out.name}_truth"


def room(floor_y: float) -> tuple[torch.Tensor, torch.Tensor]:
    """A floor at height ``floor_y`` and a wall 1.5 m behind the body (metres, body frame: y up, z front)."""
    s = 6.0
    v = torch.tensor(
        [[-s, floor_y, -1.5], [s, floor_y, -1.5], [s, floor_y, s], [-s, floor_y, s],
         [-s, floor_y, -1.5], [s, floor_y, -1.5], [s, floor_y + 3.0, -1.5], [-s, floor_y + 3.0, -1.5]],
        dtype=torch.float64,
    )  # fmt: skip
    f = torch.tensor([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    return v, f


def make(out: Path, count: int, seed: int = 2026) -> None:
    from arteq.body.factory import create_body
    from arteq.data.dataset import seeded_generator
    from arteq.data.poses import SyntheticIDPoses
    from arteq.data.single_view import look_at, rasterize
    from arteq.fit.depth import write_depth_png

    body = create_body({"name": "anny22"})
    src = SyntheticIDPoses()
    truth = truth_dir(out)
    truth.mkdir(parents=True, exist_ok=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "intrinsics.json").write_text(json.dumps(INTRINSICS, indent=1))
    for i in range(count):
        g = seeded_generator(seed, "depth-demo", i)
        pose = src.sample(i, g)["pose"]
        rot = roma.rotvec_to_rotmat(pose.double()).float()
        betas = torch.randn(1, body.num_betas, generator=g)
        with torch.no_grad():
            o = body(betas=betas, pose=rot[None])
        verts, joints = o.vertices[0].double(), o.joints[0].double()
        pelvis = joints[0]
        floor_v, floor_f = room(float(verts[:, 1].min()))
        scene_v = torch.cat([verts, floor_v])
        scene_f = torch.cat([body.faces, floor_f + len(verts)])
        heading = math.radians(float(torch.empty(()).uniform_(-40, 40, generator=g)))
        dist = float(torch.empty(()).uniform_(2.0, 3.5, generator=g))
        offset = [dist * math.sin(heading), 0.5, dist * math.cos(heading)]
        cam = pelvis + torch.tensor(offset, dtype=torch.float64)
        r = look_at(cam, pelvis, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
        vc = (scene_v - cam) @ r.T
        # the rasteriser's pixel centres are at +0.5: OpenCV's cx = rasteriser's cx - 0.5
        _, _, depth = rasterize(vc, scene_f, INTRINSICS["fx"], WIDTH, HEIGHT, 320.0, 240.0)
        depth = depth.numpy()
        z = np.where(np.isfinite(depth), depth, 0.0)
        rng = np.random.default_rng(seed + i)
        z = z + (0.001 + NOISE_QUAD * z**2) * rng.standard_normal(z.shape) * (z > 0)
        z[rng.random(z.shape) < 0.05] = 0.0
        write_depth_png(out / f"person_{i}.png", z)
        v_cam, j_cam = ((verts - cam) @ r.T).numpy(), ((joints - cam) @ r.T).numpy()
        np.savez(truth / f"person_{i}.npz", vertices=v_cam, joints=j_cam)
        print(f"{out / f'person_{i}.png'}: camera {dist:.2f} m, heading {math.degrees(heading):.0f} deg")


def score(out: Path, fits: Path) -> None:
    """V2V and MPJPE of ``arteq-fit``'s fits against the truth files (the fits are in the camera frame)."""
    rows = []
    for t in sorted(truth_dir(out).glob("*.npz")):
        f = fits / f"{t.stem}.npz"
        if not f.is_file():
            print(f"{t.stem}: no fit")
            continue
        truth, fit = np.load(t), np.load(f)
        v2v = np.linalg.norm(fit["vertices"] - truth["vertices"], axis=1).mean() * 100
        mpjpe = np.linalg.norm(fit["joints"] - truth["joints"], axis=1).mean() * 100
        rows.append((v2v, mpjpe))
        how = f"{fit['status']}, {fit['scan_mode_reason']}, parts seen {int(fit['parts_seen'].sum())}"
        print(f"{t.stem}: V2V {v2v:.1f} cm, MPJPE {mpjpe:.1f} cm, {how}")
    if rows:
        a = np.array(rows)
        print(f"mean over {len(a)}: V2V {a[:, 0].mean():.1f} cm, MPJPE {a[:, 1].mean():.1f} cm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder of the depth images")
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument("--score", default=None, help="score the fits in this folder against the truth")
    args = ap.parse_args()
    out = Path(args.out)
    if args.score:
        score(out, Path(args.score))
    else:
        make(out, args.count)


if __name__ == "__main__":
    main()
