"""Probe: can a brief refinement of both starts pick between them as well as two full fits do?

    OMP_NUM_THREADS=1 python experiments/fitting/second_start_brief.py 0 0,8,16
    OMP_NUM_THREADS=1 python experiments/fitting/second_start_brief.py 1 8,12

Reads ``second_start/seed<N>.json`` (``second_start.py``: both starts fitted through the whole pipeline, their
V2V). For each body of the check's labelled set (seed N), the network's start and the second start (as
``Fitter`` builds them) are refined together for each of the given iteration counts on 2000 evenly strided
points of the scan (no searches; 0: the starts themselves), scored with ``arteq.fit.crossing.surface_score``
against the scan's 5000 points, and the lower score picks which start's full-pipeline fit counts. Prints
V2V mean / median cm (usable, <= 3 cm) without the second start (``none``), with the oracle's pick and with
each brief pick.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))


def main() -> None:
    from check_calibration import labelled_set
    from scipy.spatial import cKDTree

    from arteq.fit import Fitter
    from arteq.fit.api import resample
    from arteq.fit.crossing import surface_score
    from arteq.fit.refine import RefineConfig, refine

    torch.set_num_threads(1)
    seed, iters = int(sys.argv[1]), [int(x) for x in sys.argv[2].split(",")]
    f = Fitter(device="cpu", anny=False)
    rec = {r["name"]: r for r in json.loads((HERE / f"second_start/seed{seed}.json").read_text())["records"]}
    rows = []
    for it in labelled_set(seed):
        if it.get("vertices") is None:
            continue
        item = f.prepare(it["points"], name=it["name"])
        rng = np.random.default_rng(0)
        net_in = resample(item["centred"], f.net_points, rng)
        ref_in = resample(item["centred"], f.points, rng)
        with torch.no_grad():
            pred = f._network([net_in])
        near = [cKDTree(net_in).query(ref_in)[1]]
        probs = pred["part_probs"].float().numpy()[0][near[0]]
        sec = f._second_starts([net_in], near, pred)
        keys = ("local_rotmats", "betas", "transl")
        starts = {k: torch.cat([pred[k].float(), sec["init"][k].float()]) for k in keys}
        sub = np.arange(0, len(ref_in), len(ref_in) // 2000)[:2000]
        pts = torch.as_tensor(np.stack([ref_in[sub]] * 2), dtype=torch.float32)
        pr = torch.as_tensor(np.stack([probs[sub], sec["probs"][0][sub]]), dtype=torch.float32)
        row = [rec[it["name"]]["scan_v2v"], rec[it["name"]]["second_v2v"]]
        for k in iters:
            out = refine(f.body, pts, pr, starts, RefineConfig(iters=k, twist_at=-1, swing_at=-1))
            v = out.vertices.double().numpy()
            row += [surface_score(ref_in, v[0], f.subset), surface_score(ref_in, v[1], f.subset)]
        rows.append(row)
    v = np.array(rows)
    best = v[:, :2].min(1)
    print(f"seed {seed}: none {v[:, 0].mean():.2f} / {np.median(v[:, 0]):.2f} ({(v[:, 0] <= 3).sum()}); "
          f"oracle {best.mean():.2f} / {np.median(best):.2f} ({(best <= 3).sum()})")  # fmt: skip
    for j, k in enumerate(iters):
        take = v[:, 3 + 2 * j] < v[:, 2 + 2 * j]
        p = np.where(take, v[:, 1], v[:, 0])
        print(f"brief {k} iterations (2000 points): {int(take.sum())} taken, "
              f"{p.mean():.2f} / {np.median(p):.2f} ({(p <= 3).sum()})")  # fmt: skip


if __name__ == "__main__":
    main()
