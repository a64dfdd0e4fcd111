"""Oracle starts for the lost acrobatic fits: which part of the refinement's start decides its basin.

    OMP_NUM_THREADS=1 python experiments/scan_model/spine/reach/oracle_probe.py --set bends \
        [--templates side_bend,camel] [--bodies 4] [--arms pipeline,true,torso,limbs] [--json OUT.json]

The scans of ``acro_eval.py`` (``--bodies`` bodies per template, the same generator) through ``arteq-fit``'s
``Fitter`` (defaults, but no retries: the first fit's refinement is what is probed), with every start the
refinement gets changed before it refines (``arteq.fit.api.refine`` wrapped):

- ``pipeline``: unchanged;
- ``true``: every part's global rotation the truth's (shape and translation the network's);
- ``torso``: the pelvis and the three spine parts the truth's, every other part its own global rotation;
- ``limbs``: every part but those four the truth's; ``arms`` (collars, shoulders, elbows, wrists) and
  ``legs`` (hips, knees, ankles, feet) the truth's alone.

Per scan and start: ``[V2V cm, surface score cm, seconds]`` of the fit (the surface score:
``arteq.fit.crossing.surface_score``, what the fitter's choices compare); for ``pipeline`` also the parts
whose vertices lie more than 5 cm off the truth (mean, cm).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1]))  # experiments/scan_model
sys.path.insert(0, str(HERE.parents[2] / "fitting"))

import acro_eval as ae  # noqa: E402

import arteq.fit.api as api  # noqa: E402
from arteq.body.skeleton import JOINT_NAMES, PARENTS  # noqa: E402
from arteq.fit import Fitter  # noqa: E402
from arteq.fit.crossing import surface_score  # noqa: E402

TORSO = [0, 3, 6, 9]
ARMS = [13, 14, 16, 17, 18, 19, 20, 21]
LEGS = [1, 2, 4, 5, 7, 8, 10, 11]


def to_local(g):
    loc = g.clone()
    for j in range(1, g.shape[-3]):
        loc[..., j, :, :] = g[..., PARENTS[j], :, :].transpose(-1, -2) @ g[..., j, :, :]
    return loc


def to_global(loc):
    g = loc.clone()
    for j in range(1, loc.shape[-3]):
        g[..., j, :, :] = g[..., PARENTS[j], :, :] @ loc[..., j, :, :]
    return g


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--set", default="bends")
    ap.add_argument("--templates")
    ap.add_argument("--bodies", type=int, default=4)
    ap.add_argument("--arms", default="pipeline,true,torso,limbs")
    ap.add_argument("--json")
    a = ap.parse_args()
    torch.set_num_threads(1)
    templates = ae.SETS[a.set]
    scans = ae.make_scans(a.bodies, templates)
    if a.templates:
        keep = a.templates.split(",")
        scans = [s for s in scans if s["template"] in keep]
    fitter = Fitter("anny_scan", anny=False, retries=0, torso_retry=False)
    subset = fitter.subset
    part_of = fitter.body.part_labels.cpu().numpy()
    truth = {}
    arm = {"name": "pipeline"}
    refine = api.refine

    def refine_from(body_, points, probs, starts, cfg, **kw):
        if arm["name"] != "pipeline":
            starts = dict(starts)
            loc = starts["local_rotmats"].clone()
            g = to_global(loc)
            tg = torch.as_tensor(truth["g"], dtype=loc.dtype)
            if arm["name"] == "true":
                g[:] = tg
            elif arm["name"] == "torso":
                g[:, TORSO] = tg[TORSO]
            elif arm["name"] in ("arms", "legs"):
                idx = ARMS if arm["name"] == "arms" else LEGS
                g[:, idx] = tg[idx]
            elif arm["name"] == "limbs":
                rest = [j for j in range(22) if j not in TORSO]
                g[:, rest] = tg[rest]
            starts["local_rotmats"] = to_local(g)
        return refine(body_, points, probs, starts, cfg, **kw)

    api.refine = refine_from
    rows = []
    for s in scans:
        truth["g"] = s["grot"]
        row = {"template": s["template"], "body": s["body"], "age": s["age"]}
        for name in a.arms.split(","):
            arm["name"] = name
            t = time.perf_counter()
            f = fitter.fit_points(s["points"])
            v2v = float(np.linalg.norm(f.vertices - s["vertices"], axis=1).mean() * 100)
            c = f.vertices.mean(0)
            sc = surface_score(s["points"] - c, f.vertices - c, subset)
            row[name] = (round(v2v, 2), round(sc, 3), round(time.perf_counter() - t, 1))
            if name == "pipeline":
                err = np.linalg.norm(f.vertices - s["vertices"], axis=1) * 100
                row["parts"] = {
                    JOINT_NAMES[k]: round(float(err[part_of == k].mean()), 1)
                    for k in range(22)
                    if err[part_of == k].mean() > 5
                }
        rows.append(row)
        print(json.dumps(row), flush=True)
    if a.json:
        Path(a.json).write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
