"""The Anny rig machinery shared by every body built from the ``anny`` package (Apache-2.0, CC0 assets).

A body built here is an SMPL-format ``.npz`` (read by :class:`arteq.body.BodyModel`) defined by an
:class:`AnnyBodySpec`: which Anny shapes its PCA shape space is built from, how many samples, seed and
components. ``anny22`` (:mod:`arteq.body.anny22`, adults 18-70, the research model's body) and
``anny_allages`` (:mod:`arteq.body.anny_allages`, ages 2-90 and extreme builds) are the two specs;
everything else is common. ``anny`` is imported only inside the build functions: everything else runs
from the cached file on machines without ``anny``. Nothing is downloaded.

What is built (see docs/body.md):

* Skeleton: SMPL's 22 body joints, order and parents as :mod:`arteq.body.skeleton`. Each joint is an Anny
  bone head (:data:`JOINT_TO_ANNY`), except ``left_foot`` / ``right_foot``: SMPL's foot joint sits at the
  ball of the foot, taken as the mean head of Anny's five first toe bones. Every other Anny bone is folded
  into the part of its nearest articulated ancestor (:func:`fold_table`), toes into the feet.
* Rest pose: a T-pose. Anny's reference pose (its A-pose) is posed with the upper arms and forearms rotated
  to horizontal (minimal rotations, computed once on the default phenotype) and that is baked in.
* Axes: Anny is z-up facing -y; SMPL is y-up facing +z, +x the body's left in both:
  ``p_smpl = C p_anny`` with ``C = [[1,0,0],[0,0,1],[0,-1,0]]`` (a rotation, -90 deg about x).
* Origin: the pelvis (Anny's root bone head) of every shape sample is at the origin.
* Shape space: PCA over the spec's shape samples (:meth:`AnnyBodySpec.sampler`); ``num_stored_betas``
  components stored with unit variance (``shapedirs[..., k] = sqrt(lambda_k) * u_k``), so ``beta ~ N(0, I)``
  reproduces the sampled distribution's covariance within the kept subspace.
* Joint regressor: per joint, convex weights (non-negative, sum to one, hence translation-equivariant) over
  the 600 nearest vertices of its part and its parent's part, fitted by NNLS to Anny's own joint positions
  across the shape samples; the held-out error is stored in the provenance.
* posedirs: none (Anny has no pose correctives); stored as an empty ``[V, 3, 0]`` array.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS, local_to_global
from arteq.paths import cache_dir

#: SMPL joint -> Anny bone whose head is the joint ("" = virtual joint, see TOE_BASES).
JOINT_TO_ANNY: dict[str, str] = {
    "pelvis": "root",
    "left_hip": "upperleg01.L",
    "right_hip": "upperleg01.R",
    "spine1": "spine03",
    "left_knee": "lowerleg01.L",
    "right_knee": "lowerleg01.R",
    "spine2": "spine02",
    "left_ankle": "foot.L",
    "right_ankle": "foot.R",
    "spine3": "spine01",
    "left_foot": "",
    "right_foot": "",
    "neck": "neck01",
    "left_collar": "clavicle.L",
    "right_collar": "clavicle.R",
    "head": "head",
    "left_shoulder": "upperarm01.L",
    "right_shoulder": "upperarm01.R",
    "left_elbow": "lowerarm01.L",
    "right_elbow": "lowerarm01.R",
    "left_wrist": "wrist.L",
    "right_wrist": "wrist.R",
}
#: The virtual foot joints: mean head of these toe bones (the ball of the foot).
TOE_BASES: dict[str, tuple[str, ...]] = {
    side: tuple(f"toe{i}-1.{s}" for i in range(1, 6)) for side, s in (("left_foot", "L"), ("right_foot", "R"))
}
#: Anny bones rotated to bring the arms from Anny's A-pose to a T-pose: (bone, child bone, target dir).
TPOSE_BAKE: tuple[tuple[str, str, tuple[float, float, float]], ...] = (
    ("upperarm01.L", "lowerarm01.L", (1.0, 0.0, 0.0)),
    ("lowerarm01.L", "wrist.L", (1.0, 0.0, 0.0)),
    ("upperarm01.R", "lowerarm01.R", (-1.0, 0.0, 0.0)),
    ("lowerarm01.R", "wrist.R", (-1.0, 0.0, 0.0)),
)
#: Anny (z up, -y front) -> SMPL (y up, +z front) axes: p_smpl = C @ p_anny.
ANNY_TO_SMPL = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
NUM_STORED_BETAS = 16


def fold_table(bone_labels: list[str], bone_parents: list[int]) -> list[int]:
    """Part index (0..21) of every Anny bone: its own joint if articulated, toes -> foot, else the part of
    its nearest articulated ancestor."""
    bone_to_joint = {b: JOINT_NAMES.index(j) for j, b in JOINT_TO_ANNY.items() if b}
    toe_to_joint = {b: JOINT_NAMES.index(j) for j, bones in TOE_BASES.items() for b in bones}
    parts = []
    for i, label in enumerate(bone_labels):
        a = i
        while True:
            lab = bone_labels[a]
            if lab in bone_to_joint:
                parts.append(bone_to_joint[lab])
                break
            if lab in toe_to_joint:
                parts.append(toe_to_joint[lab])
                break
            a = bone_parents[a]
            if a < 0:
                raise RuntimeError(f"anny bone {label!r} has no articulated ancestor")
    return parts


def _align(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Minimal rotation ``[3,3]`` taking direction ``a`` to direction ``b``."""
    from arteq.geometry.rotations import rotation_between

    return rotation_between(a, b)


