"""Probe: the torso read turned round (half a turn about its long axis), the limbs read again after it.

acro_eval.py finds the lost back bends (backbend, bow, wheel, camel) with the network's torso rotations half a
turn off about the torso's long axis (front read as back), and with it every limb's side (the side rule reads
left and right in that frame). This probe turns the network's torso reading round inside the network, so that
the sides, the limbs' pooling and the limbs' rotations follow, and turns the torso parts' own predicted
rotations round too (``ArtEqNet(...)(points, turn_torso=True)``; parent conditioning is invariant: the limbs
do not read the torso's rotation); the second start's network (``anny22``) reads as trained. Then:

- network only: part accuracy, torso error, V2V, read as trained and turned round;
- the whole fitter (``arteq-fit``'s defaults) from each reading: V2V and the fit's surface score
  (``arteq.fit.crossing.surface_score``, what the fitter's own choices between starts compare).

    OMP_NUM_THREADS=1 python experiments/scan_model/torso_flip_probe.py [--bodies 4] [--fit] \
        [--templates bow,pike]
"""

from __future__ import annotations

import argparse
import functools
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent / "fitting"))

from acro_eval import BENDS, make_scans, torso_error_deg  # noqa: E402
from check_calibration import ACROBATIC  # noqa: E402


def read_turned(fitter, on: bool) -> None:
    """Make ``fitter``'s network read every cloud with its torso turned round (``ArtEqNet``'s ``turn_torso``)
    or as trained; the second start's network (``fitter.second``) is left as it is."""
    net = fitter.module.net
    if on:
        net.forward = functools.partial(type(net).forward, net, turn_torso=True)
    else:
        net.__dict__.pop("forward", None)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bodies", type=int, default=4)
    ap.add_argument("--fit", action="store_true")
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--templates", help="comma-separated subset of the probe's templates")
    a = ap.parse_args()
    from arteq.fit import Fitter
    from arteq.fit.crossing import surface_score

    torch.set_num_threads(1)
    net = Fitter(
        a.ckpt, refine=False, check=False, clean=False, second_start=False, crossing=False, anny=False
    )
    full = Fitter(a.ckpt, anny=False) if a.fit else None
    sets = {k: ACROBATIC[k] for k in ("backbend", "bow", "pike", "handstand", "tuck")}
    sets.update({k: BENDS[k] for k in ("wheel", "camel", "cobra")})
    if a.templates:
        sets = {k: v for k, v in sets.items() if k in a.templates.split(",")}
    rng = np.random.default_rng(0)
    print("| template | body | reading | part acc % | torso err deg | network V2V cm |"
          + (" fit V2V cm | fit score cm | status |" if full else ""))  # fmt: skip
    print("|---|---:|---|---:|---:|---:|" + ("---:|---:|---|" if full else ""))
    for name, t in sets.items():
        for s in make_scans(a.bodies, {name: t}, seed=9300):
            subset = rng.choice(len(s["vertices"]), 2000, replace=False)
            for flip in (False, True):
                read_turned(net, flip)
                if full is not None:
                    read_turned(full, flip)
                r = net.fit_points(s["points"])
                line = (
                    f"| {name} | {s['body']} | {'turned' if flip else 'as read'} | "
                    f"{100 * (r.point_labels == s['labels']).mean():.1f} | "
                    f"{torso_error_deg(r.global_rotmats, s['grot']):.0f} | "
                    f"{np.linalg.norm(r.vertices - s['vertices'], axis=1).mean() * 100:.2f} |"
                )
                if full is not None:
                    t0 = time.perf_counter()
                    f = full.fit_points(s["points"])
                    v2v = np.linalg.norm(f.vertices - s["vertices"], axis=1).mean() * 100
                    score = surface_score(s["points"], f.vertices, subset)
                    line += f" {v2v:.2f} | {score:.2f} | {f.status} ({time.perf_counter() - t0:.1f} s) |"
                print(line, flush=True)


if __name__ == "__main__":
    main()
