"""Pure, batched, differentiable linear blend skinning in the SMPL format (22 body joints).

Conventions (SMPL's): ``pose`` holds *local* (parent-relative) rotation matrices expressed in the model's
world axes at rest; the root rotates the body about the pelvis joint; ``transl`` is added last. Pose
blendshapes, when given, are driven by ``(R_k - I)`` of joints ``1..K-1`` flattened row-major
(``(K-1) * 9`` features, 189 for 22 joints). A SMPL ``posedirs`` with 207 features (23 joints) is accepted:
the two folded hand joints are taken at identity, so their features are zero and their rows are skipped.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from arteq.body.skeleton import PARENTS, local_to_global, tree_tables


def _check(name: str, x: torch.Tensor, shape: tuple) -> None:
    """Raise a clear ``ValueError`` if ``x`` does not match ``shape`` (``None`` = any size)."""
    ok = x.dim() == len(shape) and all(s is None or s == d for s, d in zip(shape, x.shape))
    if not ok:
        want = "[" + ", ".join("*" if s is None else str(s) for s in shape) + "]"
        raise ValueError(f"lbs: `{name}` must have shape {want}, got {list(x.shape)}")


def pose_features(pose: torch.Tensor) -> torch.Tensor:
    """Pose-blendshape features ``(R_k - I)`` for joints ``1..K-1``.

    Args:
        pose: ``[B, K, 3, 3]`` local rotation matrices.
    Returns:
        ``[B, (K-1) * 9]``.
    """
    eye = torch.eye(3, dtype=pose.dtype, device=pose.device)
    return (pose[:, 1:] - eye).flatten(1)


def skin(
    v_shaped: torch.Tensor,
    rest_joints: torch.Tensor,
    pose: torch.Tensor,
    lbs_weights: torch.Tensor,
    parents: Sequence[int] = PARENTS,
    posedirs: torch.Tensor | None = None,
    transl: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Pose shaped rest vertices with given rest joints (forward kinematics + LBS).

    Args:
        v_shaped: ``[B, V, 3]`` rest-pose vertices (template + shape blendshapes).
        rest_joints: ``[B, K, 3]`` rest-pose joint positions.
        pose: ``[B, K, 3, 3]`` local rotation matrices.
        lbs_weights: ``[V, K]`` skinning weights (rows sum to 1).
        parents: length-``K`` parent table (root first, parents precede children).
        posedirs: ``[P, V*3]`` pose blendshapes or ``None``; ``P = (K-1)*9`` or ``(K+1)*9`` (SMPL's 207).
        transl: ``[B, 3]`` global translation or ``None``.
    Returns:
        vertices ``[B, V, 3]``, posed joints ``[B, K, 3]``, global rotations ``[B, K, 3, 3]``.
    """
    B, V, _ = v_shaped.shape
    K = len(parents)
    _check("v_shaped", v_shaped, (None, None, 3))
    _check("rest_joints", rest_joints, (B, K, 3))
    _check("pose", pose, (B, K, 3, 3))
    _check("lbs_weights", lbs_weights, (V, K))
    if posedirs is not None:
        feats = pose_features(pose)
        P = posedirs.shape[0]
        if posedirs.dim() != 2 or posedirs.shape[1] != V * 3 or P < feats.shape[1] or P % 9:
            raise ValueError(
                f"lbs: `posedirs` must have shape [P, {V * 3}] with P a multiple of 9 and >= "
                f"{feats.shape[1]} (extra joints are taken at identity), got {list(posedirs.shape)}"
            )
        # Extra joints (SMPL's folded hands) sit at identity: their features are 0, skip their rows.
        v_shaped = v_shaped + (feats @ posedirs[: feats.shape[1]]).view(B, V, 3)

    global_rot = local_to_global(pose, tuple(parents))
    # Posed joints: J'_k = J'_p + G_p (J_k - J_p); the root stays at its rest position. Unrolled:
    # J'_k = J_0 + sum over the path's non-root joints a of G_p(a) (J_a - J_p(a)), one product for all.
    _, _, ancestors, par = tree_tables(tuple(parents), pose.device)
    offsets = (global_rot[:, par] @ (rest_joints - rest_joints[:, par]).unsqueeze(-1)).squeeze(-1)
    joints = rest_joints[:, :1] + torch.einsum("ka,bac->bkc", ancestors.to(offsets.dtype), offsets)
    # Per-joint rigid transform x -> G_k x + (J'_k - G_k J_k), blended per vertex.
    trans = joints - (global_rot @ rest_joints.unsqueeze(-1)).squeeze(-1)  # [B, K, 3]
    rot_v = torch.einsum("vk,bkij->bvij", lbs_weights, global_rot)
    trans_v = torch.einsum("vk,bki->bvi", lbs_weights, trans)
    verts = (rot_v @ v_shaped.unsqueeze(-1)).squeeze(-1) + trans_v
    if transl is not None:
        _check("transl", transl, (B, 3))
        verts = verts + transl[:, None]
        joints = joints + transl[:, None]
    return verts, joints, global_rot


