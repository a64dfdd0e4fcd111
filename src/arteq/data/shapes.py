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


class StoredShapePrior:
    """Betas drawn from stored shape samples, perturbed with their age band's covariance (module docstring).

    Args:
        betas: ``[N, K]`` stored samples' betas (the body's shape space, unit-variance components).
        ages: ``[N]`` their ages in years.
        jitter: perturbation scale (0: the stored samples themselves).
        bands: age band edges in years (increasing); a band with fewer than 2 samples uses all samples.
        name: what the prior is called in fingerprints.
    """

    def __init__(
        self,
        betas: np.ndarray | torch.Tensor,
        ages: np.ndarray | torch.Tensor,
        jitter: float = JITTER,
        bands: tuple[float, ...] = AGE_BANDS_YEARS,
        name: str = "allages",
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
        """One draw: betas ``[num_betas]`` float64 (the leading block of the stored components)."""
        if not 1 <= num_betas <= self.num_stored:
            raise ValueError(
                f"{self.name} shape prior: the body has {num_betas} betas, "
                f"the stored samples {self.num_stored}"
            )
        i = int(torch.randint(len(self.betas), (1,), generator=generator))
        z = torch.randn(num_betas, generator=generator, dtype=torch.float64)
        # the Cholesky factor of a covariance's leading block is the leading block of its factor
        chol = self.chol[self.band[i], :num_betas, :num_betas]
        return self.betas[i, :num_betas] + self.jitter * (chol @ z)

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
            return cls(z["sample_betas"], z["sample_ages_years"], jitter=jitter)


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
