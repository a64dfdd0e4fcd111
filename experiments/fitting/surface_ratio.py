"""The check's surface ratio on scans whose truth is known: one body (and its scanner defects) against two.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/surface_ratio.py --seeds 0 1 2 \
        --out experiments/fitting/surface_ratio/truth.md

``arteq.fit.quality`` refuses a scan as ``extra_surface`` when it holds more than ``max_surface_ratio``
(1.4) times the fitted body's surface and the fit explains fewer than 55 % of its points. The ratio is
:func:`arteq.fit.quality.surface_cells` of the scan over that of the body's vertices, on the check's grid
(6 cm cells, corner at the mesh's lowest corner). Here the "fit" is the **true** mesh, so the table shows
what each kind of scan holds, apart from how well a network fits it (the fitter's own values are in the
user-scan suite's records, ``user_scans.py --json``: ``surface_ratio``, ``inlier_frac``):

- the user-scan suite's bodies (``user_scans.people_scans``: acrobatic, children, adults; clutter scans
  without their clutter, which the clean-up removes), on their flat faces and (``curved``) on the smooth
  surface through their vertices;
- the scanner defects of ``scan_defects.py`` (noise, density, holes, one side, a stool, clothing) on the
  adults and children of its bodies, scanned the same way (the stool and the floor kept: the clean-up keeps
  a stool touching the body; the floor it removes is left out here);
- two people side by side, their centres 0.55, 0.8 and 1.0 m apart (the suite's and the calibration's
  spacings), everyday poses, 2500 points each: the ratio against each one's mesh (the fit lands on one).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv: list[str] | None = None) -> None:
    import scan_defects as sd
    import user_scans as us

    from arteq.fit.conditions import scan_conditions
    from arteq.fit.quality import QualityThresholds, surface_cells

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--out", default=None, help="write the Markdown table here")
    a = ap.parse_args(argv)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))
    th = QualityThresholds()
    cell = th.surface_cell_cm / 100

    def ratio(points: np.ndarray, verts: np.ndarray) -> float:
        """As the check: its cell grown with the scan's measured noise."""
        c = cell
        noise = scan_conditions(points).get("noise_m")
        if noise is not None:
            c = max(c, th.noise_cell * noise)
        o = verts.min(0)
        return surface_cells(points, c, o) / surface_cells(verts, c, o)

    t0 = time.perf_counter()
    rows: dict[str, list[float]] = {}
    people = us.People(us.TRUTH_BETAS)
    for seed in a.seeds:
        for curved in (False, True):
            for s in us.people_scans(seed, curved=curved):
                if s.vertices is None:
                    continue
                pts = s.points if s.clean_points is None else s.clean_points
                key = f"one body: {s.group}" + (", curved surface" if curved else "")
                rows.setdefault(key, []).append(ratio(pts, s.vertices))
        rng = np.random.default_rng(seed)
        phen = people.sample(2, (3.0, 12.0), 8100 + seed) + people.sample(2, (18.0, 70.0), 8200 + seed)
        labels = people.body.part_labels.numpy()
        for k, ph in enumerate(phen):
            p = people.person(ph)
            pose = us.pose_from_template(us.EVERYDAY[list(us.EVERYDAY)[k % len(us.EVERYDAY)]], rng)
            rot = us.z_up_heading(rng)
            v, j = people.posed(p, pose, rot, np.zeros(3))
            up = rot @ np.array([0.0, 1.0, 0.0])
            for kind in sd.DEFECTS:
                pts = sd.defect_scan(kind, v, j, people.faces, up, rng, labels=labels)
                if kind in ("seat", "no_soles"):  # the floor goes with the clean-up; a stool stays
                    pts = pts[pts @ up > (v @ up).min() + 0.01]
                if len(pts) > 5000:  # the check sees the fitter's 5000-point resample
                    pts = pts[rng.choice(len(pts), 5000, replace=False)]
                rows.setdefault(f"scanner defect: {kind}", []).append(ratio(pts, v))
        for gap in (0.55, 0.8, 1.0):
            ph = people.sample(2, (18.0, 70.0), 9000 + seed + int(gap * 100))
            vs = []
            for m in range(2):
                pose = us.pose_from_template(us.EVERYDAY[list(us.EVERYDAY)[(seed + m) % len(us.EVERYDAY)]], rng)
                vs.append(people.posed(people.person(ph[m]), pose, np.eye(3), np.array([m * gap, 0.0, 0.0]))[0])
            pts = np.concatenate([us.surface_scan(v, people.faces, 2500, rng) for v in vs])
            rows.setdefault(f"two people, {gap} m apart", []).extend(ratio(pts, v) for v in vs)
    lines = [
        f"# {__doc__.splitlines()[0]}", "", "```",
        "OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/surface_ratio.py " + " ".join(argv or sys.argv[1:]),
        "```", "",
        f"Seeds {', '.join(map(str, a.seeds))}; {time.perf_counter() - t0:.0f} s. Surface ratio: the scan's "
        f"occupied {th.surface_cell_cm:g} cm cells (with an occupied neighbour; at least {th.noise_cell:g} times "
        "the measured noise) over the true mesh's; the check "
        f"refuses above {th.max_surface_ratio:g} when the fit explains < {th.unexplained[0]:.0%} of the points.",
        "", "| scans | count | min | median | max |", "|---|---:|---:|---:|---:|",
    ]  # fmt: skip
    for k, x in rows.items():
        lines.append(f"| {k} | {len(x)} | {min(x):.2f} | {np.median(x):.2f} | {max(x):.2f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text)


if __name__ == "__main__":
    main()
