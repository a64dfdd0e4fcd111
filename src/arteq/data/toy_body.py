"""A small procedural 22-part body with the ``BodyModel`` call signature, for fast data tests.

It is NOT a human model: capsule-like limbs (cylinders + spheres) on the SMPL 22-joint skeleton in
a T-pose (y up, facing +z, +x is the body's left, metres), linear blend skinning with weights that
blend smoothly over a few centimetres around each joint, and two "betas" (0: overall scale,
1: limb thickness). It lets the data pipeline be tested in a second without building anny22.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import roma
import torch
import trimesh
from torch import nn

from arteq.body.skeleton import NUM_JOINTS, PARENTS, local_to_global

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


@dataclass
class ToyBodyOutput:
    vertices: torch.Tensor  # [B, V, 3]
    joints: torch.Tensor  # [B, 22, 3]
    global_rotmats: torch.Tensor  # [B, 22, 3, 3]
    rest_joints: torch.Tensor  # [B, 22, 3]


def _build_mesh() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Template vertices [V,3], faces [F,3], owning part per vertex [V]."""
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
    for mesh, part in pieces:
        verts.append(np.asarray(mesh.vertices))
        faces.append(np.asarray(mesh.faces) + off)
        owner.append(np.full(len(mesh.vertices), part))
        off += len(mesh.vertices)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(owner)


class ToyBody(nn.Module):
    """Procedural stand-in with ``BodyModel``'s interface: ``body(betas, pose, transl)``."""

    def __init__(self, num_betas: int = 2, blend_width: float = 0.04) -> None:
        super().__init__()
        v, f, owner = _build_mesh()
        vt = torch.tensor(v, dtype=torch.float32)
        joints = torch.tensor(_REST_JOINTS, dtype=torch.float32)
        # Smooth weights: vertices near a child joint blend with the child's part.
        w = torch.zeros(len(v), NUM_JOINTS)
        w[torch.arange(len(v)), torch.tensor(owner)] = 1.0
        for k in range(1, NUM_JOINTS):
            d = (vt - joints[k]).norm(dim=-1)
            near = (torch.tensor(owner) == PARENTS[k]) & (d < blend_width)
            a = 0.5 * (1 - d[near] / blend_width)
            w[near] = w[near] * (1 - a[:, None])
            w[near, k] += a
        self.num_betas = num_betas
        self.name = "toy"
        self.register_buffer("v_template", vt)
        self.register_buffer("faces", torch.tensor(f, dtype=torch.long))
        self.register_buffer("lbs_weights", w)
        self.register_buffer("part_labels", w.argmax(-1))
        self.register_buffer("j_template", joints)

    def forward(
        self,
        betas: torch.Tensor | None = None,
        pose: torch.Tensor | None = None,
        transl: torch.Tensor | None = None,
    ) -> ToyBodyOutput:
        """``betas [B,nb]``, ``pose [B,22,3,3]`` or ``[B,22,3]`` axis-angle, ``transl [B,3]``."""
        if pose is None:
            raise ValueError("pose is required")
        if pose.shape[-1] == 3 and pose.shape[-2] == NUM_JOINTS:
            pose = roma.rotvec_to_rotmat(pose)
        b = pose.shape[0]
        dtype = self.v_template.dtype
        pose = pose.to(dtype)
        if betas is None:
            betas = torch.zeros(b, self.num_betas, dtype=dtype, device=pose.device)
        scale = 1 + 0.05 * betas[:, :1].to(dtype)  # [B,1]
        thick = 1 + 0.1 * (betas[:, 1:2].to(dtype) if self.num_betas > 1 else 0 * scale)
        jr = self.j_template[None] * scale[..., None]
        owner_j = self.j_template[self.part_labels]
        vr = (owner_j[None] + (self.v_template - owner_j)[None] * thick[..., None]) * scale[..., None]
        grot = local_to_global(pose)
        jp = [jr[:, 0]]
        for k in range(1, NUM_JOINTS):
            p = PARENTS[k]
            jp.append(jp[p] + (grot[:, p] @ (jr[:, k] - jr[:, p])[..., None])[..., 0])
        joints = torch.stack(jp, 1)
        # v = sum_k w_k (R_k (v - J_k^rest) + J_k)
        per_part = torch.einsum("bkij,bvkj->bvki", grot, vr[:, :, None, :] - jr[:, None]) + joints[:, None]
        verts = (self.lbs_weights[None, :, :, None] * per_part).sum(2)
        if transl is not None:
            verts = verts + transl[:, None].to(dtype)
            joints = joints + transl[:, None].to(dtype)
        return ToyBodyOutput(verts, joints, grot, jr)
