"""Anny's own parameters and body measurements of a fit (needs the optional ``anny`` package).

For a fit of a body in Anny's topology (``anny22``, ``anny_allages``: Anny's mesh, rig folded to 22
parts), :class:`AnnyExport` gives:

* **phenotype**: Anny's ``gender``, ``age``, ``muscle``, ``weight``, ``height``, ``proportions`` (each in
  [0, 1], Anny's parameters) and the age in years (Anny's morphological age mapping). Found by fitting
  Anny's rest shape to the fitted shape: the fitted betas give the body's rest (T-pose) mesh; the ~64 %
  of Anny's vertices that the T-pose bake does not move are, in Anny's own rest pose, a linear function
  of Anny's blendshape coefficients, which are a piecewise multilinear function of the phenotype.
  Levenberg-Marquardt from 16 stratified starts (the landscape has local minima at the interpolation
  anchors), 10 iterations each, on 1000 evenly spread such vertices, translation eliminated by centring.
* **pose on Anny's rig**, two ways:

  - ``anny_bone_poses`` ``[n_bones, 4, 4]``: Anny's *world* bone poses in the scan's frame (metres), each
    bone moved rigidly with its anny22 part as the fitted body moves it, so that the stock model
    rebuilds the fitted mesh (no convention to match)::

        import anny, numpy as np, torch
        z = np.load("fit.npz")
        model = anny.Anny().to(torch.float64)
        phen = {k: torch.tensor([v]) for k, v in zip(z["anny_phenotype_labels"], z["anny_phenotype"])}
        out = model(pose_parameters=torch.as_tensor(z["anny_bone_poses"])[None], phenotype_kwargs=phen,
                    pose_parameterization="world")
        vertices = out["vertices"][0].numpy() / z["scale_to_m"]   # ~ the fitted mesh, the scan's units

    Its distance to the fitted mesh (``anny_rebuild_mm``: mean and max over vertices, per fit) is the
    phenotype misfit plus the shoulder blend region, where LBS on the baked T-pose is not Anny's skinning.
    The bones rotate about the fitted body's joint centres (its regressor, within ~5 mm of Anny's bone
    heads), so they are not exactly chained.
  - ``anny_pose_local_ref`` ``[n_bones, 4, 4]``: the kinematic pose, Anny's default ``local-ref``
    parameters of the stock model (``model(pose_parameters=..., phenotype_kwargs=phen)``): rotations only,
    every bone takes the world rotation of its anny22 part (T-pose bake included,
    :func:`arteq.body.anny_rig.anny_deltas_from_pose`) about Anny's own joint centres; for animating the
    Anny body. Its rebuild error (``anny_kinematic_rebuild_mm``) adds the joint-centre differences.
* **measurements** (``anny.anthropometry.Anthropometry``) of the fitted phenotype in Anny's rest pose:
  stature (m), waist circumference (m), volume (m^3), mass (kg, 980 kg/m^3) and BMI.

Accuracy against ground truth on held-out Anny bodies of every age: experiments/fitting/README.md.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import torch

from arteq.body import anny_rig

#: The phenotype labels of Anny's default model, in the order of ``anny_phenotype``.
PHENOTYPE_LABELS = ("gender", "age", "muscle", "weight", "height", "proportions")
MEASUREMENTS = ("stature_m", "waist_circumference_m", "volume_m3", "mass_kg", "bmi")


class AnnyUnavailable(RuntimeError):
    """The ``anny`` package is needed (and absent) or the body is not in Anny's topology."""


def anny_available() -> bool:
    try:
        import anny  # noqa: F401
    except ImportError:
        return False
    return True


def require_anny(what: str = "Anny parameters and body measurements") -> None:
    """Raise :class:`AnnyUnavailable` with the install line when ``anny`` cannot be imported."""
    if not anny_available():
        raise AnnyUnavailable(
            f"{what} need the optional `anny` package, which is not installed: "
            "`pip install anny==0.6.2` (or `pip install arteq[anny]`); or run without them (--no-anny)"
        )


