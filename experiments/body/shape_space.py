"""How many shape components does a body for every age and build need? (issue 19, item 1)

    PYTHONPATH=src OMP_NUM_THREADS=1 python experiments/body/shape_space.py [--samples 2000] [--heldout 100]

Builds the anny_allages PCA exactly as ``python -m arteq.body.anny_allages`` does (same sampler, seed and
sample count), then projects held-out Anny bodies (new seeds) of each group onto its first k components:

- children: Anny's sampler, morphological age 2-12 years;
- adults: Anny's sampler, 18-70 years;
- elderly: Anny's sampler, 70-90 years;
- extreme builds: ages 2-90, weight / muscle / proportions uniform over Anny's range (height: the sampler's).

Reported per group and k: variance explained (1 - residual / total sum of squares about the PCA mean)
and the vertex error of the projection (mean over vertices and bodies; the worst vertex of any body),
T-posed, pelvis at the origin, millimetres. The same held-out bodies projected onto anny22's shape space
(adults 18-70, 16 components) show what the adult body misses. Prints Markdown tables.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

GROUPS = {
    "children 2-12": dict(age_range=(2.0, 12.0), extreme_fraction=0.0),
    "adults 18-70": dict(age_range=(18.0, 70.0), extreme_fraction=0.0),
    "elderly 70-90": dict(age_range=(70.0, 90.0), extreme_fraction=0.0),
    "extreme builds 2-90": dict(age_range=(2.0, 90.0), extreme_only=True),
}
KS = (1, 2, 4, 6, 8, 10, 12, 16, 20, 24, 32)


def project(V: np.ndarray, mean: np.ndarray, dirs: np.ndarray, k: int) -> np.ndarray:
    """Least-squares reconstruction of shapes ``V [N, nv, 3]`` with the first ``k`` components."""
    X = V.reshape(len(V), -1) - mean
    A = dirs.reshape(-1, dirs.shape[-1])[:, :k]
    coef, *_ = np.linalg.lstsq(A, X.T, rcond=None)
    return (A @ coef).T + mean, coef


def main() -> None:
    from dataclasses import replace

    from arteq.body import anny22, anny_allages, anny_rig

    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=anny_allages.NUM_SAMPLES)
    ap.add_argument("--heldout", type=int, default=100, help="held-out bodies per group")
    a = ap.parse_args()
    t0 = time.time()
    model = anny_rig.load_anny()
    bake = anny_rig.compute_bake(model)
    spec = anny_allages.spec(num_samples=a.samples)
    train = anny_rig.sample_shapes(spec, model, bake)
    mean, dirs, explained = anny_rig.pca_shape_space(train["vertices"], max(KS))
    h = train["vertices"][..., 1].max(1) - train["vertices"][..., 1].min(1)
    print(f"anny_allages PCA: {a.samples} samples in {time.time() - t0:.0f} s; ages "
          f"{train['ages'].min():.1f}-{train['ages'].max():.1f} y, heights {h.min():.2f}-{h.max():.2f} m, "
          f"{int(train['tags']['extreme'].sum())} extreme builds\n")  # fmt: skip
    print("training-set variance explained (cumulative), k = " + ", ".join(map(str, KS)) + ":")
    print(", ".join(f"{explained[k - 1] * 100:.2f}" for k in KS) + " %\n")

    adult = np.load(anny22.default_path())
    a_mean, a_dirs = adult["v_template"].reshape(-1).astype(np.float64), adult["shapedirs"].astype(np.float64)

    rows, adult_rows = [], []
    for gi, (group, kw) in enumerate(GROUPS.items()):

        def make(model, kw=kw):
            return anny_allages.make_sampler(model, **kw)

        held_spec = replace(spec, make_sampler=make)
        held = anny_rig.sample_shapes(held_spec, model, bake, a.heldout, seed=1000 + gi)
        V = held["vertices"]
        hh = V[..., 1].max(1) - V[..., 1].min(1)
        tot = ((V.reshape(len(V), -1) - mean) ** 2).sum()
        for k in KS:
            R, _ = project(V, mean, dirs, k)
            err = np.linalg.norm(R.reshape(V.shape) - V, axis=-1) * 1000
            ve = 1 - ((R - V.reshape(len(V), -1)) ** 2).sum() / tot
            rows.append((group, k, ve, err.mean(), err.max(1).mean(), err.max()))
        for k in (10, 16):
            R, _ = project(V, a_mean, a_dirs, k)
            err = np.linalg.norm(R.reshape(V.shape) - V, axis=-1) * 1000
            adult_rows.append((group, k, err.mean(), err.max()))
        ages = held["ages"]
        print(f"{group}: {a.heldout} held-out bodies, ages {ages.min():.1f}-{ages.max():.1f} y, "
              f"heights {hh.min():.2f}-{hh.max():.2f} m", flush=True)  # fmt: skip

    print("\n| group | k | variance explained % | vertex error mean mm | worst vertex per body, mean mm "
          "| worst vertex mm |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|")
    for group, k, ve, m, wb, w in rows:
        print(f"| {group} | {k} | {ve * 100:.3f} | {m:.2f} | {wb:.2f} | {w:.1f} |")
    print("\nthe same bodies in anny22's shape space (adults 18-70):\n")
    print("| group | k | vertex error mean mm | worst vertex mm |")
    print("|---|---:|---:|---:|")
    for group, k, m, w in adult_rows:
        print(f"| {group} | {k} | {m:.2f} | {w:.1f} |")
    print(f"\n{time.time() - t0:.0f} s in all")


if __name__ == "__main__":
    main()
