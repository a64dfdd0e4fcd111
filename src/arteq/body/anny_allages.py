"""Build "anny_allages", the free body for every age and build, from the ``anny`` package.

Usage: ``python -m arteq.body.anny_allages [--out PATH] [--force] [--samples N] [--seed S]``; cached under
``cache_dir("body_models") / "anny_allages.npz"`` and built on first use by
``load_body_model("anny_allages")`` (or ``body_model=anny_allages``). Same mesh, rig, T-pose, axes and
file format as ``anny22`` (:mod:`arteq.body.anny_rig`); only the shape space differs:

* ages: Anny's own age-aware sampler (``SimpleShapeDistribution``) with morphological age uniform in
  ``[2, 90]`` years (toddlers to elderly; heights about 0.8-2.0 m), gender uniform in [0, 1];
* extreme builds: for a quarter of the samples (:data:`EXTREME_FRACTION`, drawn per sample) weight,
  muscle and proportions are uniform over Anny's whole phenotype range [0, 1] at the sampled age instead
  of the sampler's per-age distributions (very heavy, very thin, very muscular); height stays the
  sampler's (Anny's height range at a given age spans 1.2-2.4 m for adults: uniform would make giants);
* 2000 samples, seed 0, 32 components stored, :data:`DEFAULT_NUM_BETAS` used by default (chosen from the
  explained variance and vertex error per age band and build: experiments/body/README.md).

anny22 stays the research model's body (adults, like SMPL); a checkpoint records its body by name in its
``body_model`` hyper-parameters, so models of either body load with the right one.
"""

from __future__ import annotations

from pathlib import Path

import torch

from arteq.body import anny_rig
from arteq.body.anny_rig import AnnyBodySpec

NAME = "anny_allages"
AGE_RANGE = (2.0, 90.0)
#: Share of the samples whose build (weight, muscle, proportions) is uniform over Anny's range.
EXTREME_FRACTION = 0.25
BUILD_PHENOTYPES = ("weight", "muscle", "proportions")
NUM_SAMPLES = 2000
NUM_STORED_BETAS = 32
#: Betas used when a config does not say (chosen from experiments/body/README.md).
DEFAULT_NUM_BETAS = 16


def make_sampler(model, age_range=AGE_RANGE, extreme_fraction: float = EXTREME_FRACTION, extreme_only=False):
    """The all-ages sampler: ``sample(n) -> (age years, phenotypes, {"extreme": bool})``.

    ``extreme_only``: every sample an extreme build (for held-out evaluation sets)."""
    dist = anny_rig.phenotype_sampler(model, age_range)

    def sample(n: int):
        age, phen = dist.sample(n)
        dtype = phen["height"].dtype
        extreme = (
            torch.ones(n, dtype=torch.bool) if extreme_only else torch.rand(n, dtype=dtype) < extreme_fraction
        )
        for key in BUILD_PHENOTYPES:
            phen[key] = torch.where(extreme, torch.rand(n, dtype=dtype), phen[key])
        return age, phen, {"extreme": extreme}

    return sample


def spec(num_samples: int = NUM_SAMPLES, seed: int = 0) -> AnnyBodySpec:
    """The anny_allages build (see the module docstring)."""
    return AnnyBodySpec(
        name=NAME,
        make_sampler=make_sampler,
        num_samples=num_samples,
        seed=seed,
        num_stored_betas=NUM_STORED_BETAS,
        default_num_betas=DEFAULT_NUM_BETAS,
        meta={
            "morphological_age_range_years": list(AGE_RANGE),
            "gender": "uniform in [0, 1] (anny phenotype)",
            "extreme_builds": (
                f"a fraction {EXTREME_FRACTION} of the samples (drawn per sample) has "
                f"{', '.join(BUILD_PHENOTYPES)} uniform in [0, 1] instead of anny's per-age distributions"
            ),
        },
        build_time="about two minutes",
    )


def default_path() -> Path:
    """Where the cached file lives: ``cache_dir("body_models") / "anny_allages.npz"``."""
    return spec().default_path()


def ensure_anny_allages(path: str | Path | None = None, force: bool = False) -> Path:
    """Return the cached anny_allages file, building it (needs ``anny``) if absent or ``force``."""
    return anny_rig.ensure_body(spec(), path, force)


def main(argv: list[str] | None = None) -> None:
    anny_rig.main(spec, argv, doc=__doc__.split("\n\n")[0])


if __name__ == "__main__":
    main()
