"""Which part group's start limits the worst acrobatic fits of the user suite: the pipeline's fit with one
group's global rotations replaced by the truth's (the fit's betas and translation kept), refined 60
iterations without gating (``arteq.fit.crossing.try_swaps``, no early stop, no polish); per start its
surface score (cm) / V2V (cm). ``--start truth``: instead, the whole fitter with every start's local
rotations replaced by the truth's before it refines (as experiments/fitting/start_probe.py does).

    OMP_NUM_THREADS=1 python experiments/scan_model/spine/torso/limbs/oracle_groups.py [--start truth]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[4] / "fitting"))

from arteq.body.skeleton import PARENTS  # noqa: E402

GROUPS = {
    "torso": [0, 3, 6, 9, 12, 15],
    "legs": [1, 2, 4, 5, 7, 8, 10, 11],
    "arms": [13, 14, 16, 17, 18, 19, 20, 21],
    "left_arm": [13, 16, 18, 20],
    "right_arm": [14, 17, 19, 21],
    "torso+legs": [0, 3, 6, 9, 12, 15, 1, 2, 4, 5, 7, 8, 10, 11],
    "torso+arms": [0, 3, 6, 9, 12, 15, 13, 14, 16, 17, 18, 19, 20, 21],
    "all": list(range(22)),
}
#: the suite's acrobatic scans probed, per seed (its four worst fits and two more)
SCANS = {0: ["pike", "bow", "tuck", "backbend"], 1: ["backbend", "bow", "tuck", "pike"]}


def global_of(local: np.ndarray) -> np.ndarray:
    g = [None] * 22
    for j in range(22):
        g[j] = local[j] if PARENTS[j] < 0 else g[PARENTS[j]] @ local[j]
    return np.stack(g)


def local_of(g: np.ndarray) -> np.ndarray:
    return np.stack([g[j] if PARENTS[j] < 0 else g[PARENTS[j]].T @ g[j] for j in range(22)])


def v2v_cm(a, b) -> float:
    return float(np.linalg.norm(np.asarray(a, dtype=np.float64) - b, axis=1).mean() * 100)


def main() -> None:
    import user_scans as us

    import arteq.fit.api as api
    from arteq.fit import Fitter
    from arteq.fit.crossing import CrossingConfig, surface_score, try_swaps

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--start", choices=("groups", "truth"), default="groups")
    a = ap.parse_args()
    torch.set_num_threads(1)
    fitter = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
    body, dt = fitter.body, fitter.body.v_template.dtype
    cfg = CrossingConfig(iters=60, stop_at=-1, polish_iters=0)
    truth: dict = {}
    refine = api.refine

    def refine_from_truth(body_, points, probs, starts, rc, **kw):
        starts = dict(starts)
        r = starts["local_rotmats"].clone()
        r[:] = truth["pose"].to(r.dtype)
        starts["local_rotmats"] = r
        return refine(body_, points, probs, starts, rc, **kw)

    for seed, names in SCANS.items():
        for s in us.people_scans(seed):
            if s.group != "acrobatic" or not any(w in s.name for w in names):
                continue
            pts = s.points.astype(np.float64)
            r = fitter.fit_points(s.points, name=s.name)
            line = [f"seed {seed} {s.name}: fit v2v {v2v_cm(r.vertices, s.vertices):.2f} score "
                    f"{surface_score(pts, r.vertices.astype(np.float64), fitter.subset):.3f}"]  # fmt: skip
            if a.start == "truth":
                truth["pose"] = s.pose.double()
                api.refine = refine_from_truth
                try:
                    t = fitter.fit_points(s.points, name=s.name)
                finally:
                    api.refine = refine
                line.append(f"truth score {surface_score(pts, s.vertices, fitter.subset):.3f}")
                score = surface_score(pts, t.vertices.astype(np.float64), fitter.subset)
                line.append(f"from the true pose {score:.3f}/{v2v_cm(t.vertices, s.vertices):.2f} {t.status}")
                print(" | ".join(line), flush=True)
                continue
            betas = torch.as_tensor(r.betas[None], dtype=dt)
            transl = torch.as_tensor(r.transl_m[None], dtype=dt)
            local = roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=dt))[None]
            with torch.no_grad():
                o = body(betas=betas, pose=local, transl=transl)
            fit = {"local_rotmats": local, "betas": betas, "transl": transl, "vertices": o.vertices,
                   "joints": o.joints, "global_rotmats": o.global_rotmats}  # fmt: skip
            gf, gt = o.global_rotmats[0].double().numpy(), global_of(s.pose.double().numpy())
            extra = {}
            for name, idx in GROUPS.items():
                g = gf.copy()
                g[idx] = gt[idx]
                extra[name] = local_of(g)
            p = try_swaps(body, [pts], fit, fitter.subset, [[]], fitter.refine_config, cfg, keep_all=True,
                          extra=[extra])[0]  # fmt: skip
            for k, sc in p["tried"].items():
                v = p["all_vertices"][k]
                v = v.detach().double().numpy() if torch.is_tensor(v) else v
                line.append(f"{k} {sc:.3f}/{v2v_cm(v, s.vertices):.1f}")
            print(" | ".join(line), flush=True)


if __name__ == "__main__":
    main()