def load_anny():
    """Instantiate the full-body Anny model (float64, CPU, local-ref pose parameterisation).

    Anny's optional per-bone *reference* orientations are dropped, so that identity deltas give Anny's rest
    mesh itself (its A-pose) and every bone's skinning transform is the identity there: posing the baked
    T-pose then composes exactly with Anny's own skinning except where the bake itself blends (shoulders).
    """
    import anny

    model = anny.Anny(pose_parameterization="local-ref").to(dtype=torch.float64)
    model.reference_bone_orientations = None
    return model


def _bone_index(model) -> dict[str, int]:
    return {b: i for i, b in enumerate(model.bone_labels)}


def compute_bake(model) -> dict[str, torch.Tensor]:
    """Local-ref deltas ``{bone: [3,3]}`` that pose Anny's default phenotype from its A-pose to a T-pose.

    Each listed bone is rotated (minimally) so that the segment to its child points along the target
    direction; deltas are world-axis rotations composed along the chain (``G_c = G_p D_c``).
    """
    idx = _bone_index(model)
    bake: dict[str, torch.Tensor] = {}
    glob: dict[str, torch.Tensor] = {}
    eye = torch.eye(3, dtype=torch.float64)
    for bone, child, target in TPOSE_BAKE:
        out = model(pose_parameters=_bake_pose(model, bake, 1))
        heads = out["bone_poses"][0, :, :3, 3]
        seg = heads[idx[child]] - heads[idx[bone]]
        g_new = _align(seg, torch.tensor(target, dtype=torch.float64))
        # Parent's global (relative to reference) rotation = product of the deltas already baked on the chain.
        g_parent = eye
        a = model.bone_parents[idx[bone]]
        while a >= 0:
            if model.bone_labels[a] in glob:
                g_parent = glob[model.bone_labels[a]]
                break
            a = model.bone_parents[a]
        g_bone = g_new @ g_parent
        glob[bone] = g_bone
        bake[bone] = g_parent.T @ g_bone
    return bake


def _bake_pose(model, bake: dict[str, torch.Tensor], batch: int) -> dict[str, torch.Tensor]:
    pose = {}
    for bone, rot in bake.items():
        h = torch.eye(4, dtype=torch.float64)
        h[:3, :3] = rot
        pose[bone] = h.expand(batch, 4, 4).clone()
    if not pose:
        pose["root"] = torch.eye(4, dtype=torch.float64).expand(batch, 4, 4).clone()
    return pose


def baked_globals(model, bake: dict[str, torch.Tensor]) -> torch.Tensor:
    """Global rotation ``[n_bones,3,3]`` of every bone in the baked T-pose, relative to Anny's reference."""
    eye = torch.eye(3, dtype=torch.float64)
    out: list[torch.Tensor] = []
    for i, label in enumerate(model.bone_labels):
        p = model.bone_parents[i]
        g_p = out[p] if p >= 0 else eye
        out.append(g_p @ bake.get(label, eye))
    return torch.stack(out)


