"""Probe: scans made of stripes (a LiDAR's or a structured-light scanner's scan lines) instead of even points.

    OMP_NUM_THREADS=2 .venv/bin/python experiments/fitting/stripes_probe.py [--bodies 4] [--gaps 0.02 0.05]

Bodies from anny's own sampler (18-70 y, seed 9100, not the training shapes), everyday templates of the
user-scan suite, standing upright; 200 000 surface points with 3 mm noise (``user_scans.surface_scan``), of
which only those within 1.5 mm of horizontal planes every ``gap`` metres are kept (3 mm thick lines: 11-30
thousand points). Fitted with ``arteq-fit``'s defaults (``anny_scan``), against the first 5000 of the even
points. Prints status and V2V (cm, against the true mesh) per body and pattern, then the means.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bodies", type=int, default=4)
    ap.add_argument("--gaps", type=float, nargs="+", default=[0.02, 0.05])
    a = ap.parse_args(argv)
    from user_scans import EVERYDAY, People, pose_from_template, surface_scan

    from arteq.fit import Fitter

    fitter = Fitter(anny=False)
    people = People()
    rng = np.random.default_rng(5)
    poses = list(EVERYDAY)
    v2v: dict[str, list[float]] = {}
    for k, phen in enumerate(people.sample(a.bodies, (18.0, 70.0), 9100)):
        pose = poses[k % len(poses)]
        verts, _ = people.posed(people.person(phen), pose_from_template(EVERYDAY[pose], rng), np.eye(3), np.zeros(3))
        dense = surface_scan(verts, people.faces, 200_000, rng, noise=0.003)
        clouds = {"even 5000": dense[:5000]}
        for gap in a.gaps:
            clouds[f"stripes every {gap * 100:.0f} cm"] = dense[np.abs((dense[:, 1] + 10) % gap - gap / 2) < 0.0015]
        for name, pts in clouds.items():
            r = fitter.fit_points(pts, name=name)
            e = float(np.linalg.norm(r.vertices - verts, axis=1).mean() * 100) if r.vertices is not None else np.nan
            v2v.setdefault(name, []).append(e)
            print(f"{k} {pose:12s} {name:22s} {len(pts):6d} points  {r.status:10s} V2V {e:.2f} cm", flush=True)
    for name, vals in v2v.items():
        print(f"mean V2V {name}: {np.nanmean(vals):.2f} cm (worst {np.nanmax(vals):.2f}), {len(vals)} bodies")


if __name__ == "__main__":
    main()