def shape_blend(
    betas: torch.Tensor, v_template: torch.Tensor, shapedirs: torch.Tensor, J_regressor: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor]:
    """Shaped rest mesh and its joints: ``v = v_template + shapedirs . betas``, ``J = J_regressor v``.

    Args:
        betas: ``[B, nb]`` (``nb <= NB``: the first ``nb`` shape directions are used).
        v_template: ``[V, 3]``; shapedirs: ``[V, 3, NB]``; J_regressor: ``[K, V]``.
    Returns:
        ``v_shaped [B, V, 3]``, ``rest_joints [B, K, 3]``.
    """
    _check("v_template", v_template, (None, 3))
    V = v_template.shape[0]
    _check("shapedirs", shapedirs, (V, 3, None))
    _check("betas", betas, (None, None))
    _check("J_regressor", J_regressor, (None, V))
    nb = betas.shape[1]
    if nb > shapedirs.shape[-1]:
        raise ValueError(f"lbs: got {nb} betas but the model has only {shapedirs.shape[-1]} shape directions")
    v_shaped = v_template + torch.einsum("bl,vcl->bvc", betas, shapedirs[..., :nb])
    rest_joints = torch.einsum("kv,bvc->bkc", J_regressor, v_shaped)
    return v_shaped, rest_joints


def lbs(
    betas: torch.Tensor,
    pose: torch.Tensor,
    v_template: torch.Tensor,
    shapedirs: torch.Tensor,
    posedirs: torch.Tensor | None,
    J_regressor: torch.Tensor,
    parents: Sequence[int],
    lbs_weights: torch.Tensor,
    transl: torch.Tensor | None = None,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """SMPL-format linear blend skinning.

    Args:
        betas: ``[B, nb]`` shape coefficients (``nb <= shapedirs.shape[-1]``; only the first ``nb``
            shape directions are used).
        pose: ``[B, K, 3, 3]`` local rotation matrices (``K = len(parents)``, 22 for SMPL's body).
        v_template: ``[V, 3]`` mean rest-pose vertices.
        shapedirs: ``[V, 3, NB]`` shape blendshapes.
        posedirs: ``[P, V*3]`` pose blendshapes, or ``None`` for none.
        J_regressor: ``[K, V]`` dense joint regressor (rest joints = ``J_regressor @ v_shaped``).
        parents: length-``K`` parent table.
        lbs_weights: ``[V, K]`` skinning weights.
        transl: ``[B, 3]`` or ``None``.
    Returns:
        vertices ``[B, V, 3]``, posed joints ``[B, K, 3]``, global rotations ``[B, K, 3, 3]``,
        rest joints ``[B, K, 3]``.
    """
    _check("J_regressor", J_regressor, (len(parents), None))
    v_shaped, rest_joints = shape_blend(betas, v_template, shapedirs, J_regressor)
    verts, joints, global_rot = skin(v_shaped, rest_joints, pose, lbs_weights, parents, posedirs, transl)
    return verts, joints, global_rot, rest_joints
