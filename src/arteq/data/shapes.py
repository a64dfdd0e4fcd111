"""Training body shapes from the all-ages body's stored shape samples (``data.shape_prior``).

``normal`` (the default) draws ``betas ~ N(0, beta_scale^2 I)`` over the body's shape space: for ``anny22``
the adult distribution it was built from. Over ``anny_allages`` the same Gaussian is one blob over
children to elderly: it blends ages (a child's proportions at an adult's stature and back) and keeps
neither the age structure nor the extreme builds of the samples the space was built from.

``allages`` draws from those samples themselves. ``anny_allages``' file stores the betas of the 2000 Anny
shapes its PCA was built from (``sample_betas``: anny's own age-aware sampler, ages 2-90 uniform, a quarter
extreme builds; ``sample_ages_years``). A draw takes one stored sample uniformly and adds a Gaussian
perturbation whose covariance is that of the stored samples of the same age band (:data:`AGE_BANDS_YEARS`,
per-age statistics) times ``jitter**2`` (:data:`JITTER`): a new body of that age and build, close to a real
Anny body. Statures span the samples' (about 0.85-2.0 m).

Used by :class:`arteq.data.dataset.BodyScanDataset` (argument ``shapes``) through
:class:`arteq.data.BodyScanDataModule` (``shape_prior``); draws are deterministic per sample stream.

What body a draw is: :meth:`StoredShapePrior.draw` also returns the stored sample it started from, and a
dataset with this prior adds it to every sample (:data:`SHAPE_META_KEYS`): ``shape_index`` (the stored
sample, -1 when the pose source brought its own betas), ``age_years`` (that sample's age; NaN for -1) and
``build_extreme`` (1: one of the extreme builds, 0: a typical build, -1: not known). The draws themselves
are the same as :meth:`~StoredShapePrior.sample`'s, draw for draw. :func:`rest_measurements` gives a body's
stature, volume, mass and BMI from its rest mesh (the test sets' breakdown per build,
:mod:`arteq.training.breakdown`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
import torch

#: ``data.shape_prior`` values.
SHAPE_PRIORS = ("normal", "allages")
#: Age band edges (years) of the per-age statistics: finer where bodies change fastest.
AGE_BANDS_YEARS = (0.0, 4.0, 6.0, 9.0, 12.0, 15.0, 18.0, 25.0, 35.0, 50.0, 70.0, 200.0)
#: Perturbation scale, in units of the band's standard deviations.
JITTER = 0.25
#: What a sample drawn with a :class:`StoredShapePrior` records about its body (module docstring).
SHAPE_META_KEYS = ("shape_index", "age_years", "build_extreme")
#: Version of those keys in the fixed sets' cache keys (only sets drawn with such a prior carry it).
SHAPE_META_VERSION = 1
#: Body density (kg/m^3) of :func:`rest_measurements`: anny's ``Anthropometry`` value.
BODY_DENSITY = 980.0


class StoredShapePrior:
    """Betas drawn from stored shape samples, perturbed with their age band's covariance (module docstring).

    Args:
        betas: ``[N, K]`` stored samples' betas (the body's shape space, unit-variance components).
        ages: ``[N]`` their ages in years.
        jitter: perturbation scale (0: the stored samples themselves).
        bands: age band edges in years (increasing); a band with fewer than 2 samples uses all samples.
        name: what the prior is called in fingerprints.
        extreme: ``[N]`` bool, whether each stored sample is one of the extreme builds (None: not known).
            Only recorded with the draws (:meth:`draw`); it does not change them.
    """

    def __init__(
        self,
        betas: np.ndarray | torch.Tensor,
        ages: np.ndarray | torch.Tensor,
        jitter: float = JITTER,
        bands: tuple[float, ...] = AGE_BANDS_YEARS,
        name: str = "allages",
        extreme: np.ndarray | torch.Tensor | None = None,
    ) -> None:
        b = torch.as_tensor(np.asarray(betas), dtype=torch.float64)
        a = torch.as_tensor(np.asarray(ages), dtype=torch.float64)
        if b.ndim != 2 or b.shape[0] < 2 or b.shape[1] < 1:
            raise ValueError(f"StoredShapePrior: betas must be [N >= 2, K >= 1], got {list(b.shape)}")
        if a.shape != (b.shape[0],):
            raise ValueError(f"StoredShapePrior: ages must be [{b.shape[0]}], got {list(a.shape)}")
        if not (torch.isfinite(b).all() and torch.isfinite(a).all()):
            raise ValueError("StoredShapePrior: betas and ages must be finite")
        if not (jitter >= 0 and np.isfinite(jitter)):
            raise ValueError(f"StoredShapePrior: jitter must be a finite number >= 0, got {jitter}")
        edges = torch.as_tensor(bands, dtype=torch.float64)
        if edges.ndim != 1 or len(edges) < 2 or not bool((edges[1:] > edges[:-1]).all()):
            raise ValueError(f"StoredShapePrior: bands must be increasing edges, got {bands}")
        self.betas, self.ages, self.jitter, self.name = b, a, float(jitter), name
        self.extreme: torch.Tensor | None = None
        if extreme is not None:
            e = torch.as_tensor(np.asarray(extreme))
            if e.shape != (b.shape[0],):
                raise ValueError(f"StoredShapePrior: extreme must be [{b.shape[0]}], got {list(e.shape)}")
            self.extreme = e.to(torch.bool)
        self.num_stored = b.shape[1]
        self.band = torch.bucketize(a, edges[1:-1], right=True)  # [N] band of each sample
        k = b.shape[1]
        ridge = 1e-9 * torch.eye(k, dtype=torch.float64)
        chol = []
        for i in range(len(edges) - 1):
            members = b[self.band == i]
            members = members if len(members) >= 2 else b
            chol.append(torch.linalg.cholesky(torch.cov(members.T).reshape(k, k) + ridge))
        self.chol = torch.stack(chol)  # [bands, K, K] lower-triangular
        h = hashlib.sha256(b.numpy().tobytes() + a.numpy().tobytes()).hexdigest()[:12]
        self._fingerprint = f"{name}(n={b.shape[0]}, k={k}, jitter={self.jitter:g}, bands={list(bands)}, {h})"

    def sample(self, num_betas: int, generator: torch.Generator) -> torch.Tensor:
        """One draw: betas ``[num_betas]`` float64 (the first ``num_betas`` of the stored components)."""
        return self.draw(num_betas, generator)[0]

    def draw(
        self, num_betas: int, generator: torch.Generator
    ) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """One draw and what body it is: ``(betas, meta)``, the betas of :meth:`sample` (the same random
        numbers) and ``meta`` (:data:`SHAPE_META_KEYS`, 0-d tensors) of the stored sample it started from."""
        if not 1 <= num_betas <= self.num_stored:
            raise ValueError(
                f"{self.name} shape prior: the body has {num_betas} betas, "
                f"the stored samples {self.num_stored}"
            )
        i = int(torch.randint(len(self.betas), (1,), generator=generator))
        z = torch.randn(num_betas, generator=generator, dtype=torch.float64)
        # the Cholesky factor of a covariance's top-left k x k submatrix is the top-left k x k of its factor
        chol = self.chol[self.band[i], :num_betas, :num_betas]
        return self.betas[i, :num_betas] + self.jitter * (chol @ z), self.meta(i)

    def meta(self, index: int) -> dict[str, torch.Tensor]:
        """What stored sample ``index`` is (:data:`SHAPE_META_KEYS`, 0-d tensors)."""
        extreme = -1 if self.extreme is None else int(self.extreme[index])
        return {
            "shape_index": torch.tensor(int(index), dtype=torch.long),
            "age_years": torch.tensor(float(self.ages[index]), dtype=torch.float32),
            "build_extreme": torch.tensor(extreme, dtype=torch.long),
        }

    def meta_spec(self) -> str:
        """What the recorded metadata depends on beyond :meth:`fingerprint` (the fixed sets' cache keys of
        this prior's sets name it: they store the metadata)."""
        if self.extreme is None:
            return f"v{SHAPE_META_VERSION}(extreme=unknown)"
        digest = hashlib.sha256(self.extreme.numpy().tobytes()).hexdigest()[:12]
        return f"v{SHAPE_META_VERSION}(extreme={digest})"

    def fingerprint(self) -> str:
        """A string that changes with anything that changes the draws (used in fixed-set cache keys)."""
        return self._fingerprint

    __str__ = fingerprint

    def __repr__(self) -> str:
        return f"StoredShapePrior<{self._fingerprint}>"

    @classmethod
    def from_file(cls, path: str | Path, jitter: float = JITTER) -> StoredShapePrior:
        """The prior of a body file storing its shape samples (``sample_betas``, ``sample_ages_years``)."""
        path = Path(path).expanduser()
        with np.load(path, allow_pickle=False) as z:
            missing = [k for k in ("sample_betas", "sample_ages_years") if k not in z.files]
            if missing:
                raise ValueError(
                    f"{path}: no stored shape samples ({missing} missing; rebuild the body file)"
                )
            extreme = z["sample_extreme"] if "sample_extreme" in z.files else None
            return cls(z["sample_betas"], z["sample_ages_years"], jitter=jitter, extreme=extreme)


def no_shape_meta() -> dict[str, torch.Tensor]:
    """The metadata of a sample whose betas did not come from the prior (the pose source gave them)."""
    return {
        "shape_index": torch.tensor(-1, dtype=torch.long),
        "age_years": torch.tensor(float("nan"), dtype=torch.float32),
        "build_extreme": torch.tensor(-1, dtype=torch.long),
    }


def rest_measurements(body: Any, betas: torch.Tensor) -> dict[str, torch.Tensor]:
    """Stature (m), volume (m^3), mass (kg) and BMI (kg/m^2) of bodies ``betas [B, nb]`` in the rest pose.

    As anny's ``Anthropometry`` computes them, on the body's own rest (T-pose) mesh: stature is the vertical
    (y) extent, volume the enclosed volume of the mesh (signed tetrahedra), mass ``volume * BODY_DENSITY``,
    BMI ``mass / stature**2``. Each ``[B]`` float64."""
    with torch.no_grad():
        dtype = body.v_template.dtype
        rest, _ = body.shape(betas.to(device=body.v_template.device, dtype=dtype))
        rest = rest.double()
        faces = body.faces.to(rest.device).long()
        v0, v1, v2 = rest[:, faces[:, 0]], rest[:, faces[:, 1]], rest[:, faces[:, 2]]
        volume = (torch.cross(v0, v1, dim=-1) * v2).sum(-1).sum(-1).abs() / 6.0
        y = rest[..., 1]
        stature = y.amax(1) - y.amin(1)
        mass = volume * BODY_DENSITY
        bmi = mass / stature.clamp_min(1e-6) ** 2
    return {"stature_m": stature, "volume_m3": volume, "mass_kg": mass, "bmi": bmi}


def make_shape_prior(kind: str, body: Any) -> StoredShapePrior | None:
    """The prior ``data.shape_prior`` names for the body ``body`` (a config mapping or a body module).

    ``normal`` -> None (the dataset draws ``N(0, beta_scale^2 I)``); ``allages`` -> the stored samples of
    the ``anny_allages`` body (its ``model_path``, or the cached build; built on first use, needs ``anny``).
    Raises ``ValueError`` for another value or another body."""
    if kind not in SHAPE_PRIORS:
        raise ValueError(f"data.shape_prior must be one of {list(SHAPE_PRIORS)}, got {kind!r}")
    if kind == "normal":
        return None
    if body is None or isinstance(body, Mapping):
        body = body or {}
        name, model_path = str(body.get("name", "anny22")).lower(), body.get("model_path")
    else:
        name, model_path = str(getattr(body, "name", type(body).__name__)).lower(), None
    if name != "anny_allages":
        raise ValueError(
            f"data.shape_prior=allages draws the stored shapes of the all-ages body; body_model is {name!r} "
            "(use body_model=anny_allages, or data.shape_prior=normal)"
        )
    from arteq.body.anny_allages import ensure_anny_allages

    return StoredShapePrior.from_file(ensure_anny_allages(model_path))