class AnnyExport:
    """Anny phenotype, pose and measurements for fits of ``body`` (an Anny-topology body).

    Raises :class:`AnnyUnavailable` without ``anny`` or for a body that is not Anny's mesh (SMPL...).
    """

    def __init__(self, body: torch.nn.Module, starts: int = 16, iters: int = 10, vertices: int = 1000):
        require_anny()
        import anny
        from anny.shape_distribution import SimpleShapeDistribution
        from anny.skinning.skinning import dense_bone_weights

        model = anny_rig.load_anny()
        faces = model.faces.cpu().long()
        if body.num_vertices != model.template_vertices.shape[0] or not torch.equal(body.faces.cpu(), faces):
            raise AnnyUnavailable(
                f"Anny parameters need a body in Anny's topology (anny22, anny_allages); "
                f"'{getattr(body, 'name', 'body')}' has {body.num_vertices} vertices"
            )
        if tuple(model.phenotype_labels) != PHENOTYPE_LABELS:
            raise AnnyUnavailable(f"unexpected anny phenotype labels {model.phenotype_labels}")
        self.body = body
        self.model = model
        # the stock model (Anny's own reference bone orientations) for its default local-ref parameters
        self.stock = anny.Anny().to(dtype=torch.float64)
        self.bake = anny_rig.compute_bake(model)
        self.C = torch.as_tensor(anny_rig.ANNY_TO_SMPL, dtype=torch.float64)
        self.anthropometry = anny.Anthropometry(model)
        self.age_mapping = SimpleShapeDistribution(model).morphological_age_mapping
        self.bone_labels = list(model.bone_labels)
        # vertices the T-pose bake leaves where Anny's rest pose has them
        n_bones = len(self.bone_labels)
        dense = dense_bone_weights(model.vertex_bone_weights, model.vertex_bone_indices, n_bones)
        glob = anny_rig.baked_globals(model, self.bake)
        moved = (glob - torch.eye(3, dtype=glob.dtype)).abs().amax((1, 2)) > 1e-9
        static = torch.nonzero(dense[:, moved].sum(1) < 1e-9)[:, 0]
        self.subset = static[torch.linspace(0, len(static) - 1, min(vertices, len(static))).long()]
        self._blend = model.blendshapes[:, self.subset].reshape(model.blendshapes.shape[0], -1).double()
        self._template = model.template_vertices[self.subset].reshape(-1).double()
        g = torch.Generator().manual_seed(0)
        strata = torch.stack([torch.randperm(starts, generator=g) for _ in PHENOTYPE_LABELS], 1).double()
        jitter = torch.rand(starts, len(PHENOTYPE_LABELS), generator=g, dtype=torch.float64)
        self._starts = (strata + jitter) / starts  # stratified (Latin hypercube) starts in [0, 1]^6
        self.iters = iters

    # ------------------------------------------------------------------ phenotype
    def _coeffs(self, phen: torch.Tensor) -> torch.Tensor:
        z = phen.new_zeros(len(phen), 0)
        return self.model._get_phenotype_blendshape_coefficients(phen, z, z)

    def _subset_rest(self, phen: torch.Tensor) -> torch.Tensor:
        v = (self._template + self._coeffs(phen) @ self._blend).reshape(len(phen), -1, 3)
        return (v - v.mean(1, keepdim=True)).reshape(len(phen), -1)

    @torch.no_grad()
    def phenotype(self, rest_smpl: torch.Tensor) -> tuple[torch.Tensor, float]:
        """Phenotype ``[6]`` whose Anny rest shape matches ``rest_smpl [V, 3]`` (the body's T-pose mesh, SMPL
        axes, metres) on the vertices the bake does not move; and the RMS residual there (mm)."""
        target = rest_smpl.double()[self.subset] @ self.C  # SMPL -> Anny axes (row vectors)
        target = (target - target.mean(0)).reshape(-1)
        x = self._starts.clone()
        k = x.shape[1]
        lam = torch.full((len(x),), 1e-3, dtype=torch.float64)
        r = self._subset_rest(x) - target
        e = (r**2).sum(1)
        eps = 1e-5
        idx = torch.arange(k)
        for _ in range(self.iters):
            d = torch.where(x <= 1 - eps, eps, -eps)
            X = x[:, None].repeat(1, k, 1)
            X[:, idx, idx] += d
            moved = self._subset_rest(X.reshape(-1, k)).reshape(len(x), k, -1)
            J = (moved - (r + target)[:, None]) / d[..., None]
            H = J @ J.transpose(1, 2)
            g = (J @ r[..., None])[..., 0]
            damped = H + lam[:, None, None] * torch.diag_embed(torch.diagonal(H, dim1=1, dim2=2))
            damped = damped + 1e-12 * torch.eye(k, dtype=H.dtype)
            xn = (x - torch.linalg.solve(damped, g)).clamp(0.0, 1.0)
            rn = self._subset_rest(xn) - target
            en = (rn**2).sum(1)
            better = en < e
            x = torch.where(better[:, None], xn, x)
            r = torch.where(better[:, None], rn, r)
            e = torch.where(better, en, e)
            lam = torch.where(better, lam * 0.3, lam * 10.0)
        best = int(e.argmin())
        return x[best], float((e[best] / len(self.subset)).sqrt() * 1000.0)

    @torch.no_grad()
    def measurements(self, phen: torch.Tensor) -> dict[str, float]:
        """Anthropometry of Anny's rest pose (its A-pose) for phenotype ``[6]``."""
        rest = self.model.get_rest_vertices(self._coeffs(phen.double()[None]))
        m = self.anthropometry(rest)
        return {
            "stature_m": float(m["height"][0]),
            "waist_circumference_m": float(m["waist_circumference"][0]),
            "volume_m3": float(m["volume"][0]),
            "mass_kg": float(m["mass"][0]),
            "bmi": float(m["bmi"][0]),
        }

    def age_years(self, phen: torch.Tensor) -> float:
        age = phen.double()[PHENOTYPE_LABELS.index("age")].reshape(1)
        return float(self.age_mapping.anny_to_morphological_age(age)[0])

    # ------------------------------------------------------------------ one fit
    @torch.no_grad()
    def _finger_turns(self, rest: torch.Tensor, hand_curl: np.ndarray | None):
        """For a curl ``[2]`` (None or zero: nothing): Anny's 30 finger bone indices, their rest-frame
        transforms ``[30, 4, 4]`` in the body's T-pose (:meth:`arteq.body.hands.HandCurl.transforms`) and
        each bone's own turn ``[30, 3, 3]`` in Anny's rest axes (the bake undone)."""
        if hand_curl is None or not np.any(np.asarray(hand_curl) > 0):
            return None
        import roma

        from arteq.body.hands import FINGER_BONES, SIDES, hands_for

        if not hasattr(self, "_hands"):
            self._hands = hands_for(self.body)
        if self._hands is None:
            return None
        hc = self._hands.double().cpu()
        c = torch.as_tensor(np.asarray(hand_curl), dtype=torch.float64)[None]
        rot, trans = hc.transforms(hc.heads(rest[None].double()), c)
        T = torch.eye(4, dtype=torch.float64).repeat(30, 1, 1)
        T[:, :3, :3], T[:, :3, 3] = rot[0], trans[0]
        idx = {b: i for i, b in enumerate(self.bone_labels)}
        bones = [idx[f"{name}.{side}"] for side in SIDES for name in FINGER_BONES]
        glob = anny_rig.baked_globals(self.model, self.bake)[bones]  # [30, 3, 3]
        axes = hc.axes.repeat_interleave(3, dim=0)  # [30, 3] body rest axes
        axes_anny = (glob.transpose(-1, -2) @ self.C.T @ axes[..., None])[..., 0]
        own = roma.rotvec_to_rotmat(axes_anny * (c.repeat_interleave(15, dim=1)[0] * hc.max_rad)[:, None])
        return bones, T, own

    def export(
        self,
        betas: np.ndarray,
        pose_rotmats: np.ndarray,
        vertices_m: np.ndarray,
        hand_curl: np.ndarray | None = None,
    ) -> dict[str, Any]:
        """Everything for one fit: ``betas [nb]``, local ``pose_rotmats [22, 3, 3]``, the fitted mesh
        ``vertices_m [V, 3]`` in metres in the scan's frame and its fingers' curl ``hand_curl [2]``
        (:mod:`arteq.body.hands`; None: flat). Returns arrays and values for the npz / json."""
        t0 = time.perf_counter()
        body = self.body
        dev = body.v_template.device
        b = torch.as_tensor(np.asarray(betas), dtype=body.v_template.dtype, device=dev)[None]
        pose = torch.as_tensor(np.asarray(pose_rotmats), dtype=torch.float64)[None]
        fit = body(betas=b, pose=pose.to(b.dtype).to(dev))  # the fitted body, its own frame
        rest, _ = body.shape(b)
        rest = rest[0].detach().cpu().double()
        phen, rms = self.phenotype(rest)
        kwargs = {k: phen[i : i + 1] for i, k in enumerate(PHENOTYPE_LABELS)}
        target = torch.as_tensor(np.asarray(vertices_m), dtype=torch.float64)

        # Anny's T-posed phenotype, its bones' world poses carried into the body's rest frame (F), then
        # moved rigidly with their part as the fitted body's LBS moves it (A_p): the rebuild follows the
        # fitted mesh, with the fitted body's joint centres.
        tpose = self.model(
            pose_parameters=anny_rig._bake_pose(self.model, self.bake, 1), phenotype_kwargs=kwargs
        )
        F = torch.eye(4, dtype=torch.float64)
        F[:3, :3] = self.C
        F[:3, 3] = (rest - tpose["vertices"][0] @ self.C.T).mean(0)
        G = fit.global_rotmats[0].detach().cpu().double()
        A = torch.eye(4, dtype=torch.float64).repeat(len(G), 1, 1)
        A[:, :3, :3] = G
        A[:, :3, 3] = (
            fit.joints[0].detach().cpu().double() - (G @ fit.rest_joints[0].cpu().double()[..., None])[..., 0]
        )
        parts = anny_rig.fold_table(self.model.bone_labels, self.model.bone_parents)
        curl = self._finger_turns(rest, hand_curl)  # (bone indices, rest-frame transforms [30, 4, 4], ...)
        world = A[parts]
        if curl is not None:  # the finger bones curled in the body's rest frame, then moved with their part
            world = world.clone()
            world[curl[0]] = world[curl[0]] @ curl[1]
        world = world @ F @ tpose["bone_poses"][0]
        rebuilt = self.stock(
            pose_parameters=world[None], phenotype_kwargs=kwargs, pose_parameterization="world"
        )
        shift = (target - rebuilt["vertices"][0]).mean(0)
        world[:, :3, 3] += shift
        err = (rebuilt["vertices"][0] + shift - target).norm(dim=-1) * 1000.0

        # The kinematic pose on Anny's rig: rotations only (every bone takes its part's world rotation),
        # Anny's own joint centres; in the stock model's local-ref parameters.
        deltas = anny_rig.anny_deltas_from_pose(self.model, self.bake, pose)
        if curl is not None:  # each finger bone's own turn, in Anny's rest axes (its local-ref delta)
            deltas[0, curl[0], :3, :3] = deltas[0, curl[0], :3, :3] @ curl[2]
        out = self.model(pose_parameters=deltas, phenotype_kwargs=kwargs)
        kin = out["vertices"][0] @ self.C.T
        kshift = (target - kin).mean(0)
        kerr = (kin + kshift - target).norm(dim=-1) * 1000.0
        to_scan = torch.eye(4, dtype=torch.float64)
        to_scan[:3, :3] = self.C
        to_scan[:3, 3] = kshift
        placed = self.stock(pose_parameters=(to_scan @ out["bone_poses"][0])[None], phenotype_kwargs=kwargs,
                            pose_parameterization="world")  # fmt: skip
        local = self.stock.get_pose_parameterization(placed, "local-ref")[0]
        return {
            "phenotype": {k: float(phen[i]) for i, k in enumerate(PHENOTYPE_LABELS)},
            "age_years": self.age_years(phen),
            "measurements": self.measurements(phen),
            "phenotype_fit_rms_mm": rms,
            "rebuild_mm": {"mean": float(err.mean()), "max": float(err.max())},
            "kinematic_rebuild_mm": {"mean": float(kerr.mean()), "max": float(kerr.max())},
            "bone_labels": self.bone_labels,
            "bone_poses_world": world.numpy(),
            "pose_local_ref": local.numpy(),
            "seconds": time.perf_counter() - t0,
        }


