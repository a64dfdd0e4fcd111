"""Calibration of the check's tube test (:func:`arteq.fit.quality.tube_fit`): bodies against tube-like objects.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/tube_probe.py [--seeds 0 1] [--views 32]

The share of a scan's points on its best tube (within 3 cm) for: every body of the user-scan suite
(``user_scans.people_scans``, acrobatic, children, adults, clutter scans without their clutter), the same
bodies in a pencil pose (arms overhead, legs together: the most tube-like a person gets) and sideways, the
cached single-view test sets (front, side, back, top, near; ``--views`` scans each) and non-bodies (a line,
poles, cylinders, capsules, a box, a cone, a torus, spheres; sampled surfaces with 3 mm noise). No fitting:
the value depends on the points only. Prints per group the min / median / max; ``--fit``: each non-body's
status and message from :class:`arteq.fit.Fitter` (``arteq-fit``'s defaults).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from arteq.fit.quality import sphere_fit, tube_fit  # noqa: E402


def arc_fit(points: np.ndarray, tol_m: float = 0.03) -> tuple[float, float]:
    """Like :func:`arteq.fit.quality.tube_fit`'s cylinder, but its axis placed by a circle fitted to the points
    across the long axis (algebraic, 2D), so that one camera's view of a pole (a half shell, whose centroid is
    off the axis) lies on it too. Probed for ``--arc``, not used by the check (experiments/fitting/tube_check.md)."""
    p = np.asarray(points, dtype=np.float64)
    p = p - p.mean(0)
    axis = np.linalg.svd(p[:: max(1, len(p) // 5000)], full_matrices=False)[2][0]
    t = p @ axis
    q = p - t[:, None] * axis
    xy = q @ np.linalg.svd(q[:: max(1, len(q) // 5000)], full_matrices=False)[2][:2].T
    sol = np.linalg.lstsq(np.c_[2 * xy, np.ones(len(xy))], (xy**2).sum(1), rcond=None)[0]
    r = float(np.sqrt(max(sol[2] + sol[:2] @ sol[:2], 0.0)))
    rho = np.linalg.norm(xy - sol[:2], axis=1)
    lo, hi = np.percentile(t, [0.5, 99.5])
    side = np.abs(rho - r) + np.maximum(np.maximum(lo - t, t - hi), 0.0)
    ends = np.minimum(np.abs(t - lo), np.abs(t - hi)) + np.maximum(rho - r, 0.0)
    return float((np.minimum(side, ends) < tol_m).mean()), r


def non_bodies(rng: np.random.Generator) -> dict[str, np.ndarray]:
    import trimesh

    def samp(m, n=5000):
        p, _ = trimesh.sample.sample_surface(m, n, seed=0)
        return np.asarray(p) + rng.normal(0, 0.003, (n, 3))

    c = trimesh.creation
    out = {"line 1.7 m": np.c_[np.linspace(0, 1.7, 5000), rng.normal(0, 0.003, (5000, 2))]}
    for r, h in ((0.05, 1.7), (0.15, 1.7), (0.2, 1.2), (0.3, 1.0)):
        out[f"cylinder r={r} h={h}"] = samp(c.cylinder(radius=r, height=h))
    for r, h in ((0.1, 1.5), (0.2, 1.4), (0.25, 1.0)):
        out[f"capsule r={r} h={h}"] = samp(c.capsule(radius=r, height=h))
    out["box 0.5 x 0.4 x 1.8"] = samp(c.box(extents=(0.5, 0.4, 1.8)))
    out["cone r=0.4 h=1.7"] = samp(c.cone(radius=0.4, height=1.7))
    out["torus 0.6 / 0.12"] = samp(c.torus(major_radius=0.6, minor_radius=0.12))
    out["sphere r=0.4"] = samp(c.icosphere(radius=0.4))
    return out


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--views", type=int, default=32)
    ap.add_argument("--arc", action="store_true", help="also the arc fit (arc_fit) of bodies and half objects")
    ap.add_argument("--fit", action="store_true", help="also fit the non-bodies with arteq-fit's defaults")
    ap.add_argument("--max-tube", type=float, default=None, help="--fit with this max_tube_frac (1.01: off)")
    a = ap.parse_args(argv)
    from user_scans import People, people_scans, pose_from_template, random_rotation, surface_scan

    rng = np.random.default_rng(0)
    groups: dict[str, list[tuple[str, float, float]]] = {}

    def add(group: str, name: str, pts: np.ndarray) -> None:
        f, r = tube_fit(pts)
        groups.setdefault(group, []).append((name, f, r))
        if a.arc:
            groups.setdefault(f"arc: {group}", []).append((name, *arc_fit(pts)))

    people = People()
    pencil = {"left_shoulder": (0, 0, 170), "right_shoulder": (0, 0, -170)}
    for seed in a.seeds:
        for s in people_scans(seed):
            if s.vertices is None:
                continue
            add(f"bodies: {s.group}", f"{seed} {s.name}", s.points if s.clean_points is None else s.clean_points)
        from user_scans import stated_builds

        for name, phen in stated_builds(people, 7000 + seed).items():
            v, _ = people.posed(people.person(phen), pose_from_template(pencil, rng), random_rotation(rng),
                                np.zeros(3))  # fmt: skip
            add("bodies: pencil pose", f"{seed} {name}", surface_scan(v, people.faces, 5000, rng))
        for phen in people.sample(2, (2.0, 6.0), 7900 + seed):
            v, _ = people.posed(people.person(phen), pose_from_template(pencil, rng), random_rotation(rng),
                                np.zeros(3))  # fmt: skip
            add("bodies: pencil pose", f"{seed} child", surface_scan(v, people.faces, 5000, rng))
    if a.views:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "single_view"))
        from run import scans as view_scans

        from arteq.body import create_body

        body = create_body({"name": "anny_allages"})
        for split, d in view_scans(a.views, body).items():
            for k, pts in enumerate(d["points"]):
                add(f"single views: {split.removeprefix('test_view_')}", str(k), pts.numpy())
    for name, pts in non_bodies(rng).items():
        add("non-bodies", name, pts)
        if a.arc:  # one camera's view of it: the half facing +x
            add("non-bodies, half (one side)", name, pts[pts[:, 0] > np.median(pts[:, 0])])
        groups.setdefault("non-bodies (sphere test)", []).append((name, *sphere_fit(pts)))
    print("| group | scans | tube share min / median / max | highest |")
    print("|---|---:|---|---|")
    for g, rows in groups.items():
        f = np.array([x[1] for x in rows])
        top = max(rows, key=lambda x: x[1])
        print(f"| {g} | {len(rows)} | {f.min():.2f} / {np.median(f):.2f} / {f.max():.2f} | {top[0]} |")
    for g in ("non-bodies", "arc: non-bodies", "non-bodies, half (one side)", "arc: non-bodies, half (one side)"):
        for name, f, r in groups.get(g, []):
            print(f"  {g}: {name}: {f:.2f} (r {r:.2f} m)")
    if a.fit:
        from arteq.fit import Fitter
        from arteq.fit.quality import QualityThresholds

        th = QualityThresholds() if a.max_tube is None else QualityThresholds(max_tube_frac=a.max_tube)
        fitter = Fitter(anny=False, thresholds=th)
        for name, pts in non_bodies(np.random.default_rng(1)).items():
            res = fitter.fit_points(pts, name=name)
            print(f"  fitted: {res.status}: {res.message}")


if __name__ == "__main__":
    main()
