"""Articulated equivariance, measured: turn one limb about its joint and see what the network does.

ArtEq's claim is *part-wise* equivariance: if one kinematic subtree (a forearm with its hand, a shin with
its foot, a whole arm or leg) is turned about its joint by a group element ``g``, the moved part's
features should turn by ``g`` (the group permutation of :func:`arteq.equivariant.rotate_group_features`),
its predicted rotation should become ``R_g`` times the prediction before the move, and the parts that did
not move should not change. A whole-body rotation test cannot see this property: a network whose
neighbourhoods span the whole body is exactly equivariant to global rotations and not at all to
articulation.

:func:`articulated_equivariance` measures it on clean surface samples of a body model:

1. a pose from a pose source, its mesh, and a surface sample (faces and barycentric coordinates, no
   noise) with part labels;
2. for each tested joint ``k`` and group element ``g`` (order-5 elements, 72 degrees, chosen so that the
   moved subtree stays clear of the rest of the body), the pose with the subtree's global rotations
   left-multiplied by ``R_g`` (``L_k' = G_p^T R_g G_p L_k``), the *same* surface sample on the new mesh,
   the *same* FPS indices;
3. features pooled per part with the ground-truth labels, and the network's part rotations with
   ground-truth pooling.

Reported per joint (means over poses and elements): ``feat_moved`` = ``|F'_k - g.F_k| / |F_k|`` (the
moved part against its group-rotated original; 0 = part-equivariant, ~1 = no relation),
``feat_parent`` / ``feat_far`` = ``|F'_q - F_q| / |F_q|`` for the parent and for the parts outside the
subtree and its parent; ``rot_moved_deg`` = angle between the moved part's predicted rotation and ``R_g``
times its prediction before the move, ``rot_parent_deg`` / ``rot_far_deg`` the change of the others'
predictions, ``err_before_deg`` / ``err_after_deg`` the moved part's error against the ground truth
before and after the move. Linear blend skinning bends the skin around the joint, so even a perfectly
part-local network shows a small ``feat_moved`` there; a whole-body rotation (``joint="global"``
internally: every part moved) is the control and is exact.

Command: ``python -m arteq.models.articulation --ckpt anny22`` (a checkpoint, a run folder or a shipped
model name) or ``--config arteq_local`` (a model config at random initialisation); see
``benchmarks/bench_articulation.py`` for the table of old against new architecture.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from dataclasses import dataclass

import torch
import torch.nn.functional as F

from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS
from arteq.equivariant.group import group_rotations, rotate_group_features, rotation_angles
from arteq.geometry.rotations import geodesic_deg
from arteq.geometry.sampling import interpolate_labels, sample_surface
from arteq.models.heads import pool_parts

#: Joints whose subtree the default probe turns (elbow, knee, shoulder, hip on both sides).
DEFAULT_JOINTS = (
    "left_elbow", "right_elbow", "left_knee", "right_knee",
    "left_shoulder", "right_shoulder", "left_hip", "right_hip",
)  # fmt: skip
METRICS = (
    "feat_moved", "feat_parent", "feat_far",
    "rot_moved_deg", "rot_parent_deg", "rot_far_deg", "err_before_deg", "err_after_deg",
)  # fmt: skip


def subtree(joint: int) -> list[int]:
    """``joint`` and all its descendants in the 22-part tree."""
    out = [joint]
    for j in range(NUM_JOINTS):  # parents precede children in the table
        if PARENTS[j] in out and j not in out:
            out.append(j)
    return out


def turn_subtree(local: torch.Tensor, global_: torch.Tensor, joint: int, rot: torch.Tensor) -> torch.Tensor:
    """Local rotations ``[22, 3, 3]`` with the subtree of ``joint`` turned by the world rotation ``rot``
    about the joint: the subtree's global rotations become ``rot @ G`` (the others are unchanged)."""
    out = local.clone()
    gp = global_[PARENTS[joint]] if joint > 0 else torch.eye(3, dtype=local.dtype)
    out[joint] = gp.T @ rot.to(local.dtype) @ gp @ local[joint]
    return out


