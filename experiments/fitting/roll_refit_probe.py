"""Probe: do upper-arm roll starts, refined like the crossed-limb swaps and picked by the surface score, bring
the reach_up adults' arms out of their wrong twist (stature/README.md: the network's upper arms rolled 59-158
deg, made up by elbow twist; a roll split without refinement did not find them)?

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/roll_refit_probe.py --seeds 0 1 [--iters 30] \
        [--angles 90 180 270] [--groups adults children] [--only reach_up] [--variants plain arms]

For every scan of the chosen groups of the user-scan suite, ``arteq-fit``'s fit (defaults, ``anny_scan``) and
the same fit with extra starts in the crossed-limb step (:func:`arteq.fit.crossing.try_swaps`) wherever the
check doubts the fit: each arm's upper arm rolled about its own axis (shoulder -> elbow) by each angle, the
forearm keeping its world orientation (the elbow takes the difference), and both arms rolled by the same
angle; each on the fit (``plain``) and on the fit with its whole arms swapped (``arms``, the swap the
crossed-limb step takes on these scans). Printed per scan: V2V (cm, to the truth) of both, what the crossed-limb step took, and the fit's
seconds.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
import user_scans as us  # noqa: E402

import arteq.fit.api as api  # noqa: E402
import arteq.fit.crossing as crossing  # noqa: E402
from arteq.body.skeleton import JOINT_NAMES, PARENTS  # noqa: E402

ANGLES: list[int] = []
VARIANTS: list[str] = []  # "": rolled on the fit; "_arms": rolled after the whole-arms swap
_swap = crossing.swap_start
_pairs = api.pairs_to_try


def roll_start(local: np.ndarray, global_rot: np.ndarray, joints: np.ndarray, name: str) -> np.ndarray:
    """``roll_<sides>_<deg>[_<swap>]``: each named arm's upper arm rolled about shoulder -> elbow by deg, the
    forearm's world rotation kept; after ``swap`` (:func:`arteq.fit.crossing.swap_start`) when named."""
    _, sides, deg, *swap = name.split("_")
    out = np.array(local, dtype=np.float64, copy=True)
    if swap:  # the swapped fit's global rotations and joints, as swap_start moves them
        from arteq.fit.refine import branch_parts
        from arteq.geometry.rotations import rotation_between

        g, pos, ref = np.array(global_rot, copy=True), np.array(joints, copy=True), joints
        for p in crossing.SWAPS.get(swap[0], (swap[0],)):
            lj, rj, le, re = crossing.PAIRS[p]
            for j, end, other in ((lj, le, re), (rj, re, le)):
                aim = rotation_between(torch.as_tensor(pos[end] - pos[j]), torch.as_tensor(ref[other] - pos[j])).numpy()
                moved = branch_parts(j)
                g[moved] = aim @ g[moved]
                pos[moved] = pos[j] + (pos[moved] - pos[j]) @ aim.T
        out = _swap(local, global_rot, joints, swap[0])
        global_rot, joints = g, pos
    for side in {"L": ["left"], "R": ["right"], "B": ["left", "right"]}[sides]:
        sh, el = JOINT_NAMES.index(f"{side}_shoulder"), JOINT_NAMES.index(f"{side}_elbow")
        axis = joints[el] - joints[sh]
        turn = roma.rotvec_to_rotmat(torch.as_tensor(axis / np.linalg.norm(axis) * np.radians(float(deg)))).numpy()
        g_sh = turn @ global_rot[sh]
        out[sh] = global_rot[PARENTS[sh]].T @ g_sh
        out[el] = g_sh.T @ global_rot[el]
    return out


def swap_or_roll(local, global_rot, joints, pair):
    return roll_start(local, global_rot, joints, pair) if pair.startswith("roll_") else _swap(local, global_rot, joints, pair)


def pairs_with_rolls(joints, doubtful, config=None):
    pairs = _pairs(joints, doubtful, config)
    if doubtful:
        pairs += [f"roll_{s}_{a}{w}" for s in "LRB" for a in ANGLES for w in VARIANTS]
    return pairs


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--iters", type=int, default=30)
    ap.add_argument("--angles", type=int, nargs="+", default=[90, 180, 270])
    ap.add_argument("--groups", nargs="+", default=["adults"])
    ap.add_argument("--only", default="", help="only scans whose name holds this")
    ap.add_argument("--variants", nargs="+", choices=("plain", "arms"), default=["plain", "arms"],
                    help="roll the fit's arms (plain) and / or the arms-swapped fit's (arms)")
    args = ap.parse_args()
    ANGLES[:] = args.angles
    VARIANTS[:] = ["" if v == "plain" else "_arms" for v in args.variants]
    torch.set_num_threads(1)
    from arteq.fit import Fitter

    cc = crossing.CrossingConfig(iters=args.iters)
    f = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False, crossing=cc)
    rows = []
    for seed in args.seeds:
        for s in us.people_scans(seed):
            if s.group not in args.groups or s.vertices is None or args.only not in s.name:
                continue
            res = {}
            for arm in ("base", "rolls"):
                crossing.swap_start = swap_or_roll if arm == "rolls" else _swap
                api.pairs_to_try = pairs_with_rolls if arm == "rolls" else _pairs
                v2v, taken, sec, r = us.timed_fit(f, s)
                res[arm] = (v2v, taken, sec, r.status)
                if arm == "rolls" and r.crossing:
                    tried = sorted(r.crossing["tried_cm"].items(), key=lambda kv: kv[1])
                    print("   fit", r.crossing["score_cm"], "tried:", " ".join(f"{k}={v:.3f}" for k, v in tried[:8]),
                          "stopped:", len(r.crossing["stopped"]))
            rows.append((seed, s.name, res))
            b, k = res["base"], res["rolls"]
            print(f"{seed} {s.name[:40]:40s} base {b[0]:6.2f} {b[1]:10s} {b[2]:5.2f}s {b[3]:9s} | "
                  f"rolls {k[0]:6.2f} {k[1]:10s} {k[2]:5.2f}s {k[3]}", flush=True)  # fmt: skip
    for arm in ("base", "rolls"):
        v = np.array([r[2][arm][0] for r in rows])
        t = np.array([r[2][arm][2] for r in rows])
        print(f"{arm}: V2V mean {v.mean():.3f} worst {v.max():.2f}; above 1.5: {(v > 1.5).sum()}; s/scan {t.mean():.2f}")


if __name__ == "__main__":
    main()
