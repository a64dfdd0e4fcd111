"""Turned-torso starts for the lost acrobatic fits, tried on the first fit outside the fitter.

    OMP_NUM_THREADS=1 python experiments/scan_model/spine/torso/turn_probe.py bends plough,wheel \
        [--iters 60] [--family narrow|wide] [--stop-at 8] [--rounds 2] [--bodies 4] [--json OUT.json]

The scans of ``acro_eval.py``. Each is fitted by ``arteq-fit``'s ``Fitter`` (defaults, the torso step off);
its first fit, as the crossed-limb step leaves it, is then refined again beside every start of
:func:`arteq.fit.torso_turns.torso_starts` (``--family wide``: also the spine parts turned without the
pelvis: spine1, spine1-2, spine1-3, spine2, spine2-3, spine3) by :func:`arteq.fit.crossing.try_swaps`
(``--iters`` iterations, no score limit, ``--stop-at``), ``--rounds`` rounds from the start kept. Per scan:
the fitter's V2V (cm, with its retries), the first fit's surface score and V2V, per round what was kept, and
the last round's starts' scores and V2V.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # experiments/scan_model
sys.path.insert(0, str(HERE.parents[2] / "fitting"))

import acro_eval as ae  # noqa: E402

from arteq.body.skeleton import global_to_local  # noqa: E402
from arteq.fit import Fitter  # noqa: E402
from arteq.fit.crossing import CrossingConfig, surface_score, try_swaps  # noqa: E402
from arteq.fit.torso_turns import TURNS, torso_starts  # noqa: E402

SPINE = {"s1": (3,), "s1s2": (3, 6), "s1s3": (3, 6, 9), "s2": (6,), "s2s3": (6, 9), "s3": (9,)}


def starts(global_rot: np.ndarray, family: str) -> dict[str, np.ndarray]:
    out = torso_starts(global_rot)
    if family == "wide":
        for chain, parts in SPINE.items():
            for turn, t in TURNS.items():
                g = global_rot.copy()
                g[list(parts)] = g[list(parts)] @ t
                out[f"spine_{chain}_{turn}"] = global_to_local(torch.as_tensor(g)).numpy()
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("set", choices=list(ae.SETS))
    ap.add_argument("templates")
    ap.add_argument("--iters", type=int, default=60)
    ap.add_argument("--family", choices=("narrow", "wide"), default="narrow")
    ap.add_argument("--stop-at", type=int, default=8)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--bodies", type=int, default=4)
    ap.add_argument("--json")
    a = ap.parse_args()
    torch.set_num_threads(1)
    fitter = Fitter("anny_scan", anny=False, crossing=CrossingConfig(torso=False))
    state: dict = {}
    prepare, crossings = fitter.prepare, fitter._crossings

    def keep_centre(*args, **kw):
        item = prepare(*args, **kw)
        state.setdefault("center", item["center"])
        return item

    def probe(ref_in, probs_ref, modes, fit, conditions=None):
        res = crossings(ref_in, probs_ref, modes, fit, conditions)
        if "row" in state:  # the retries' fits: not probed
            return res
        truth = state["truth"] - state["center"]

        def measure(v: np.ndarray) -> tuple[float, float]:
            sc = surface_score(ref_in[0], v, fitter.subset)
            return round(sc, 3), round(float(np.linalg.norm(v - truth, axis=1).mean() * 100), 2)

        one = {k: v[:1].detach().clone() for k, v in fit.items()}
        cfg = dataclasses.replace(fitter.crossing, iters=a.iters, max_score_cm=math.inf, stop_at=a.stop_at)
        kept, last = [], {}
        for _ in range(a.rounds):
            cands = starts(one["global_rotmats"][0].double().numpy(), a.family)
            p = try_swaps(fitter.body, ref_in[:1], one, fitter.subset, [[]], fitter.refine_config, cfg,
                          keep_all=True, extra=[cands])[0]  # fmt: skip
            last = {k: measure(v.double().numpy()) for k, v in p["all_vertices"].items()}
            if not p["taken"]:
                break
            kept.append(p["taken"])
            for k in one:
                one[k][0] = p[k].to(one[k].dtype)
        first, after = (
            measure(fit["vertices"][0].double().numpy()),
            measure(one["vertices"][0].double().numpy()),
        )
        state["row"] = {"first": first, "kept": kept, "after": after, "last_round": last}
        return res

    fitter.prepare, fitter._crossings = keep_centre, probe
    rows = []
    for s in [s for s in ae.make_scans(a.bodies, ae.SETS[a.set]) if s["template"] in a.templates.split(",")]:
        state.clear()
        state["truth"] = s["vertices"]
        t0 = time.perf_counter()
        f = fitter.fit_points(s["points"])
        r = state["row"]
        r = {"template": s["template"], "body": s["body"],
             "fitter_v2v": round(float(np.linalg.norm(f.vertices - s["vertices"], axis=1).mean() * 100), 2),
             **r, "seconds": round(time.perf_counter() - t0, 1)}  # fmt: skip
        print(f"{r['template']} {r['body']}: fitter {r['fitter_v2v']} first (score, v2v) {r['first']} "
              f"kept {r['kept']} after {r['after']} ({r['seconds']} s)", flush=True)  # fmt: skip
        rows.append(r)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