def npz_arrays(anny: dict[str, Any] | None) -> dict[str, Any]:
    """The ``anny_*`` / ``measure_*`` keys of a fit's npz (empty without an Anny export)."""
    if anny is None:
        return {}
    m = anny["measurements"]
    return {
        "anny_phenotype": np.array([anny["phenotype"][k] for k in PHENOTYPE_LABELS], dtype=np.float64),
        "anny_phenotype_labels": np.array(PHENOTYPE_LABELS),
        "anny_age_years": np.float64(anny["age_years"]),
        "anny_bone_labels": np.array(anny["bone_labels"]),
        "anny_bone_poses": anny["bone_poses_world"].astype(np.float64),
        "anny_pose_local_ref": anny["pose_local_ref"].astype(np.float64),
        "anny_rebuild_mm": np.array([anny["rebuild_mm"]["mean"], anny["rebuild_mm"]["max"]]),
        "anny_kinematic_rebuild_mm": np.array(
            [anny["kinematic_rebuild_mm"]["mean"], anny["kinematic_rebuild_mm"]["max"]]
        ),
        "anny_phenotype_fit_rms_mm": np.float64(anny["phenotype_fit_rms_mm"]),
        **{f"measure_{k}": np.float64(m[k]) for k in MEASUREMENTS},
    }


