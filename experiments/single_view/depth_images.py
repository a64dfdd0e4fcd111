"""Depth images to try ``arteq-fit`` on: a person in a room seen by a Kinect-like camera, as 16-bit PNGs.

Each image is the z-buffer (:func:`arteq.data.single_view.rasterize`) of a body from the project's
everyday poses (a fixed stream, not the training one) standing on a floor in front of a wall, seen by a
640 x 480 camera (fx = fy = 525 px, cx = 319.5, cy = 239.5; OpenCV convention) 2-3.5 m away at chest
height, slightly from above; depth noise along the rays as the simulator's (1 mm + 1 mm/m^2 z^2: 1 cm
at 3 m; ``--noise-quad 0.0002`` for a time-of-flight camera's 1 mm + 0.2 mm/m^2 z^2), 5 % missing pixels,
stored in millimetres. The floor (8 m wide, from the wall to 5 m in front of the body) and the wall (1.5 m
behind the body, 3 m high) are grids of 25 cm tiles (the rasteriser drops a triangle with a corner
behind the camera). Written: ``<out>/person_<i>.png``, ``<out>/intrinsics.json`` (read by arteq-fit
beside the images) and ``<out>_truth/person_<i>.npz`` (ground-truth vertices and joints in the camera
frame, metres, what each pixel shows and the floor plane; outside ``<out>``, which arteq-fit reads whole).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/depth_images.py --out depth_demo
    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/depth_images.py --out depth_demo --clean
    OMP_NUM_THREADS=1 .venv/bin/arteq-fit depth_demo --out depth_fits --threads 1 --no-anny
    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/depth_images.py --out depth_demo \
        --score depth_fits

``--clean``: what the clean-up removes of the floor, the wall, the body and its feet (pixel labels);
``--score``: the fits' V2V and MPJPE; ``--json FILE`` writes either's rows.
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
#: depth noise sigma(z) = 1 mm + NOISE_QUAD * z^2 (the simulator's default; a time-of-flight camera: 2e-4)
NOISE_QUAD = 0.001


def truth_dir(out: Path) -> Path:
    return out.parent / f"{out.name}_truth"


def _grid(
    corner: np.ndarray, du: np.ndarray, dv: np.ndarray, nu: int, nv: int
) -> tuple[np.ndarray, np.ndarray]:
    """A rectangle from ``corner`` along ``nu`` steps ``du`` and ``nv`` steps ``dv`` as a triangle grid (small
    tiles: the rasteriser drops a triangle with a corner behind the camera), counter-clockwise seen from
    the side ``du x dv`` points to (the rasteriser culls the other side)."""
    i, j = np.meshgrid(np.arange(nu + 1), np.arange(nv + 1), indexing="ij")
    v = corner + i.reshape(-1, 1) * du + j.reshape(-1, 1) * dv
    k = (i * (nv + 1) + j)[:-1, :-1].reshape(-1)
    f = np.concatenate([np.stack([k, k + nv + 1, k + nv + 2], 1), np.stack([k, k + nv + 2, k + 1], 1)])
    return v, f


def room(floor_y: float, tile: float = 0.25) -> tuple[torch.Tensor, torch.Tensor, int]:
    """A floor at height ``floor_y`` (8 m wide, from the wall to 5 m in front of the body) and a wall 1.5 m
    behind the body (8 m wide, 3 m high): metres, body frame (y up, z front), tiles of ``tile`` metres.
    Returns vertices, faces (the floor's first) and the floor's face count."""
    w, front, back, high = 8.0, 5.0, -1.5, 3.0
    nx = int(round(w / tile))
    fv, ff = _grid(np.array([-w / 2, floor_y, front]), np.array([tile, 0, 0]), np.array([0, 0, -tile]),
                   nx, int(round((front - back) / tile)))  # fmt: skip  # x . -z = +y: seen from above
    wv, wf = _grid(np.array([-w / 2, floor_y, back]), np.array([tile, 0, 0]), np.array([0, tile, 0]),
                   nx, int(round(high / tile)))  # fmt: skip  # x . y = +z: seen from the front
    v = torch.tensor(np.concatenate([fv, wv]), dtype=torch.float64)
    return v, torch.tensor(np.concatenate([ff, wf + len(fv)])), len(ff)


def make(out: Path, count: int, seed: int = 2026, noise_quad: float = NOISE_QUAD) -> None:
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
        floor_v, floor_f, n_floor = room(float(verts[:, 1].min()))
        scene_v = torch.cat([verts, floor_v])
        scene_f = torch.cat([body.faces, floor_f + len(verts)])
        heading = math.radians(float(torch.empty(()).uniform_(-40, 40, generator=g)))
        dist = float(torch.empty(()).uniform_(2.0, 3.5, generator=g))
        offset = [dist * math.sin(heading), 0.5, dist * math.cos(heading)]
        cam = pelvis + torch.tensor(offset, dtype=torch.float64)
        r = look_at(cam, pelvis, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64))
        vc = (scene_v - cam) @ r.T
        # the rasteriser's pixel centres are at +0.5: OpenCV's cx = rasteriser's cx - 0.5
        face, _, depth = rasterize(vc, scene_f, INTRINSICS["fx"], WIDTH, HEIGHT, 320.0, 240.0)
        depth, face = depth.numpy(), face.numpy()
        what = np.zeros(face.shape, np.uint8)  # what each pixel shows: 0 nothing, 1 body, 2 floor, 3 wall
        hit = face[face >= 0]
        what[face >= 0] = 1 + (hit >= len(body.faces)) + (hit >= len(body.faces) + n_floor)
        z = np.where(np.isfinite(depth), depth, 0.0)
        rng = np.random.default_rng(seed + i)
        z = z + (0.001 + noise_quad * z**2) * rng.standard_normal(z.shape) * (z > 0)
        z[rng.random(z.shape) < 0.05] = 0.0
        write_depth_png(out / f"person_{i}.png", z)
        v_cam, j_cam = ((verts - cam) @ r.T).numpy(), ((joints - cam) @ r.T).numpy()
        up = (r @ torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)).numpy()  # the floor's normal (camera)
        floor_d = -float(up @ v_cam[np.argmin(verts[:, 1].numpy())])  # up . p + floor_d = height above it
        np.savez(truth / f"person_{i}.npz", vertices=v_cam, joints=j_cam, pixel_labels=what,
                 floor_plane=np.append(up, floor_d))  # fmt: skip
        print(f"{out / f'person_{i}.png'}: camera {dist:.2f} m, heading {math.degrees(heading):.0f} deg")


#: body points up to this height above the floor are the feet (foot loss: the share of them removed)
FOOT_HEIGHT_M = 0.10


def clean_report(out: Path) -> list[dict]:
    """What the fitter's clean-up (``arteq-fit``'s defaults: the automatic depth band, then
    :func:`arteq.fit.clean.clean_scan` with the camera as viewpoint) removes from each image, against the
    truth's pixel labels: the floor's and wall's points left, the body's points removed, and the feet's
    (body points up to ``FOOT_HEIGHT_M`` above the floor) removed."""
    from arteq.fit.clean import CODES, clean_scan
    from arteq.fit.depth import read_depth

    rows = []
    for t in sorted(truth_dir(out).glob("*.npz")):
        truth = np.load(t)
        if "pixel_labels" not in truth:
            print(f"{t.stem}: truth without pixel labels (made by an older version of this script)")
            continue
        scan = read_depth(out / f"{t.stem}.png")
        what = truth["pixel_labels"][scan.pixels[:, 0], scan.pixels[:, 1]]
        try:
            res = clean_scan(scan.points, viewpoint=scan.viewpoint)
        except TypeError:  # a clean-up from before the camera was passed to it
            res = clean_scan(scan.points)
        height = scan.points @ truth["floor_plane"][:3] + truth["floor_plane"][3]
        body, feet = what == 1, (what == 1) & (height < FOOT_HEIGHT_M)
        on_plane = res.codes == CODES["plane"]
        row = {
            "image": t.stem,
            "points": len(what),
            "body": int(body.sum()),
            "floor": int((what == 2).sum()),
            "wall": int((what == 3).sum()),
            "planes": len(res.planes),
            "bands_cm": [round(100 * p["band_m"], 1) for p in res.planes],
            "band_ranges_cm": [
                [round(100 * b, 1) for b in p.get("band_range_m", [p["band_m"]] * 2)] for p in res.planes
            ],
            "plane_points": [p["points"] for p in res.planes],
            "floor_left": int(((what == 2) & res.keep).sum()),
            "wall_left": int(((what == 3) & res.keep).sum()),
            "body_removed": int((body & ~res.keep).sum()),
            "body_on_planes": int((body & on_plane).sum()),
            "feet": int(feet.sum()),
            "feet_removed": int((feet & ~res.keep).sum()),
            "flags": list(res.flags),
            "seconds": round(res.seconds, 2),
        }
        rows.append(row)
        print(
            f"{t.stem}: {row['points']} points (body {row['body']}, floor {row['floor']}, "
            f"wall {row['wall']}): "
            f"{row['planes']} planes (bands {row['bands_cm']} cm); left: floor {row['floor_left']}, wall "
            f"{row['wall_left']}; removed: body {row['body_removed']} ({row['body_on_planes']} on planes), "
            f"feet {row['feet_removed']} of {row['feet']}; {res.describe()}"
            + (f"; flags {row['flags']}" if row["flags"] else "")
        )
    return rows


def score(out: Path, fits: Path) -> list[dict]:
    """V2V and MPJPE of ``arteq-fit``'s fits against the truth files (the fits are in the camera frame)."""
    rows, errs = [], []
    status = {}
    if (fits / "summary.json").is_file():
        status = {Path(r["input"]).stem: r for r in json.loads((fits / "summary.json").read_text())["inputs"]}
    for t in sorted(truth_dir(out).glob("*.npz")):
        f = fits / f"{t.stem}.npz"
        if not f.is_file():
            s = status.get(t.stem, {})
            rows.append(
                {"image": t.stem, "status": s.get("status", "no fit"), "message": s.get("message", "")}
            )
            print(f"{t.stem}: no fit ({rows[-1]['status']}: {rows[-1]['message']})")
            continue
        truth, fit = np.load(t), np.load(f)
        v2v = np.linalg.norm(fit["vertices"] - truth["vertices"], axis=1).mean() * 100
        mpjpe = np.linalg.norm(fit["joints"] - truth["joints"], axis=1).mean() * 100
        errs.append((v2v, mpjpe))
        rows.append({"image": t.stem, "status": str(fit["status"]), "v2v_cm": round(float(v2v), 2),
                     "mpjpe_cm": round(float(mpjpe), 2), "scan_mode": str(fit["scan_mode_reason"]),
                     "parts_seen": int(fit["parts_seen"].sum())})  # fmt: skip
        keys = ("removed_plane", "removed_outlier", "removed_cluster", "seconds")
        rows[-1].update({k: status[t.stem][k] for k in keys if k in status.get(t.stem, {})})
        how = f"{fit['status']}, {fit['scan_mode_reason']}, parts seen {int(fit['parts_seen'].sum())}"
        print(f"{t.stem}: V2V {v2v:.1f} cm, MPJPE {mpjpe:.1f} cm, {how}")
    if errs:
        a = np.array(errs)
        print(f"mean over {len(a)}: V2V {a[:, 0].mean():.1f} cm, MPJPE {a[:, 1].mean():.1f} cm")
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", required=True, help="folder of the depth images")
    ap.add_argument("--count", type=int, default=4)
    ap.add_argument(
        "--noise-quad", type=float, default=NOISE_QUAD,
        help="depth noise sigma = 1 mm + this x z^2 (m^-1; the simulator's default is 0.001)",
    )  # fmt: skip
    ap.add_argument("--score", default=None, help="score the fits in this folder against the truth")
    ap.add_argument(
        "--clean", action="store_true", help="report what the clean-up removes (against the truth's labels)"
    )
    ap.add_argument("--json", default=None, help="write the --clean or --score rows to this JSON file")
    args = ap.parse_args()
    out = Path(args.out)
    if args.clean or args.score:
        rows = clean_report(out) if args.clean else score(out, Path(args.score))
        if args.json:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
            Path(args.json).write_text(json.dumps(rows, indent=1) + "\n")
    else:
        make(out, args.count, noise_quad=args.noise_quad)


if __name__ == "__main__":
    main()