def _relative(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """``|a - b| / |b|`` over the last two dims (group, channels)."""
    return (a - b).flatten(-2).norm(dim=-1) / b.flatten(-2).norm(dim=-1).clamp_min(1e-12)


def clear_elements(
    verts: torch.Tensor,
    joints: torch.Tensor,
    labels_v: torch.Tensor,
    joint: int,
    count: int,
    clearance: float,
) -> list[int]:
    """Up to ``count`` order-5 group elements that turn the subtree of ``joint`` (rigidly, about the joint)
    without bringing it within ``clearance`` metres of the body outside the subtree and its parent."""
    rots = group_rotations(torch.float64)
    five = [int(i) for i in torch.nonzero((torch.rad2deg(rotation_angles()) - 72.0).abs() < 1e-6).flatten()]
    sub = torch.tensor(subtree(joint))
    moving = torch.isin(labels_v, sub)
    centre = joints[joint]
    # skin near the joint bends with both parts: leave it out of the clearance test
    moving &= (verts - centre).norm(dim=-1) > 0.08
    still = ~torch.isin(labels_v, torch.cat([sub, torch.tensor([max(PARENTS[joint], 0)])]))
    mv, st = verts[moving].double(), verts[still].double()
    good = []
    for e in five:
        moved = (mv - centre) @ rots[e].T + centre
        if torch.cdist(moved, st).min() > clearance:
            good.append(e)
    if len(good) > count:  # spread over the candidates, deterministically
        pick = torch.linspace(0, len(good) - 1, count).round().long()
        good = [good[int(i)] for i in pick]
    return good


@dataclass
class ProbeResult:
    """Per-joint means of :data:`METRICS`, the overall mean, and how many moves were measured."""

    per_joint: dict[str, dict[str, float]]
    mean: dict[str, float]
    moves: int

    def markdown(self, title: str = "") -> str:
        head = "| joint | moves | " + " | ".join(METRICS) + " |"
        lines = [f"**{title}**", ""] if title else []
        lines += [head, "|---|---:|" + "---:|" * len(METRICS)]
        for name, row in [*self.per_joint.items(), ("mean", self.mean)]:
            cells = " | ".join(f"{row[m]:.3f}" if m.startswith("feat") else f"{row[m]:.1f}" for m in METRICS)
            lines.append(f"| {name} | {int(row.get('moves', self.moves))} | {cells} |")
        return "\n".join(lines)


@torch.no_grad()
def articulated_equivariance(
    net: torch.nn.Module,
    body: torch.nn.Module,
    joints: Sequence[str] = DEFAULT_JOINTS,
    num_poses: int = 4,
    elements_per_joint: int = 2,
    num_points: int = 500,
    seed: int = 0,
    source=None,
    clearance: float = 0.05,
) -> ProbeResult:
    """Turn subtrees about their joints by group elements and compare features and predictions (see the
    module docstring). ``net``: an :class:`arteq.models.ArtEqNet` (its backbone and pose head are used);
    ``body``: a body model; ``source``: a pose source (default :class:`arteq.data.poses.SyntheticIDPoses`)."""
    from arteq.data.poses import SyntheticIDPoses

    unknown = [j for j in joints if j not in JOINT_NAMES]
    if unknown:
        raise ValueError(f"articulated_equivariance: unknown joints {unknown}; known: {list(JOINT_NAMES)}")
    if num_poses < 1 or elements_per_joint < 1:
        raise ValueError("articulated_equivariance: num_poses and elements_per_joint must be >= 1")
    source = source or SyntheticIDPoses()
    was_training = net.training
    net.eval()
    dtype = next(net.parameters()).dtype
    rots = group_rotations(torch.float64)
    faces = body.faces
    labels_v = body.lbs_weights.argmax(-1)
    rows: dict[str, list[dict[str, float]]] = {j: [] for j in joints}
    try:
        for p in range(num_poses):
            g = torch.Generator().manual_seed(seed * 1000 + p)
            local = _as_rotmats(source.sample(p, g)["pose"])
            out = body(pose=local[None].to(body.lbs_weights.dtype))
            verts, glob, jts = out.vertices[0], out.global_rotmats[0].double(), out.joints[0]
            _, face_idx, bary = sample_surface(verts, faces, num_points, g)
            labels = interpolate_labels(body.lbs_weights, faces, face_idx, bary)
            # the moves of this pose, batched: [original, (joint, element)...]
            moves: list[tuple[str, int]] = []
            clouds = [_points(verts, faces, face_idx, bary)]
            for name in joints:
                k = JOINT_NAMES.index(name)
                for e in clear_elements(verts, jts, labels_v, k, elements_per_joint, clearance):
                    lk = turn_subtree(local, glob, k, rots[e])
                    vb = body(pose=lk[None].to(body.lbs_weights.dtype)).vertices[0]
                    moves.append((name, e))
                    clouds.append(_points(vb, faces, face_idx, bary))
            if not moves:
                continue
            pts = torch.stack(clouds).to(dtype)
            fps = net.backbone.compute_fps(pts[:1]).expand(len(clouds), -1)
            lab = labels[None].expand(len(clouds), -1)
            feats = net.backbone(pts, fps_idx=fps)
            part = pool_parts(feats, F.one_hot(lab, NUM_JOINTS).to(feats.dtype)).double()  # [M+1, K, A, C]
            pred = net(pts, gt_labels=lab, fps_idx=fps)["global_rotmats"].double()  # [M+1, K, 3, 3]
            for i, (name, e) in enumerate(moves, start=1):
                k = JOINT_NAMES.index(name)
                sub = set(subtree(k))
                par = max(PARENTS[k], 0)
                far = [q for q in range(NUM_JOINTS) if q not in sub and q != par]
                gt_after = rots[e] @ glob[k]
                rows[name].append(
                    {
                        "feat_moved": float(_relative(part[i, k], rotate_group_features(part[0, k], e, 0))),
                        "feat_parent": float(_relative(part[i, par], part[0, par])),
                        "feat_far": float(_relative(part[i, far], part[0, far]).mean()),
                        "rot_moved_deg": float(geodesic_deg(pred[i, k], rots[e] @ pred[0, k])),
                        "rot_parent_deg": float(geodesic_deg(pred[i, par], pred[0, par])),
                        "rot_far_deg": float(geodesic_deg(pred[i, far], pred[0, far]).mean()),
                        "err_before_deg": float(geodesic_deg(pred[0, k], glob[k])),
                        "err_after_deg": float(geodesic_deg(pred[i, k], gt_after)),
                    }
                )
    finally:
        net.train(was_training)
    per_joint = {}
    for name, rs in rows.items():
        if rs:
            per_joint[name] = {m: sum(r[m] for r in rs) / len(rs) for m in METRICS} | {"moves": len(rs)}
    allr = [r for rs in rows.values() for r in rs]
    if not allr:
        raise RuntimeError(
            "articulated_equivariance: no group element kept any tested subtree clear of the body"
        )
    mean = {m: sum(r[m] for r in allr) / len(allr) for m in METRICS} | {"moves": len(allr)}
    return ProbeResult(per_joint, mean, len(allr))


def _as_rotmats(pose: torch.Tensor) -> torch.Tensor:
    import roma

    pose = pose.double()
    return pose if pose.shape[-2:] == (3, 3) else roma.rotvec_to_rotmat(pose)


def _points(
    verts: torch.Tensor, faces: torch.Tensor, face_idx: torch.Tensor, bary: torch.Tensor
) -> torch.Tensor:
    tri = verts[faces[face_idx]]
    return (bary.to(verts.dtype)[..., None] * tri).sum(1)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    src = ap.add_mutually_exclusive_group(required=True)
    src.add_argument("--ckpt", help="checkpoint, run folder or shipped model name (e.g. anny22)")
    src.add_argument(
        "--config", help="a model config name at random init (arteq, arteq_local) or a JSON net config"
    )
    ap.add_argument("--poses", type=int, default=4)
    ap.add_argument("--elements", type=int, default=2)
    ap.add_argument("--points", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--json", help="also write the result here")
    args = ap.parse_args(argv)
    torch.manual_seed(args.seed)
    if args.ckpt:
        from arteq.pretrained.card import load_module

        module = load_module(args.ckpt)
        net, body = module.net, module.body
    else:
        from arteq.body.factory import create_body
        from arteq.models.registry import build_net

        cfg = (
            json.loads(args.config)
            if args.config.lstrip().startswith("{")
            else default_net_config(args.points, args.config)
        )
        net, body = build_net(cfg), create_body({"name": "anny22"})
    res = articulated_equivariance(net, body, num_poses=args.poses, elements_per_joint=args.elements,
                                   num_points=args.points, seed=args.seed)  # fmt: skip
    print(res.markdown(args.ckpt or "random init"))
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"per_joint": res.per_joint, "mean": res.mean}, f, indent=1)


def default_net_config(num_points: int = 500, model: str = "arteq") -> dict:
    """The ArtEq network config of ``conf/model/<model>.yaml`` (``arteq``: the default, ``arteq_local``: the
    part-local variant), composed by Hydra and resolved at ``num_points``."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from arteq.config import register_resolvers
    from arteq.paths import conf_dir

    register_resolvers()
    with initialize_config_dir(version_base="1.3", config_dir=str(conf_dir())):
        cfg = compose("train", overrides=[f"model={model}", f"data.num_points={num_points}"])
    net = OmegaConf.to_container(cfg.model.net, resolve=True)
    net.setdefault("num_betas", 10)
    return net


if __name__ == "__main__":
    main()

__all__ = ["DEFAULT_JOINTS", "METRICS", "ProbeResult", "articulated_equivariance", "subtree", "turn_subtree"]
