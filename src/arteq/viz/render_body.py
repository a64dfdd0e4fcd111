"""Render a body model at rest and in three poses, coloured by its 22 parts, to a PNG.

``python -m arteq.viz.render_body [--out experiments/figures/body_anny22.png] [--body anny22|smpl
--model-path ...]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Poly3DCollection  # noqa: E402

from arteq.body import create_body  # noqa: E402
from arteq.body.skeleton import JOINT_NAMES  # noqa: E402


def demo_poses() -> dict[str, torch.Tensor]:
    """Three hand-made axis-angle poses ``[22, 3]`` (SMPL axes: y up, +z front)."""
    j = {n: i for i, n in enumerate(JOINT_NAMES)}
    walk = torch.zeros(22, 3)
    walk[j["left_hip"], 0], walk[j["right_hip"], 0] = -0.6, 0.4
    walk[j["right_knee"], 0] = 0.8
    walk[j["left_shoulder"], 2], walk[j["right_shoulder"], 2] = -1.2, 1.2
    walk[j["left_elbow"], 1], walk[j["right_elbow"], 1] = 0.5, -0.5
    reach = torch.zeros(22, 3)
    reach[j["left_shoulder"], 2] = 1.2
    reach[j["right_shoulder"], 1] = 1.2
    reach[j["spine2"], 2] = 0.3
    reach[j["head"], 1] = 0.5
    squat = torch.zeros(22, 3)
    squat[j["pelvis"], 1] = 0.6
    for s in ("left", "right"):
        squat[j[f"{s}_hip"], 0] = -1.4
        squat[j[f"{s}_knee"], 0] = 1.9
        squat[j[f"{s}_ankle"], 0] = -0.4
    squat[j["spine1"], 0] = 0.4
    squat[j["left_shoulder"], 1], squat[j["right_shoulder"], 1] = -1.0, 1.0
    return {"rest (T-pose)": torch.zeros(22, 3), "walk": walk, "reach": reach, "squat, turned": squat}


def render(body, out: Path, max_faces: int = 30000, dpi: int = 70, azim: float = 60.0) -> Path:
    cmap = matplotlib.colormaps["tab20"].resampled(22)
    faces = body.faces.cpu().numpy()
    rng = np.random.default_rng(0)
    keep = np.sort(rng.choice(len(faces), min(max_faces, len(faces)), replace=False))
    faces = faces[keep]
    face_part = body.part_labels.cpu().numpy()[faces[:, 0]]
    poses = demo_poses()
    fig = Figure(figsize=(3.2 * len(poses), 4.2))
    with torch.no_grad():
        for i, (title, pose) in enumerate(poses.items()):
            v = body(pose=pose).vertices.cpu().numpy()
            # plot in (x, z, y): matplotlib's z axis is up
            tri = v[:, [0, 2, 1]][faces]
            light = np.abs(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]))
            shade = 0.55 + 0.45 * (light[:, 1] / (np.linalg.norm(light, axis=1) + 1e-12))
            colors = cmap(face_part)[:, :3] * shade[:, None]
            # painter's order: farthest from the camera first
            a = np.deg2rad(azim)
            depth = tri.mean(1) @ np.array([np.cos(a), np.sin(a), 0.0])
            order = np.argsort(depth)
            ax = fig.add_subplot(1, len(poses), i + 1, projection="3d")
            ax.add_collection3d(Poly3DCollection(tri[order], facecolors=colors[order], linewidths=0))
            c, r = v.mean(0)[[0, 2, 1]], 0.85
            ax.set_xlim(c[0] - r, c[0] + r)
            ax.set_ylim(c[1] - r, c[1] + r)
            ax.set_zlim(c[2] - r, c[2] + r)
            ax.set_box_aspect((1, 1, 1))
            ax.view_init(elev=10, azim=azim)
            ax.set_axis_off()
            ax.set_title(title)
    fig.suptitle(f"{body.name}: {body.num_vertices} vertices, {body.faces.shape[0]} faces, 22 parts")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=dpi)
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("experiments/figures/body_anny22.png"))
    ap.add_argument("--body", default="anny22", help="anny22 | smpl | smplh | toy")
    ap.add_argument("--model-path", default=None)
    args = ap.parse_args(argv)
    body = create_body(name=args.body, model_path=args.model_path)
    print(render(body, args.out))


if __name__ == "__main__":
    main()
