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


@tensor_cache(maxsize=16)
def tree_tables(
    parents: tuple[int, ...], device: torch.device
) -> tuple[list[tuple[torch.Tensor, torch.Tensor]], torch.Tensor, torch.Tensor, torch.Tensor]:
    """Index tables of a tree (root first, parents before children) for batched kinematics.

    Returns ``(levels, order_inv, ancestors, parent)``: per depth 1, 2, ... the joints at that depth and
    their parents' positions in the depth-first-level order (root, then depth 1, 2, ...); the position of
    each joint in that order; ``ancestors [K, K]`` with ``ancestors[k, a] = 1`` for every non-root ``a`` on
    the path from the root to ``k`` (``k`` included); the parent of each joint (the root's own index for
    the root).
    """
    k_all = len(parents)
    if parents[0] >= 0 or any(not 0 <= parents[k] < k for k in range(1, k_all)):
        raise ValueError(f"parents must list the root first (-1) and each parent before its child: {parents}")
    depth = [0] * k_all
    by_depth: dict[int, list[int]] = {}
    for k in range(1, k_all):
        depth[k] = depth[parents[k]] + 1
        by_depth.setdefault(depth[k], []).append(k)
    order = [0] + [k for d in sorted(by_depth) for k in by_depth[d]]
    pos = {k: i for i, k in enumerate(order)}
    levels = [
        (
            torch.tensor(by_depth[d], dtype=torch.long, device=device),
            torch.tensor([pos[parents[k]] for k in by_depth[d]], dtype=torch.long, device=device),
        )
        for d in sorted(by_depth)
    ]
    ancestors = torch.zeros(k_all, k_all, dtype=torch.float64)
    for k in range(1, k_all):
        a = k
        while a > 0:
            ancestors[k, a] = 1.0
            a = parents[a]
    order_inv = torch.tensor([pos[k] for k in range(k_all)], dtype=torch.long, device=device)
    return levels, order_inv, ancestors.to(device), _parent_index(parents, device)


def local_to_global(local_rotmats: torch.Tensor, parents: tuple[int, ...] = PARENTS) -> torch.Tensor:
    """Global rotations by accumulating local ones down the tree (parents precede children).

    One batched product per tree depth (8 for the body's 22 joints) instead of one per joint: the same
    products, so the same values, with a third of the operations forward and backward.

    Args:
        local_rotmats: ``[..., K, 3, 3]``.
    Returns:
        ``[..., K, 3, 3]`` with ``R_k = R_parent(k) theta_k``.
    """
    levels, order_inv, _, _ = tree_tables(tuple(parents), local_rotmats.device)
    done = local_rotmats[..., :1, :, :]  # the joints so far, in depth order
    for ids, parent_pos in levels:
        new = done.index_select(-3, parent_pos) @ local_rotmats.index_select(-3, ids)
        done = torch.cat([done, new], dim=-3)
    return done.index_select(-3, order_inv)