def json_section(anny: dict[str, Any] | None, reason: str = "") -> dict[str, Any]:
    """The human-readable ``anny`` part of ``<name>.json``."""
    if anny is None:
        return {"computed": False, "reason": reason}
    m = anny["measurements"]
    return {
        "computed": True,
        "phenotype": {k: round(v, 4) for k, v in anny["phenotype"].items()},
        "age_years": round(anny["age_years"], 1),
        "measurements": {
            "stature_cm": round(m["stature_m"] * 100, 1),
            "waist_circumference_cm": round(m["waist_circumference_m"] * 100, 1),
            "volume_litres": round(m["volume_m3"] * 1000, 1),
            "mass_kg": round(m["mass_kg"], 1),
            "bmi": round(m["bmi"], 1),
        },
        "rebuild_error_mm": {k: round(v, 2) for k, v in anny["rebuild_mm"].items()},
        "kinematic_pose_rebuild_error_mm": {k: round(v, 2) for k, v in anny["kinematic_rebuild_mm"].items()},
        "pose": "anny_bone_poses in <name>.npz: Anny's world bone poses (scan frame, metres); "
        "anny.Anny()(pose_parameters=..., phenotype_kwargs=..., pose_parameterization='world') rebuilds "
        "the mesh (docs/fitting.md)",
        "seconds": round(anny["seconds"], 3),
    }
