"""Fit a body model to a point cloud by optimisation (Chamfer objective + simple priors).

The objective, in centimetres squared so that the weights read naturally:

``E = w_p2m mean_i |p_i - v_nn(i)|^2 + w_m2p mean_j |v_j - p_nn(j)|^2
+ w_pose mean_k |theta_k|^2 + w_limit mean_k relu(|theta_k|^2 - limit^2) + w_betas mean |beta|^2``

with ``p`` the cloud, ``v`` the posed mesh vertices (the mesh -> points direction uses a fixed,
evenly spread vertex subset), ``theta_k`` the local axis-angle of the non-root joints (radians).
Nearest neighbours are found without gradient (``arteq.geometry.pointops.knn``) and the distances
recomputed differentiably, the usual ICP-style alternation done once per iteration.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import roma
import torch

from arteq.body.skeleton import NUM_JOINTS
from arteq.geometry.pointops import farthest_point_sample, gather, knn
from arteq.results import BodyFitResult

#: The result of :func:`fit_body`: :class:`arteq.results.BodyFitResult` (``pose`` reads its
#: ``local_rotmats``; ``pose_aa`` is set), the type :func:`arteq.fit.refine.refine` returns too.
OptimFitResult = BodyFitResult


def root_candidates(count: int, dtype=torch.float32, device=None) -> torch.Tensor:
    """``[count, 3, 3]`` root orientations tried from a standard start: 1 = identity; 24 = the
    rotations of the cube (signed permutation matrices with determinant +1), identity first."""
    if count == 1:
        return torch.eye(3, dtype=dtype, device=device)[None]
    if count != 24:
        raise ValueError(f"root_candidates: count must be 1 or 24, got {count}")
    mats = []
    for perm in ((0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)):
        for signs in range(8):
            m = torch.zeros(3, 3, dtype=torch.float64)
            for r, c in enumerate(perm):
                m[r, c] = -1.0 if signs >> r & 1 else 1.0
            if torch.det(m) > 0:
                mats.append(m)
    mats.sort(key=lambda m: -float(torch.trace(m)))  # identity first
    return torch.stack(mats).to(dtype=dtype, device=device)


def chamfer_terms(
    points: torch.Tensor, vertices: torch.Tensor, vertex_subset: torch.Tensor | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """Mean squared nearest-neighbour distances, in cm^2, per cloud.

    Args:
        points: ``[B, N, 3]`` metres; vertices: ``[B, V, 3]`` metres (differentiable);
        vertex_subset: ``[S]`` long, the vertices used in the mesh -> points direction (all if None).
    Returns:
        ``(p2m [B], m2p [B])``.
    """
    _, idx = knn(points, vertices, 1)
    p2m = ((points - gather(vertices, idx[..., 0])) * 100).square().sum(-1).mean(-1)
    vs = vertices if vertex_subset is None else vertices[:, vertex_subset]
    _, idx2 = knn(vs, points, 1)
    m2p = ((vs - gather(points, idx2[..., 0])) * 100).square().sum(-1).mean(-1)
    return p2m, m2p


def _check_points(points: torch.Tensor) -> None:
    if not isinstance(points, torch.Tensor) or points.ndim != 3 or points.shape[-1] != 3:
        shape = tuple(points.shape) if isinstance(points, torch.Tensor) else type(points).__name__
        raise ValueError(f"fit_body: points must be a [B, N, 3] tensor, got {shape}")
    if points.shape[1] == 0:
        raise ValueError("fit_body: points is an empty cloud (N = 0)")
    if not torch.isfinite(points).all():
        raise ValueError("fit_body: points contains NaN or Inf")
    extent = float((points.amax(1) - points.amin(1)).max())
    if extent > 10.0:
        raise ValueError(f"fit_body: points span {extent:.1f} units; expected metres (a body is ~2 m)")


def fit_body(
    body: torch.nn.Module,
    points: torch.Tensor,
    init: dict[str, torch.Tensor] | None = None,
    iters: int = 300,
    lr: float = 0.02,
    optimizer: str = "adam",
    w_p2m: float = 1.0,
    w_m2p: float = 1.0,
    w_pose: float = 0.01,
    w_limit: float = 10.0,
    joint_limit_deg: float = 150.0,
    w_betas: float = 0.01,
    fit_betas: bool = True,
    num_roots: int = 1,
    mesh_subset: int | torch.Tensor | None = 2000,
    tol: float = 1e-5,
    patience: int = 30,
) -> OptimFitResult:
    """Fit local pose (axis-angle), betas and translation of ``body`` to ``points``.

    Args:
        body: ``arteq.body.BodyModel`` (or anything with its call signature, ``num_betas``, ``faces``).
        points: ``[B, N, 3]`` clouds in metres.
        init: optional start ``{"pose": [B,22,3,3] local rotmats or [B,22,3] axis-angle, "betas": [B,nb],
            "transl": [B,3]}`` (e.g. ArtEq's prediction: the "refinement" option); missing entries take the
            standard start: rest pose, zero betas, translation putting the mesh centroid on the cloud's.
        iters: maximum iterations (Adam steps, or L-BFGS outer steps of up to 20 evaluations).
        lr: Adam learning rate (cosine-decayed to 5 %), or L-BFGS step size.
        optimizer: ``"adam"`` or ``"lbfgs"``.
        w_*: objective weights (see module docstring); ``joint_limit_deg``: free angle per joint.
        fit_betas: optimise shape (else kept at its start).
        num_roots: 1, or 24 to start from the best of the cube's 24 root orientations (by initial
            Chamfer) when no initial pose is given.
        mesh_subset: number of vertices (farthest-point sampled on the rest mesh) in the mesh -> points
            term, or their indices (``[S]`` long tensor), or None for all.
        tol, patience: stop when the objective improved by less than ``tol`` (relative) over
            ``patience`` iterations.
    Returns:
        :class:`OptimFitResult` with ``history`` (objective terms per iteration), ``iterations`` and
        ``seconds`` (wall clock).
    """
    _check_points(points)
    if optimizer not in ("adam", "lbfgs"):
        raise ValueError(f"fit_body: optimizer must be 'adam' or 'lbfgs', got {optimizer!r}")
    if iters < 0:
        raise ValueError(f"fit_body: iters must be >= 0, got {iters}")
    t0 = time.time()
    init = dict(init or {})
    b, nb = points.shape[0], int(body.num_betas)
    dtype, device = body.lbs_weights.dtype, points.device
    points = points.to(dtype)
    like = {"dtype": dtype, "device": device}

    aa = _start_pose(init.get("pose"), b, like)
    given = _given(init, "betas", (b, nb), like)
    betas = given if given is not None else torch.zeros(b, nb, **like)
    subset = _mesh_subset(body, mesh_subset, nb, like)
    if aa is None:
        aa = _best_root(body, points, betas, subset, num_roots, w_p2m, w_m2p, like)
    transl = _given(init, "transl", (b, 3), like)
    if transl is None:
        transl = _centroid_transl(body, points, aa, betas)

    params = [aa.requires_grad_(True), transl.requires_grad_(True)]
    if fit_betas:
        params.append(betas.requires_grad_(True))
    weights = {"p2m": w_p2m, "m2p": w_m2p, "pose": w_pose, "limit": w_limit, "betas": w_betas}
    limit2 = math.radians(joint_limit_deg) ** 2

    def objective() -> tuple[torch.Tensor, dict[str, float]]:
        return _objective(body, points, subset, aa, betas, transl, weights, limit2)

    history = _optimise(params, objective, iters, lr, optimizer, tol, patience)
    with torch.no_grad():
        out = body(betas=betas, pose=aa, transl=transl)
        pose = roma.rotvec_to_rotmat(aa)
    return OptimFitResult(
        local_rotmats=pose.detach(),
        betas=betas.detach(),
        transl=transl.detach(),
        vertices=out.vertices.detach(),
        joints=out.joints.detach(),
        global_rotmats=out.global_rotmats.detach(),
        history=history,
        iterations=len(history),
        seconds=time.time() - t0,
        pose_aa=aa.detach(),
    )


# ------------------------------------------------------------------ the pieces of fit_body
def _given(
    init: dict[str, Any], key: str, shape: tuple[int, ...], like: dict[str, Any]
) -> torch.Tensor | None:
    """A detached copy of ``init[key]`` checked to have ``shape``, or None when not given."""
    if init.get(key) is None:
        return None
    x = init[key].detach().to(**like).clone()
    if x.shape != shape:
        want = ",".join(map(str, shape))
        raise ValueError(f"fit_body: init[{key!r}] must be [{want}], got {tuple(x.shape)}")
    return x


def _start_pose(pose: torch.Tensor | None, b: int, like: dict[str, Any]) -> torch.Tensor | None:
    """Local axis-angle ``[B, 22, 3]`` from given rotmats or axis-angle; None when not given."""
    if pose is None:
        return None
    p = pose.detach().to(**like)
    if p.shape == (b, NUM_JOINTS, 3, 3):
        return roma.rotmat_to_rotvec(roma.special_procrustes(p))
    if p.shape == (b, NUM_JOINTS, 3):
        return p.clone()
    raise ValueError(f"fit_body: init['pose'] must be [{b},22,3,3] or [{b},22,3], got {tuple(p.shape)}")


def _mesh_subset(
    body: torch.nn.Module, mesh_subset: int | torch.Tensor | None, nb: int, like: dict[str, Any]
) -> torch.Tensor | None:
    """Vertex indices of the mesh -> points term: given, farthest-point sampled on the rest mesh, or
    None (all vertices)."""
    num_vertices = body.lbs_weights.shape[0]
    if isinstance(mesh_subset, torch.Tensor):
        subset = mesh_subset.to(device=like["device"], dtype=torch.long)
        if subset.ndim != 1 or subset.numel() == 0 or int(subset.max()) >= num_vertices:
            raise ValueError("fit_body: mesh_subset indices must be a non-empty [S] tensor of vertex indices")
        return subset
    if mesh_subset is None or mesh_subset >= num_vertices:
        return None
    with torch.no_grad():
        rest = body(betas=torch.zeros(1, nb, **like)).vertices
        rest = rest if rest.dim() == 3 else rest[None]
        return farthest_point_sample(rest[:1], int(mesh_subset))[0]


def _centroid_transl(body: torch.nn.Module, points: torch.Tensor, aa: torch.Tensor, betas: torch.Tensor):
    """Translation putting the posed mesh's vertex centroid on the cloud's centroid."""
    with torch.no_grad():
        v = body(betas=betas, pose=aa).vertices
        return points.mean(1) - v.mean(1)


def _best_root(
    body: torch.nn.Module,
    points: torch.Tensor,
    betas: torch.Tensor,
    subset: torch.Tensor | None,
    num_roots: int,
    w_p2m: float,
    w_m2p: float,
    like: dict[str, Any],
) -> torch.Tensor:
    """Standard start: rest pose with, per cloud, the root orientation of :func:`root_candidates`
    of lowest initial Chamfer cost (centroid translation)."""
    b = points.shape[0]
    aa = torch.zeros(b, NUM_JOINTS, 3, **like)
    cands = root_candidates(num_roots, **like)
    if len(cands) == 1:
        return aa
    best, best_cost = None, None
    for c in cands:
        aa_c = aa.clone()
        aa_c[:, 0] = roma.rotmat_to_rotvec(c).expand(b, 3)
        t_c = _centroid_transl(body, points, aa_c, betas)
        with torch.no_grad():
            v = body(betas=betas, pose=aa_c, transl=t_c).vertices
            p2m, m2p = chamfer_terms(points, v, subset)
        cost = w_p2m * p2m + w_m2p * m2p
        if best is None:
            best, best_cost = aa_c, cost
        else:
            better = cost < best_cost
            best = torch.where(better[:, None, None], aa_c, best)
            best_cost = torch.minimum(cost, best_cost)
    return best


def _objective(
    body: torch.nn.Module,
    points: torch.Tensor,
    subset: torch.Tensor | None,
    aa: torch.Tensor,
    betas: torch.Tensor,
    transl: torch.Tensor,
    weights: dict[str, float],
    limit2: float,
) -> tuple[torch.Tensor, dict[str, float]]:
    """The weighted objective (module docstring) and its terms as floats (plus ``loss``)."""
    v = body(betas=betas, pose=aa, transl=transl).vertices
    p2m, m2p = chamfer_terms(points, v, subset)
    theta2 = aa[:, 1:].square().sum(-1)
    terms = {
        "p2m": p2m.mean(),
        "m2p": m2p.mean(),
        "pose": theta2.mean(),
        "limit": torch.relu(theta2 - limit2).mean(),
        "betas": betas.square().mean(),
    }
    total = (
        weights["p2m"] * terms["p2m"] + weights["m2p"] * terms["m2p"] + weights["pose"] * terms["pose"]
        + weights["limit"] * terms["limit"] + weights["betas"] * terms["betas"]
    )  # fmt: skip
    return total, {k: float(v.detach()) for k, v in terms.items()} | {"loss": float(total.detach())}


def _optimise(
    params: list[torch.Tensor],
    objective: Callable[[], tuple[torch.Tensor, dict[str, float]]],
    iters: int,
    lr: float,
    optimizer: str,
    tol: float,
    patience: int,
) -> list[dict[str, float]]:
    """Minimise ``objective`` over ``params`` (Adam with cosine-decayed lr, or L-BFGS); stop early
    when the loss improved by less than ``tol`` (relative) over ``patience`` iterations. Returns the
    terms per iteration."""
    history: list[dict[str, float]] = []
    if iters == 0:
        return history
    if optimizer == "adam":
        opt = torch.optim.Adam(params, lr=lr)
        sched = torch.optim.lr_scheduler.LambdaLR(
            opt, lambda s: 0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * min(1.0, s / max(1, iters))))
        )
    else:
        opt = torch.optim.LBFGS(params, lr=lr, max_iter=20, line_search_fn="strong_wolfe")

    def closure():
        opt.zero_grad(set_to_none=True)
        loss, _ = objective()
        loss.backward()
        return loss

    for it in range(iters):
        if optimizer == "adam":
            opt.zero_grad(set_to_none=True)
            loss, info = objective()
            loss.backward()
            opt.step()
            sched.step()
        else:
            opt.step(closure)
            with torch.no_grad():
                _, info = objective()
        history.append({"iter": it} | info)
        if not math.isfinite(info["loss"]):
            raise FloatingPointError(f"fit_body: objective became {info['loss']} at iteration {it}")
        if len(history) > patience:
            old = history[-1 - patience]["loss"]
            if old - info["loss"] < tol * max(abs(old), 1e-12):
                break
    return history
