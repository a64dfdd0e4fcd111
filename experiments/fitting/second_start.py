"""Probe: would a second start, the research model's pose, help the scan model's fits, and can the fit's
own surface score pick between the two?

    OMP_NUM_THREADS=1 python experiments/fitting/second_start.py [--seed 0] [--out FILE.json]

On the check's labelled set (``check_calibration.labelled_set``, bodies only), every scan is fitted twice
through the public pipeline on ``anny_scan``'s all-ages body, with every step on (refinement and its
searches, crossed-limb step, check):

* ``scan``: ``arteq-fit``'s default (``anny_scan``'s network);
* ``second``: the same, but started from ``anny22``'s network (the research model, adults, everyday
  motions): its local rotations and part probabilities, ``anny_scan``'s betas, the translation placed for
  that body (``estimate_translation`` with ``anny22``'s part weights).

Per scan: V2V (cm) of both, their surface scores (``arteq.fit.crossing.surface_score``, symmetric robust
Chamfer in cm) and the check's status; then what picking the lower score (by a relative margin) gives
against the oracle (the lower V2V).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default=None)
    a = ap.parse_args()
    torch.set_num_threads(1)
    from check_calibration import labelled_set

    from arteq.fit import Fitter
    from arteq.fit.crossing import surface_score
    from arteq.models.placement import estimate_translation

    research = Fitter(ckpt="anny22", device="cpu", refine=False, check=False, anny=False)

    class SecondStart(Fitter):
        """``anny_scan``'s pipeline started from ``anny22``'s pose and part probabilities."""

        @torch.no_grad()
        def _network(self, clouds):
            own = super()._network(clouds)
            other = research._network(clouds)
            x = torch.as_tensor(np.stack(clouds), dtype=torch.float32)
            posed = self.module.body(betas=own["betas"].float(), pose=other["local_rotmats"].float())
            transl = estimate_translation(
                posed.vertices, self.module.centroid_matrix, x, other["pool_weights"]
            )
            return {**own, "local_rotmats": other["local_rotmats"], "part_probs": other["part_probs"],
                    "transl": transl}  # fmt: skip

    scan = Fitter(device="cpu", anny=False, second_start=False)  # each start on its own
    second = SecondStart(device="cpu", anny=False, second_start=False)
    subset = scan.subset
    records = []
    for it in labelled_set(a.seed):
        if it.get("vertices") is None:
            continue
        row = {"group": it["group"], "name": it["name"]}
        for key, f in (("scan", scan), ("second", second)):
            t = time.perf_counter()
            r = f.fit_points(it["points"], name=it["name"])
            row[f"{key}_s"] = time.perf_counter() - t
            row[f"{key}_status"] = r.status
            row[f"{key}_v2v"] = float(np.linalg.norm(r.vertices - it["vertices"], axis=1).mean() * 100)
            pts = r.scan_points.astype(np.float64)
            row[f"{key}_score"] = surface_score(pts, r.vertices.astype(np.float64), subset)
        records.append(row)
        print(f"{row['group'][:14]:14s} {row['name']:22s} scan {row['scan_v2v']:6.2f} "
              f"({row['scan_score']:.2f}, "
              f"{row['scan_status']}) second {row['second_v2v']:6.2f} ({row['second_score']:.2f}, "
              f"{row['second_status']})", flush=True)  # fmt: skip
    v = np.array([[r["scan_v2v"], r["second_v2v"]] for r in records])
    s = np.array([[r["scan_score"], r["second_score"]] for r in records])
    print(f"\n{len(records)} bodies, seed {a.seed}: scan {v[:, 0].mean():.2f} / {np.median(v[:, 0]):.2f}, "
          f"second {v[:, 1].mean():.2f} / {np.median(v[:, 1]):.2f}, oracle {v.min(1).mean():.2f} / "
          f"{np.median(v.min(1)):.2f} (V2V mean / median cm; usable <= 3 cm: {np.sum(v[:, 0] <= 3)}, "
          f"{np.sum(v[:, 1] <= 3)}, {np.sum(v.min(1) <= 3)})")  # fmt: skip
    for margin in (0.0, 0.05, 0.1, 0.2):
        take = s[:, 1] < s[:, 0] * (1 - margin)
        picked = np.where(take, v[:, 1], v[:, 0])
        groups = {}
        for r, p in zip(records, picked):
            groups.setdefault(r["group"], []).append(p)
        per = ", ".join(f"{g} {np.mean(x):.2f}" for g, x in groups.items())
        print(f"pick the second start when its score is {margin:.0%} lower: {int(take.sum())} taken, "
              f"V2V {picked.mean():.2f} / {np.median(picked):.2f}, usable {np.sum(picked <= 3)}; {per}")
    if a.out:
        Path(a.out).write_text(json.dumps({"seed": a.seed, "records": records}, indent=1))


if __name__ == "__main__":
    main()
