"""Clutter removal alone (``arteq.fit.clean``) on generated cluttered scans: what it removes.

    PYTHONPATH=src OMP_NUM_THREADS=1 python experiments/fitting/clutter.py [--n 12]

Each scan: a generated body (5000 points, 5 mm noise, any heading, 2 m offset; everyday poses standing on
the floor, or acrobatic poses with the floor under their lowest point along a random up) plus clutter from
``arteq.fit.demo.add_clutter``: 10 % stray points in a 4 m box, a 2.5 m floor patch, a 2.5 x 2.2 m wall
0.4 m behind, a 0.3 m box 0.6 m beside (floor and wall at half the body's point density, ~5000-6000
points each). Reported per case: the share of each kind of clutter removed, the share of the body's own
points removed (and of those more than 2 cm from the floor: the soles touching the floor are
indistinguishable from it), scans flagged ``second_body``, seconds per scan.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

CASES = {
    "clean (no clutter)": ("id", ()),
    "10% stray points": ("id", ("stray",)),
    "floor": ("id", ("floor",)),
    "floor + 10% stray": ("id", ("floor", "stray")),
    "wall": ("id", ("wall",)),
    "box object": ("id", ("floor", "box")),
    "all: stray + floor + wall + box": ("id", ("stray", "floor", "wall", "box")),
    "acrobatic, all clutter": ("ood", ("stray", "floor", "wall", "box")),
    "lying on the floor + stray": ("lying", ("floor", "stray")),
    "lying on the back on the floor + stray": ("supine", ("floor", "stray")),
    "lying face down on the floor + stray": ("prone", ("floor", "stray")),
    "two people 0.9 m apart": ("two", ()),
}


def scene(body, case: str, i: int):
    from arteq.fit.demo import CLUTTER_KINDS, add_clutter, synthetic_scan

    split, kinds = CASES[case]
    s = synthetic_scan(body, "test_ood" if split == "ood" else "test_id", index=i, seed=11, offset=2.0)
    rot = s["rotation"]
    up = rot @ np.array([0.0, 1.0, 0.0])
    if split == "ood":
        up = np.random.default_rng(100 + i).normal(size=3)
    if split == "lying":
        up = rot @ np.array([1.0, 0.0, 0.0])  # lying on its side
    if split in ("supine", "prone"):  # on its back (the front up) or face down
        up = rot @ np.array([0.0, 0.0, 1.0 if split == "supine" else -1.0])
    pts, lab = add_clutter(s["points"], s["vertices"], s["faces"], up, kinds, seed=i)
    if split == "two":
        t = synthetic_scan(body, "test_id", index=i + 50, seed=12, offset=0.0, rotate=False)
        shift = s["vertices"].mean(0) + rot @ np.array([0.9 + 0.5, 0.0, 0.0]) - t["vertices"].mean(0)
        other = t["points"] @ rot.T + shift
        pts = np.concatenate([pts, other])
        lab = np.concatenate([lab, np.full(len(other), 9)])
    up = up / np.linalg.norm(up)
    floor_h = (s["vertices"] @ up).min()
    contact = np.zeros(len(pts), dtype=bool)
    contact[: len(s["points"])] = (s["points"] @ up - floor_h) < 0.02
    return pts, lab, contact, CLUTTER_KINDS


def main() -> None:
    from arteq.body import load_body_model
    from arteq.fit.clean import clean_scan

    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--cases", default="", help="comma-separated substrings of the case names to run")
    a = ap.parse_args()
    body = load_body_model("anny22")
    print(f"{a.n} scans per case\n")
    print("| case | stray removed % | floor removed % | wall removed % | box removed % | body points lost % "
          "| body lost, > 2 cm from the floor % | flagged second_body | s per scan |")  # fmt: skip
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for case in [c for c in CASES if not a.cases or any(k in c for k in a.cases.split(","))]:
        rem = {k: [0, 0] for k in ("stray", "floor", "wall", "box")}
        lost, lost_free, flagged, secs = [], [], 0, []
        for i in range(a.n):
            pts, lab, contact, kinds = scene(body, case, i)
            t = time.perf_counter()
            res = clean_scan(pts)
            secs.append(time.perf_counter() - t)
            for k in rem:
                m = lab == kinds[k]
                rem[k][0] += int((~res.keep[m]).sum())
                rem[k][1] += int(m.sum())
            b = lab == 0
            lost.append((~res.keep[b]).mean() * 100)
            lost_free.append((~res.keep[b & ~contact]).mean() * 100)
            flagged += "second_body" in res.flags
        cell = {k: (f"{100 * r / n:.1f}" if n else "-") for k, (r, n) in rem.items()}
        lost_cells = (f"{np.mean(lost):.2f} (max {np.max(lost):.2f}) | "
                      f"{np.mean(lost_free):.2f} (max {np.max(lost_free):.2f})")  # fmt: skip
        if case.startswith("two people"):  # the kept one is whichever is larger: no "body lost" here
            lost_cells = "- | -"
        print(f"| {case} | {cell['stray']} | {cell['floor']} | {cell['wall']} | {cell['box']} | {lost_cells} "
              f"| {flagged}/{a.n} | {np.median(secs):.3f} |", flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
