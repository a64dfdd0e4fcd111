"""Does the crossed-limb step keep a limb placed where the truth has it (from the fit, 30 iterations)?

    OMP_NUM_THREADS=1 python experiments/scan_model/spine/reach/crossing_oracle.py bends side_bend,camel
    OMP_NUM_THREADS=1 python experiments/scan_model/spine/reach/crossing_oracle.py acrobatic pike,bow

``oracle_probe.py``'s scans (4 bodies per template) fitted by ``Fitter`` without retries twice: as is
(``base``), and with two more starts in the crossed-limb step (``arteq.fit.crossing.try_swaps``): the fit
with both arms' (``oracle_arms``) or both legs' (``oracle_legs``) global rotations set to the truth's. One
JSON line per scan: V2V cm of each and what the step took. Run at 12ce5df (before arteq.fit.reach).
"""

import json
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parents[1]))
sys.path.insert(0, str(HERE.parents[2] / "fitting"))

import acro_eval as ae  # noqa: E402
from oracle_probe import ARMS, LEGS, to_global, to_local  # noqa: E402

import arteq.fit.api as api  # noqa: E402
import arteq.fit.crossing as cr  # noqa: E402
from arteq.fit import Fitter  # noqa: E402

torch.set_num_threads(1)
st, tpl = sys.argv[1], sys.argv[2].split(",")
scans = [s for s in ae.make_scans(4, ae.SETS[st]) if s["template"] in tpl]
truth = {}
_swap, _pairs = cr.swap_start, api.pairs_to_try


def swap(local, grot, joints, pair):
    if not pair.startswith("oracle"):
        return _swap(local, grot, joints, pair)
    g = to_global(torch.as_tensor(local)).numpy()
    idx = {"oracle_arms": ARMS, "oracle_legs": LEGS}[pair]
    g[idx] = truth["g"][idx]
    return to_local(torch.as_tensor(g)).numpy()


def pairs(joints, doubtful, config=None):
    return _pairs(joints, doubtful, config) + ORACLE


cr.swap_start, api.pairs_to_try = swap, pairs
fitter = Fitter("anny_scan", anny=False, retries=0, torso_retry=False)
for s in scans:
    truth["g"] = s["grot"]
    row = {"t": s["template"], "b": s["body"]}
    for name, orc in (("base", []), ("oracle", ["oracle_arms", "oracle_legs"])):
        ORACLE = orc
        f = fitter.fit_points(s["points"])
        row[name] = round(float(np.linalg.norm(f.vertices - s["vertices"], axis=1).mean() * 100), 2)
        row[name + "_taken"] = (f.crossing or {}).get("taken")
    print(json.dumps(row), flush=True)
