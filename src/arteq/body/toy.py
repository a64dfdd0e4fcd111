"""A small procedural 22-part body, a :class:`~arteq.body.BodyModel`, for fast tests.

It is NOT a human model: capsule-like limbs (cylinders + spheres) on the SMPL 22-joint skeleton in
a T-pose (y up, facing +z, +x is the body's left, metres), skinned by the shared LBS of
:mod:`arteq.body.lbs` with weights that blend smoothly over a few centimetres around each joint, and
two "betas" (0: overall scale, 1: limb thickness). It lets the data pipeline be tested in a second
without building anny22. ``create_body({"name": "toy"})`` builds it.
"""

from __future__ import annotations

import numpy as np
import torch
import trimesh

from arteq.body.model import BodyModel
from arteq.body.skeleton import NUM_JOINTS, PARENTS

#: Rest (T-pose) joint positions, metres, SMPL axes.
_REST_JOINTS = np.array(
    [
        [0.00, 0.00, 0.00],  # pelvis
        [0.07, -0.09, 0.00],  # left_hip
        [-0.07, -0.09, 0.00],  # right_hip
        [0.00, 0.11, -0.01],  # spine1
        [0.10, -0.48, 0.00],  # left_knee
        [-0.10, -0.48, 0.00],  # right_knee
        [0.00, 0.24, 0.00],  # spine2
        [0.09, -0.88, -0.03],  # left_ankle
        [-0.09, -0.88, -0.03],  # right_ankle
        [0.00, 0.30, 0.01],  # spine3
        [0.11, -0.94, 0.10],  # left_foot
        [-0.11, -0.94, 0.10],  # right_foot
        [0.00, 0.52, 0.00],  # neck
        [0.07, 0.43, 0.00],  # left_collar
        [-0.07, 0.43, 0.00],  # right_collar
        [0.00, 0.60, 0.03],  # head
        [0.17, 0.45, 0.00],  # left_shoulder
        [-0.17, 0.45, 0.00],  # right_shoulder
        [0.43, 0.45, 0.00],  # left_elbow
        [-0.43, 0.45, 0.00],  # right_elbow
        [0.68, 0.45, 0.00],  # left_wrist
        [-0.68, 0.45, 0.00],  # right_wrist
    ]
)


def _build_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Template vertices [V,3], faces [F,3], owning part per vertex [V], and the joint regressor
    [22,V]: joint k = mean of the vertices of the sphere centred on it (exact, the spheres are
    symmetric)."""
    pieces: list[tuple[trimesh.Trimesh, int]] = []
    radius = {0: 0.11, 3: 0.1, 6: 0.11, 9: 0.12, 1: 0.07, 2: 0.07, 4: 0.05, 5: 0.05, 12: 0.05}
    for k in range(1, NUM_JOINTS):
        p = PARENTS[k]
        if p in (9,) and k in (13, 14):
            r = 0.05
        else:
            r = radius.get(p, 0.04)
        a, b = _REST_JOINTS[p], _REST_JOINTS[k]
        if np.linalg.norm(b - a) > 1e-3:
            pieces.append((trimesh.creation.cylinder(radius=r, segment=[a, b], sections=12), p))
    for k in range(NUM_JOINTS):
        pieces.append(
            (trimesh.creation.icosphere(subdivisions=1, radius=0.05).apply_translation(_REST_JOINTS[k]), k)
        )
    pieces.append(
        (trimesh.creation.icosphere(subdivisions=2, radius=0.1).apply_translation([0, 0.7, 0.02]), 15)
    )
    for k, d in ((20, 1.0), (21, -1.0)):  # hands
        hand = trimesh.creation.box(extents=[0.16, 0.03, 0.08]).apply_translation(
            _REST_JOINTS[k] + [d * 0.09, 0, 0]
        )
        pieces.append((hand, k))
    verts, faces, owner, off = [], [], [], 0
    sphere_rows: dict[int, tuple[int, int]] = {}
    first_sphere = len(pieces) - NUM_JOINTS - 3  # the 22 joint spheres follow the limbs
    for i, (mesh, part) in enumerate(pieces):
        if first_sphere <= i < first_sphere + NUM_JOINTS:
            sphere_rows[part] = (off, off + len(mesh.vertices))
        verts.append(np.asarray(mesh.vertices))
        faces.append(np.asarray(mesh.faces) + off)
        owner.append(np.full(len(mesh.vertices), part))
        off += len(mesh.vertices)
    regressor = np.zeros((NUM_JOINTS, off))
    for k, (a, b) in sphere_rows.items():
        regressor[k, a:b] = 1.0 / (b - a)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(owner), regressor


class ToyBody(BodyModel):
    """Procedural stand-in for a human body model: a :class:`BodyModel` whose shape step is
    procedural (overall scale times limb thickness, not linear in the betas); posing is the shared
    :func:`arteq.body.lbs.skin`. ``shapedirs`` hold the first-order shape directions."""

    def __init__(self, num_betas: int = 2, blend_width: float = 0.04) -> None:
        v, f, owner, regressor = _build_mesh()
        vt = torch.tensor(v, dtype=torch.float32)
        joints = torch.tensor(_REST_JOINTS, dtype=torch.float32)
        owner_t = torch.tensor(owner)
        # Smooth weights: vertices near a child joint blend with the child's part.
        w = torch.zeros(len(v), NUM_JOINTS)
        w[torch.arange(len(v)), owner_t] = 1.0
        for k in range(1, NUM_JOINTS):
            d = (vt - joints[k]).norm(dim=-1)
            near = (owner_t == PARENTS[k]) & (d < blend_width)
            a = 0.5 * (1 - d[near] / blend_width)
            w[near] = w[near] * (1 - a[:, None])
            w[near, k] += a
        owner_j = joints[w.argmax(-1)]
        shapedirs = torch.zeros(len(v), 3, max(2, num_betas))
        shapedirs[..., 0] = 0.05 * vt  # d v / d beta_0 at betas = 0
        shapedirs[..., 1] = 0.1 * (vt - owner_j)  # d v / d beta_1 at betas = 0
        super().__init__(vt, shapedirs, None, regressor, w, f, num_betas=num_betas, name="toy")
        self.register_buffer("j_template", joints, persistent=False)
        self.register_buffer("owner_joint", owner_j, persistent=False)

    def shape(self, betas: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``v = s (J_own + t (v0 - J_own))``, ``J = s J0`` with ``s = 1 + 0.05 b0`` (scale) and
        ``t = 1 + 0.1 b1`` (thickness; ``J_own``: the joint of the vertex's part)."""
        betas = torch.nn.functional.pad(betas, (0, max(0, 2 - betas.shape[1])))
        scale = 1 + 0.05 * betas[:, :1]  # [B, 1]
        thick = 1 + 0.1 * (betas[:, 1:2] if self.num_betas > 1 else 0 * scale)
        rest_joints = self.j_template[None] * scale[..., None]
        offset = (self.v_template - self.owner_joint)[None] * thick[..., None]
        v_shaped = (self.owner_joint[None] + offset) * scale[..., None]
        return v_shaped, rest_joints