def anny_tpose(model, phenotypes: dict[str, torch.Tensor], bake: dict[str, torch.Tensor]):
    """Anny's T-posed mesh and 22 joints in SMPL axes, pelvis at the origin.

    Args:
        phenotypes: dict of ``[B]`` tensors (Anny phenotype values).
    Returns:
        vertices ``[B,V,3]``, joints ``[B,22,3]`` (float64, SMPL axes, metres).
    """
    batch = next(iter(phenotypes.values())).shape[0]
    out = model(pose_parameters=_bake_pose(model, bake, batch), phenotype_kwargs=phenotypes)
    return _to_smpl(model, out["vertices"], out["bone_poses"][..., :3, 3])


def _to_smpl(model, verts: torch.Tensor, heads: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    idx = _bone_index(model)
    joints = []
    for name in JOINT_NAMES:
        if JOINT_TO_ANNY[name]:
            joints.append(heads[:, idx[JOINT_TO_ANNY[name]]])
        else:
            joints.append(heads[:, [idx[b] for b in TOE_BASES[name]]].mean(dim=1))
    joints = torch.stack(joints, dim=1)
    C = torch.as_tensor(ANNY_TO_SMPL, dtype=verts.dtype)
    return verts @ C.T, joints @ C.T


def anny_deltas_from_pose(model, bake: dict[str, torch.Tensor], pose: torch.Tensor) -> torch.Tensor:
    """Anny local-ref deltas ``[B, n_bones, 4, 4]`` that realise an anny22/SMPL pose.

    Every Anny bone gets the global rotation of its anny22 part (folded bones follow their part). Exact for
    all joints except the virtual foot joints, where Anny's toes pivot about their own heads instead of the
    mean toe base (an exact match therefore needs ``pose[:, 10]`` and ``pose[:, 11]`` at identity).

    Args:
        pose: ``[B, 22, 3, 3]`` local rotation matrices in SMPL axes (float64).
    """
    C = torch.as_tensor(ANNY_TO_SMPL, dtype=pose.dtype)
    g_parts = C.T @ local_to_global(pose) @ C  # [B,22,3,3] in Anny axes
    parts = fold_table(model.bone_labels, model.bone_parents)
    g_hat = g_parts[:, parts] @ baked_globals(model, bake).to(pose.dtype)  # [B,n,3,3]
    parent = [p if p >= 0 else 0 for p in model.bone_parents]
    local = g_hat[:, parent].transpose(-1, -2) @ g_hat
    local[:, 0] = g_hat[:, 0]
    deltas = torch.eye(4, dtype=pose.dtype).repeat(pose.shape[0], len(parts), 1, 1)
    deltas[..., :3, :3] = local
    return deltas


def _fit_regressor(
    verts: np.ndarray,
    joints: np.ndarray,
    weights22: np.ndarray,
    max_cand: int = 600,
    ridge_sum: float = 100.0,
) -> np.ndarray:
    """Convex per-joint vertex weights ``[22, V]`` by NNLS (sum-to-one enforced by a heavy extra row).

    Candidates: the vertices skinned to the joint's part or its parent's (weight > 0.05), the
    ``max_cand`` nearest to the joint's mean position, so that they surround it.
    """
    from scipy.optimize import nnls

    N, V, _ = verts.shape
    mean_v, mean_j = verts.mean(0), joints.mean(0)
    reg = np.zeros((NUM_JOINTS, V))
    for j in range(NUM_JOINTS):
        near_parts = [j] + ([PARENTS[j]] if PARENTS[j] >= 0 else [])
        mask = weights22[:, near_parts].sum(1) > 0.05
        cand = np.nonzero(mask)[0]
        d = np.linalg.norm(mean_v[cand] - mean_j[j], axis=1)
        cand = cand[np.argsort(d)[:max_cand]]
        A = verts[:, cand, :].transpose(0, 2, 1).reshape(N * 3, len(cand))
        b = joints[:, j, :].reshape(N * 3)
        A = np.vstack([A, ridge_sum * np.ones((1, len(cand)))])
        b = np.concatenate([b, [ridge_sum]])
        w, _ = nnls(A, b, maxiter=50 * len(cand))
        reg[j, cand] = w / w.sum()
    return reg


#: A shape sampler: ``sample(n) -> (morphological age in years [n], phenotypes {label: [n]}, tags
#: {name: bool [n]})``, made once per build by :attr:`AnnyBodySpec.make_sampler` from the Anny model.
Sampler = Callable[[int], tuple[torch.Tensor, dict[str, torch.Tensor], dict[str, torch.Tensor]]]


@dataclass(frozen=True)
class AnnyBodySpec:
    """What defines one Anny-built body: its name and the shapes its PCA shape space is built from.

    ``make_sampler(model)`` returns the :data:`Sampler`; it is called once, right after
    ``torch.manual_seed(seed)``, and then asked for chunks of 64 shapes (so a build is deterministic).
    ``meta`` is provenance written into the file after ``num_samples`` (in this order).
    """

    name: str
    make_sampler: Callable[[Any], Sampler]
    num_samples: int
    seed: int = 0
    num_stored_betas: int = NUM_STORED_BETAS
    default_num_betas: int = 10
    meta: dict[str, Any] = field(default_factory=dict)
    build_time: str = "about a minute"

    def default_path(self) -> Path:
        """Where the cached file lives: ``cache_dir("body_models") / "<name>.npz"``."""
        return cache_dir("body_models") / f"{self.name}.npz"


def phenotype_sampler(model, age_range: tuple[float, float]):
    """Anny's own age-aware sampler (``SimpleShapeDistribution``: height, weight, muscle and proportions
    drawn from its per-age, per-gender distributions) with morphological age uniform in ``age_range`` years
    and gender uniform in [0, 1]."""
    from anny.shape_distribution import SimpleShapeDistribution

    age = torch.distributions.Uniform(
        torch.tensor(age_range[0], dtype=torch.float64), torch.tensor(age_range[1], dtype=torch.float64)
    )
    return SimpleShapeDistribution(model, morphological_age_distribution=age)


def sample_shapes(
    spec: AnnyBodySpec,
    model,
    bake: dict[str, torch.Tensor],
    num_samples: int | None = None,
    seed: int | None = None,
    log: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """The spec's shape samples, T-posed in SMPL axes with the pelvis at the origin.

    Returns ``vertices [N,V,3]``, ``joints [N,22,3]`` (float64 numpy), ``ages [N]`` (years),
    ``phenotypes {label: [N]}`` and ``tags {name: bool [N]}`` (numpy). ``num_samples`` / ``seed`` default
    to the spec's (other values: held-out sets drawn from the same distribution).
    """
    n_all = spec.num_samples if num_samples is None else num_samples
    torch.manual_seed(spec.seed if seed is None else seed)
    sample = spec.make_sampler(model)
    verts, joints, ages, phens, tags = [], [], [], [], []
    chunk = 64
    with torch.no_grad():
        for start in range(0, n_all, chunk):
            n = min(chunk, n_all - start)
            age, phen, tag = sample(n)
            v, j = anny_tpose(model, phen, bake)
            verts.append(v)
            joints.append(j)
            ages.append(age)
            phens.append(phen)
            tags.append(tag)
            if log is not None:
                log(f"sampled shapes {start + n}/{n_all}")
    V = torch.cat(verts).numpy()
    J = torch.cat(joints).numpy()
    # Pelvis at the origin for every shape.
    V = V - J[:, :1]
    J = J - J[:, :1]
    return {
        "vertices": V,
        "joints": J,
        "ages": torch.cat(ages).numpy(),
        "phenotypes": {k: torch.cat([p[k] for p in phens]).numpy() for k in phens[0]},
        "tags": {k: torch.cat([t[k] for t in tags]).numpy() for k in tags[0]},
    }


def pca_shape_space(V: np.ndarray, num_components: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA of shapes ``V [N, nv, 3]``: ``mean [nv*3]``, unit-variance ``shapedirs [nv, 3, k]``
    (``sqrt(lambda_k) u_k``) and the cumulative explained variance of every component ``[N]``."""
    num_samples, nv = V.shape[0], V.shape[1]
    X = V.reshape(num_samples, -1)
    mean = X.mean(0)
    Xc = X - mean
    # Eigen-decomposition of the small [N, N] Gram matrix (N << 3V): same components as the SVD, faster.
    evals, evecs = np.linalg.eigh(Xc @ Xc.T)
    order = np.argsort(evals)[::-1]
    evals, evecs = np.clip(evals[order], 0.0, None), evecs[:, order]
    var = evals / (num_samples - 1)
    explained = np.cumsum(var) / var.sum()
    k = num_components
    comps = (Xc.T @ evecs[:, :k]) / np.sqrt(evals[:k])  # unit columns [3V, k]
    shapedirs = (comps * np.sqrt(var[:k])).reshape(nv, 3, -1)
    return mean, shapedirs, explained


def folded_weights(model) -> tuple[np.ndarray, np.ndarray]:
    """Anny's skinning weights summed into the 22 parts ``[V, 22]`` and the part of every bone."""
    from anny.skinning.skinning import dense_bone_weights

    dense = dense_bone_weights(model.vertex_bone_weights, model.vertex_bone_indices, len(model.bone_labels))
    parts = np.asarray(fold_table(model.bone_labels, model.bone_parents))
    w22 = np.zeros((dense.shape[0], NUM_JOINTS))
    np.add.at(w22.T, parts, dense.numpy().T)
    w22 /= w22.sum(1, keepdims=True)
    return w22, parts


def build_anny_body(spec: AnnyBodySpec, out: str | Path | None = None, verbose: bool = True) -> Path:
    """Build the body file of ``spec`` (atomically) and return its path. About a minute warm."""
    import anny

    out = Path(out) if out is not None else spec.default_path()
    t0 = time.time()

    def log(msg: str) -> None:
        if verbose:
            print(f"[{spec.name} {time.time() - t0:6.1f}s] {msg}", file=sys.stderr, flush=True)

    log(f"building the {spec.name} body model from anny {anny.__version__} -> {out}")
    model = load_anny()
    log(f"anny loaded: {model.template_vertices.shape[0]} vertices, {len(model.bone_labels)} bones")
    bake = compute_bake(model)
    samples = sample_shapes(spec, model, bake, log=log)
    V, J = samples["vertices"], samples["joints"]
    num_samples = spec.num_samples

    w22, parts = folded_weights(model)

    log("PCA")
    nv = V.shape[1]
    mean, shapedirs, explained = pca_shape_space(V, spec.num_stored_betas)

    # Joint regressor: fit on 80 % of the samples, report the error on the rest, refit on all.
    log("fitting the joint regressor")
    n_fit = int(0.8 * num_samples)
    reg = _fit_regressor(V[:n_fit], J[:n_fit], w22)
    err = np.linalg.norm(np.einsum("kv,nvc->nkc", reg, V[n_fit:]) - J[n_fit:], axis=-1) * 1000.0
    reg = _fit_regressor(V, J, w22)

    faces = model.faces.cpu().numpy().astype(np.int64)
    kintree = np.stack([np.array([2**32 - 1] + list(PARENTS[1:]), dtype=np.int64), np.arange(NUM_JOINTS)])
    meta = {
        "name": spec.name,
        "anny_version": anny.__version__,
        "seed": spec.seed,
        "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "num_samples": num_samples,
        **spec.meta,
        "variance_explained_cumulative": [float(x) for x in explained[: spec.num_stored_betas]],
        "joint_regressor_heldout_error_mm": {
            "mean": float(err.mean()),
            "max": float(err.max()),
            "per_joint_mean": {n: float(e) for n, e in zip(JOINT_NAMES, err.mean(0))},
        },
        "axes": "SMPL: y up, +z front, +x body's left; p_smpl = C p_anny, C = [[1,0,0],[0,0,1],[0,-1,0]]",
        "origin": "pelvis (anny root bone head) at 0 for every shape sample",
        "rest_pose": "T-pose: anny reference pose with upper arms and forearms rotated to horizontal",
        "tpose_bake_bones": list(bake),
        "fold": {b: JOINT_NAMES[p] for b, p in zip(model.bone_labels, parts.tolist())},
        "posedirs": "none (anny has no pose correctives)",
        "units": "metres",
    }
    if spec.name != "anny22":  # anny22's file stays as it always was (its provenance keys included)
        meta["default_num_betas"] = spec.default_num_betas
        meta["sample_ages_years"] = {
            "min": float(samples["ages"].min()),
            "max": float(samples["ages"].max()),
        }
        heights = V[..., 1].max(1) - V[..., 1].min(1)
        meta["sample_heights_m"] = {"min": float(heights.min()), "max": float(heights.max())}
        meta["sample_tags"] = {k: int(v.sum()) for k, v in samples["tags"].items()}
    arrays = {
        "v_template": mean.reshape(nv, 3).astype(np.float32),
        "shapedirs": shapedirs.astype(np.float32),
        "posedirs": np.zeros((nv, 3, 0), dtype=np.float32),
        "J_regressor": reg.astype(np.float32),
        "weights": w22.astype(np.float32),
        "kintree_table": kintree,
        "f": faces,
        "tpose_bake_rotmats": torch.stack(list(bake.values())).numpy(),
        "meta_json": np.array(json.dumps(meta)),
    }
    if spec.name != "anny22":
        # The training shapes as betas (orthogonal columns: projection = least squares), with their ages and
        # tags: lets a data pipeline draw realistic shapes instead of beta ~ N(0, I) of a mixture.
        S = shapedirs.reshape(-1, shapedirs.shape[-1])
        arrays["sample_betas"] = ((V.reshape(num_samples, -1) - mean) @ S / (S**2).sum(0)).astype(np.float32)
        arrays["sample_ages_years"] = samples["ages"].astype(np.float32)
        for key, tag in samples["tags"].items():
            arrays[f"sample_{key}"] = tag.astype(bool)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.stem}.{os.getpid()}.tmp.npz")
    try:
        np.savez_compressed(tmp, **arrays)
        os.replace(tmp, out)
    finally:
        if tmp.exists():
            tmp.unlink()
    k = min(spec.default_num_betas, spec.num_stored_betas)
    log(
        f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB): variance explained by {k} betas "
        f"{explained[k - 1] * 100:.2f}%, joint regressor error mean {err.mean():.2f} mm / "
        f"max {err.max():.2f} mm"
    )
    return out


def read_meta(path: str | Path) -> dict:
    """Provenance dict stored in an anny22 file."""
    with np.load(path, allow_pickle=False) as z:
        return json.loads(str(z["meta_json"]))


def read_bake(path: str | Path) -> dict[str, torch.Tensor]:
    """The T-pose bake deltas ``{anny bone: [3,3]}`` stored in an anny22 file."""
    meta = read_meta(path)
    with np.load(path, allow_pickle=False) as z:
        rots = torch.as_tensor(z["tpose_bake_rotmats"], dtype=torch.float64)
    return dict(zip(meta["tpose_bake_bones"], rots))


def ensure_body(spec: AnnyBodySpec, path: str | Path | None = None, force: bool = False) -> Path:
    """Return the cached file of ``spec``, building it (needs ``anny``) if absent or ``force``."""
    path = Path(path) if path is not None else spec.default_path()
    if path.is_file() and not force:
        return path
    try:
        import anny  # noqa: F401
    except ImportError as exc:
        raise RuntimeError(
            f"the {spec.name} body model is not cached at '{path}' and the `anny` package needed to build it "
            f"is not installed: `pip install anny==0.6.2` (or copy {spec.name}.npz there from a machine that "
            "has it)"
        ) from exc
    msg = f"arteq: building the {spec.name} body model into {path} (once; {spec.build_time}) ..."
    print(msg, file=sys.stderr)
    return build_anny_body(spec, path)


def main(make_spec: Callable[..., AnnyBodySpec], argv: list[str] | None = None, doc: str = "") -> None:
    """``python -m arteq.body.<name> [--out PATH] [--force] [--samples N] [--seed S]``."""
    default = make_spec()
    parser = argparse.ArgumentParser(description=doc or f"Build the {default.name} body model file.")
    parser.add_argument("--out", type=Path, default=None, help="output .npz (default: the arteq cache)")
    parser.add_argument("--force", action="store_true", help="rebuild even if the file exists")
    parser.add_argument("--samples", type=int, default=default.num_samples, help="shape samples for the PCA")
    parser.add_argument("--seed", type=int, default=default.seed)
    args = parser.parse_args(argv)
    spec = make_spec(num_samples=args.samples, seed=args.seed)
    out = args.out or spec.default_path()
    if out.exists() and not args.force:
        print(f"{out} exists (use --force to rebuild)")
        return
    build_anny_body(spec, out)
