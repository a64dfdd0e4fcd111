"""Probe: limbs aimed at the scan points a fit leaves unexplained ("reach" starts in the crossed-limb step).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/reach_probe.py --seeds 0 1 2 3 \
        [--groups children adults acrobatic clutter] [--only NAME]

On new seeds of the user-scan suite (seeds 2-5, experiments/fitting/seeds/) some fits pass the check with a
forearm somewhere else: a child's reach_up (seed 2) 10.2 cm V2V, `ok`, its right wrist 44 cm off, and 166 scan
points (the true forearm and hand, 34 cm long) farther than 3 cm from the fit. For each fit, the scan points
farther than ``--far`` from the fitted mesh are grouped (links under 4 cm); each group of at least
``--min-points`` points and ``--min-extent`` across is a target. Every limb segment (upper arm, forearm, thigh,
shin) whose joint lies within its branch's reach of the target is aimed at the target's centroid (the
segment's children follow, as in a swap), and refined with the crossed-limb step's swaps
(:func:`arteq.fit.crossing.try_swaps`; same iterations, stop and pick by the surface score). Printed per scan:
V2V with and without the reach starts, what was taken, seconds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import user_scans as us  # noqa: E402

import arteq.fit.api as api  # noqa: E402
import arteq.fit.crossing as crossing  # noqa: E402
from arteq.body.skeleton import JOINT_NAMES  # noqa: E402

_swap = crossing.swap_start
_try = crossing.try_swaps
_pairs = api.pairs_to_try
OPT = {}
#: joint -> the end of its segment
SEGMENTS = {j: e for lj, rj, le, re in crossing.PAIRS.values() for j, e in ((lj, le), (rj, re))}


def clusters(points: np.ndarray, vertices: np.ndarray) -> list[np.ndarray]:
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.spatial import cKDTree

    far = points[cKDTree(vertices).query(points)[0] > OPT["far"]]
    if len(far) < OPT["min_points"]:
        return []
    pairs = cKDTree(far).query_pairs(0.04, output_type="ndarray")
    a = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(far),) * 2)
    _, lab = connected_components(a, directed=False)
    out = []
    for c in np.argsort(-np.bincount(lab))[:2]:
        pts = far[lab == c]
        if len(pts) >= OPT["min_points"] and np.linalg.norm(pts.max(0) - pts.min(0)) >= OPT["min_extent"]:
            out.append(pts)
    return out


def reach_start(local, global_rot, joints, name):
    from arteq.body.skeleton import PARENTS
    from arteq.fit.refine import branch_parts
    from arteq.geometry.rotations import rotation_between

    _, j, x, y, z = name.split("_")
    j, target = int(j), np.array([float(x), float(y), float(z)])
    e = SEGMENTS[j]
    aim = rotation_between(torch.as_tensor(joints[e] - joints[j]), torch.as_tensor(target - joints[j])).numpy()
    g = np.array(global_rot, dtype=np.float64, copy=True)
    moved = branch_parts(j)
    g[moved] = aim @ g[moved]
    out = np.array(local, dtype=np.float64, copy=True)
    out[j] = g[PARENTS[j]].T @ g[j]
    return out


def swap_or_reach(local, global_rot, joints, pair):
    return reach_start(local, global_rot, joints, pair) if pair.startswith("reach_") else _swap(local, global_rot, joints, pair)


def pairs_plus(joints, doubtful, config=None):
    return [*_pairs(joints, doubtful, config), "?"]  # "?": the reach starts, filled in with the points


def try_with_reach(body, points, fit, subset, tries, refine_config, config=None, keep_all=False, extra=None):
    """The swaps as usual, then reach starts from each scan's picked fit (a second round). (Since 2026-12-07
    the fitter has reach starts of its own, ``arteq.fit.reach``, passed as ``extra``; this probe's are
    the earlier design of experiments/fitting/off_fit.md.)"""
    from arteq.fit.refine import branch_parts

    swaps = [[p for p in t if p != "?"] for t in tries]
    first = _try(body, points, fit, subset, swaps, refine_config, config, extra=extra)
    fit2 = {k: v.detach().clone() for k, v in fit.items()}
    for i, p in enumerate(first):
        if p["taken"]:
            for k in fit2:
                fit2[k][i] = p[k].to(fit2[k].dtype)
    verts_all = fit2["vertices"].detach().double().cpu().numpy()
    joints_all = fit2["joints"].detach().double().cpu().numpy()
    tries2 = []
    for i, t in enumerate(tries):
        t2 = []
        if "?" in t:
            jt = joints_all[i]
            for pts in clusters(points[i], verts_all[i]):
                c = pts.mean(0)
                for j in SEGMENTS:
                    reach = max(np.linalg.norm(jt[k] - jt[j]) for k in branch_parts(j)) + 0.15
                    if 0.05 < np.linalg.norm(c - jt[j]) < reach:
                        t2.append(f"reach_{j}_{c[0]:.4f}_{c[1]:.4f}_{c[2]:.4f}")
        tries2.append(t2)
    if not any(tries2):
        return first
    second = _try(body, points, fit2, subset, tries2, refine_config, config)
    for i, (p, q) in enumerate(zip(first, second)):
        p["tried"].update({"2:" + k: v for k, v in q["tried"].items()})
        if q["taken"].startswith("reach_"):
            p.update({k: v for k, v in q.items() if k not in ("tried", "score", "stopped")})
    return first


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3])
    ap.add_argument("--groups", nargs="+", default=["children", "adults", "acrobatic", "clutter"])
    ap.add_argument("--only", default="")
    ap.add_argument("--far", type=float, default=0.03)
    ap.add_argument("--min-points", type=int, default=40)
    ap.add_argument("--min-extent", type=float, default=0.1)
    args = ap.parse_args()
    OPT.update(far=args.far, min_points=args.min_points, min_extent=args.min_extent)
    torch.set_num_threads(1)
    from arteq.fit import Fitter

    f = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
    rows = []
    for seed in args.seeds:
        for s in us.people_scans(seed):
            if s.group not in args.groups or s.vertices is None or args.only not in s.name:
                continue
            res = {}
            for arm in ("base", "reach"):
                on = arm == "reach"
                crossing.swap_start = swap_or_reach if on else _swap
                api.pairs_to_try = pairs_plus if on else _pairs
                api.try_swaps = try_with_reach if on else _try
                v2v, taken, sec, r = us.timed_fit(f, s)
                if taken.startswith("reach_"):
                    taken = "reach " + JOINT_NAMES[int(taken.split("_")[1])]
                res[arm] = (v2v, taken, sec, r.status)
                if on and args.only and r.crossing:
                    tried = {(("reach " + JOINT_NAMES[int(k.split("_")[1])]) if "reach_" in k else k): v
                             for k, v in r.crossing["tried_cm"].items()}
                    print("   score", r.crossing["score_cm"], tried, r.crossing.get("stopped"))
            rows.append((seed, s.group, s.name, res))
            b, k = res["base"], res["reach"]
            flag = " <<" if abs(b[0] - k[0]) > 0.05 else ""
            print(f"{seed} {s.group[:5]} {s.name[:34]:34s} base {b[0]:6.2f} {b[1][:14]:14s} {b[2]:5.2f}s {b[3]:9s} | "
                  f"reach {k[0]:6.2f} {k[1][:20]:20s} {k[2]:5.2f}s {k[3]}{flag}", flush=True)  # fmt: skip
    for g in args.groups:
        for arm in ("base", "reach"):
            v = np.array([r[3][arm][0] for r in rows if r[1] == g])
            t = np.array([r[3][arm][2] for r in rows if r[1] == g])
            if len(v):
                print(f"{g} {arm}: V2V mean {v.mean():.3f} worst {v.max():.2f}; s/scan {t.mean():.2f}")


if __name__ == "__main__":
    main()
