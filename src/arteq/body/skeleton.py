"""The 22-part body tree shared by SMPL and anny22: joint names, parents and helpers.

Order and parent table are SMPL's first 22 joints (pelvis .. wrists). SMPL's hand joints
(22, 23: left/right hand) fold into the wrists, as in the paper.
"""

from __future__ import annotations

import torch

from arteq.tensor_cache import tensor_cache

JOINT_NAMES: tuple[str, ...] = (
    "pelvis",
    "left_hip",
    "right_hip",
    "spine1",
    "left_knee",
    "right_knee",
    "spine2",
    "left_ankle",
    "right_ankle",
    "spine3",
    "left_foot",
    "right_foot",
    "neck",
    "left_collar",
    "right_collar",
    "head",
    "left_shoulder",
    "right_shoulder",
    "left_elbow",
    "right_elbow",
    "left_wrist",
    "right_wrist",
)
NUM_JOINTS = len(JOINT_NAMES)

#: Parent of each joint (-1 for the root), SMPL's table restricted to the 22 body joints.
PARENTS: tuple[int, ...] = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19)

#: SMPL's 24-joint table folds joints 22/23 (left/right hand) into 20/21 (wrists).
SMPL24_TO_22: tuple[int, ...] = tuple(range(22)) + (20, 21)


def parents_tensor(device: torch.device | str | None = None) -> torch.Tensor:
    """Parents as a LongTensor ``[22]`` (root = -1)."""
    return torch.tensor(PARENTS, dtype=torch.long, device=device)


def global_to_local(global_rotmats: torch.Tensor, parents: tuple[int, ...] = PARENTS) -> torch.Tensor:
    """Local (parent-relative) rotations from global ones.

    ``theta_0 = R_0`` and ``theta_k = R_parent(k)^T R_k``.

    Args:
        global_rotmats: ``[..., K, 3, 3]`` global rotation of each part.
    Returns:
        ``[..., K, 3, 3]`` local rotations.
    """
    par = _parent_index(tuple(parents), global_rotmats.device)
    parent_rot = global_rotmats[..., par, :, :]
    local = parent_rot.transpose(-1, -2) @ global_rotmats
    return torch.cat([global_rotmats[..., :1, :, :], local[..., 1:, :, :]], dim=-3)


@tensor_cache(maxsize=16)
def _parent_index(parents: tuple[int, ...], device: torch.device) -> torch.Tensor:
    """Parent index tensor on ``device``, built once: a fresh host-to-GPU copy on every call would make
    the training step wait for the GPU (a blocking copy synchronises the stream)."""
    return torch.tensor([p if p >= 0 else 0 for p in parents], device=device)


def local_to_global(local_rotmats: torch.Tensor, parents: tuple[int, ...] = PARENTS) -> torch.Tensor:
    """Global rotations by accumulating local ones down the tree (parents precede children).

    Args:
        local_rotmats: ``[..., K, 3, 3]``.
    Returns:
        ``[..., K, 3, 3]`` with ``R_k = R_parent(k) theta_k``.
    """
    out = [local_rotmats[..., 0, :, :]]
    for k in range(1, len(parents)):
        out.append(out[parents[k]] @ local_rotmats[..., k, :, :])
    return torch.stack(out, dim=-3)
