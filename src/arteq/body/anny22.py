"""Build "anny22", the free SMPL-format default body, from the ``anny`` package (Apache-2.0, CC0 assets).

Usage: ``python -m arteq.body.anny22 [--out PATH] [--force] [--samples N] [--seed S]``. The file is cached
under ``arteq.paths.cache_dir("body_models") / "anny22.npz"`` and built on first use by
``load_body_model("anny22")``. ``anny`` is imported only inside the build: everything else runs from the
cached file on machines without ``anny``. Nothing is downloaded.

anny22 is the research model's body (like SMPL, adults): its PCA shape space is built from 600 shapes of
``anny.shape_distribution.SimpleShapeDistribution`` with morphological age uniform in ``[18, 70]`` years,
all genders, seed 0; 16 components stored, 10 used by default. Everything else (rig, T-pose, axes, joint
regressor, the file format) is :mod:`arteq.body.anny_rig`, shared with ``anny_allages``. The names below
are re-exported from there, so ``arteq.body.anny22.anny_tpose`` etc. keep working.
"""

from __future__ import annotations

from pathlib import Path

from arteq.body import anny_rig
from arteq.body.anny_rig import (  # noqa: F401  (re-exported: the rig machinery under its old module name)
    ANNY_TO_SMPL,
    JOINT_TO_ANNY,
    NUM_STORED_BETAS,
    TOE_BASES,
    TPOSE_BAKE,
    AnnyBodySpec,
    _bake_pose,
    _fit_regressor,
    anny_deltas_from_pose,
    anny_tpose,
    baked_globals,
    compute_bake,
    fold_table,
    load_anny,
)

NAME = "anny22"
AGE_RANGE = (18.0, 70.0)


def spec(num_samples: int = 600, seed: int = 0, age_range: tuple[float, float] = AGE_RANGE) -> AnnyBodySpec:
    """The anny22 build: Anny's own sampler, adults of ``age_range`` years (its file never changes)."""

    def make_sampler(model):
        dist = anny_rig.phenotype_sampler(model, age_range)

        def sample(n):
            age, phen = dist.sample(n)
            return age, phen, {}

        return sample

    return AnnyBodySpec(
        name=NAME,
        make_sampler=make_sampler,
        num_samples=num_samples,
        seed=seed,
        num_stored_betas=NUM_STORED_BETAS,
        default_num_betas=10,
        meta={
            "morphological_age_range_years": list(age_range),
            "gender": "uniform in [0, 1] (anny phenotype)",
        },
    )


def default_path() -> Path:
    """Where the cached anny22 model lives: ``cache_dir("body_models") / "anny22.npz"``."""
    return spec().default_path()


def build_anny22(
    out: str | Path | None = None,
    num_samples: int = 600,
    seed: int = 0,
    age_range: tuple[float, float] = AGE_RANGE,
    verbose: bool = True,
) -> Path:
    """Build the anny22 model file (atomically) and return its path. Takes about a minute warm."""
    return anny_rig.build_anny_body(spec(num_samples, seed, age_range), out, verbose=verbose)


def read_meta(path: str | Path | None = None) -> dict:
    """Provenance dict stored in an anny22 file (default: the cached one)."""
    return anny_rig.read_meta(path or default_path())


def read_bake(path: str | Path | None = None):
    """The T-pose bake deltas ``{anny bone: [3,3]}`` stored in an anny22 file (default: the cached one)."""
    return anny_rig.read_bake(path or default_path())


def ensure_anny22(path: str | Path | None = None, force: bool = False) -> Path:
    """Return the cached anny22 file, building it (needs ``anny``) if absent or ``force``."""
    return anny_rig.ensure_body(spec(), path, force)


def main(argv: list[str] | None = None) -> None:
    anny_rig.main(spec, argv, doc=__doc__.split("\n\n")[0])


if __name__ == "__main__":
    main()
