"""Probe: a fit turned front to back with left and right swapped (the "mirror" start), refined again.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/mirror_probe.py --seeds 0 1 [--groups acrobatic]

The user-scan suite's lost acrobatic fits (a bow 39 cm V2V, a pike 14 cm) put every left joint where the
right one is and the chest where the back is, with a surface score of 3-4 cm: the body read from behind.
From the fit of ``arteq.fit.Fitter`` (the defaults of ``arteq-fit``), the mirror start gives each part the
world rotation of its mirror part (left <-> right, the torso its own) turned half a turn about the rest
pose's up axis: ``R'_k = R_m(k) Ry(pi)``. Where the rest offsets lie in the body's frontal plane this puts
every joint where the other side's joint was. That start is refined like a crossed-limb swap
(:func:`arteq.fit.crossing.try_swaps`'s settings: no part gating, the final kernel width) for ``--iters``
iterations, and the fit refined again the same way (``none``) beside it. Printed per scan: the status, the
surface score (:func:`arteq.fit.crossing.surface_score`, cm) and V2V (cm, against the true mesh) of the
fit, of ``none`` and of the mirror, and the one a rule "mirror when its score is lower by ``--gain``" picks.

``--swaps NAME ...`` (scans whose name contains one of them): instead, every crossed-limb start of
:func:`arteq.fit.crossing.try_swaps` (the four pairs, both whole limbs and all four limbs at once,
:data:`arteq.fit.crossing.ALL_LIMBS`) from that fit, with no score cap and no early stop, ``--iters`` each:
each start's surface score / V2V after its refinement; and the fit's joint errors, also with its left and
right joints swapped.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS, global_to_local  # noqa: E402
from arteq.models.sides import LEFT_PARTS, RIGHT_PARTS  # noqa: E402

#: each part's mirror part (left <-> right; the trunk and head their own)
MIRROR = list(range(len(JOINT_NAMES)))
for _l, _r in zip(LEFT_PARTS, RIGHT_PARTS, strict=True):
    MIRROR[_l], MIRROR[_r] = _r, _l
RY_PI = torch.diag(torch.tensor([-1.0, 1.0, -1.0], dtype=torch.float64))


def mirror_start(global_rot: torch.Tensor) -> torch.Tensor:
    """Local rotations ``[B, 22, 3, 3]`` of the mirror start of world rotations ``[B, 22, 3, 3]``."""
    g = global_rot.double()[:, MIRROR] @ RY_PI
    return global_to_local(g)


def swap_probe(fitter, scan, r, iters_list: list[int], seed: int) -> None:
    """Every crossed-limb start from fit ``r`` of ``scan``, refined; printed as score / V2V (cm)."""
    from arteq.fit.crossing import ALL_LIMBS, CHAINS, PAIRS, CrossingConfig, try_swaps

    pts = r.scan_points.astype(np.float64) * r.scale_to_m
    c = pts.mean(0)
    dt = fitter.body.v_template.dtype
    g = torch.as_tensor(r.global_rotmats, dtype=torch.float64)[None]
    fit = {"local_rotmats": global_to_local(g).to(dt), "global_rotmats": g.to(dt),
           "joints": torch.as_tensor(r.joints * r.scale_to_m - c, dtype=dt)[None],
           "vertices": torch.as_tensor(r.vertices * r.scale_to_m - c, dtype=dt)[None],
           "betas": torch.as_tensor(r.betas, dtype=dt)[None],
           "transl": torch.as_tensor(r.transl_m - c, dtype=dt)[None]}  # fmt: skip
    v2v_fit = np.linalg.norm(r.vertices * r.scale_to_m - scan.vertices, axis=1).mean() * 100
    j = r.joints.astype(np.float64) * r.scale_to_m
    for label, jj in (("joint error cm", j), ("with left and right swapped", j[MIRROR])):
        err = np.linalg.norm(jj - scan.joints, axis=1) * 100
        print(f"seed {seed} {scan.name} {label}: " + " ".join(f"{n}:{e:.0f}" for n, e in zip(JOINT_NAMES, err)))
    for iters in iters_list:
        cfg = CrossingConfig(max_score_cm=100.0, stop_at=-1, iters=iters)
        tries = [[*PAIRS, *CHAINS, ALL_LIMBS]]
        out = try_swaps(
            fitter.body, [pts - c], fit, fitter.subset, tries, fitter.refine_config, cfg, keep_all=True
        )[0]
        row = " ".join(
            f"{k}:{out['tried'][k]:.2f}/{np.linalg.norm(v.double().numpy() + c - scan.vertices, axis=1).mean() * 100:.1f}"
            for k, v in out["all_vertices"].items()
        )
        print(f"seed {seed} {scan.name} {iters} it: fit {out['score']:.2f}/{v2v_fit:.1f} {row}", flush=True)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seeds", type=int, nargs="+", default=[0])
    ap.add_argument("--groups", nargs="+", default=["acrobatic"])
    ap.add_argument("--iters", type=int, nargs="+", default=[30])
    ap.add_argument("--gain", type=float, default=0.03)
    ap.add_argument("--json", default=None)
    ap.add_argument("--swaps", nargs="*", default=None, metavar="NAME")
    a = ap.parse_args(argv)

    from user_scans import people_scans

    from arteq.fit import Fitter
    from arteq.fit.crossing import surface_score
    from arteq.fit.refine import refine

    fitter = Fitter(anny=False, points=5000)
    body, subset = fitter.body, fitter.subset
    dtype = body.v_template.dtype
    records = []
    for seed in a.seeds:
        for scan in people_scans(seed):
            if scan.group not in a.groups or scan.vertices is None:
                continue
            if a.swaps is not None and not any(n in scan.name for n in a.swaps):
                continue
            r = fitter.fit_points(scan.points, name=scan.name)
            if r.vertices is None:
                continue
            if a.swaps is not None:
                swap_probe(fitter, scan, r, a.iters, seed)
                continue
            pts = r.scan_points.astype(np.float64) * r.scale_to_m
            c = pts.mean(0)
            pts_c = torch.as_tensor(pts - c, dtype=dtype)[None]
            grot = torch.as_tensor(r.global_rotmats, dtype=torch.float64)[None]
            starts = torch.cat([global_to_local(grot), mirror_start(grot)]).to(dtype)
            rec = {"seed": seed, "name": scan.name, "status": r.status,
                   "fit": {"score": surface_score(pts - c, r.vertices * r.scale_to_m - c, subset),
                           "v2v": float(np.linalg.norm(r.vertices * r.scale_to_m - scan.vertices, axis=1).mean()
                                        * 100)}}  # fmt: skip
            for iters in a.iters:
                rc = dataclasses.replace(fitter.refine_config, iters=iters, gate_frac=0.0, top_parts=NUM_JOINTS,
                                         swing_at=-1.0)  # fmt: skip
                rc.sigma_start = rc.sigma_end
                init = {"local_rotmats": starts,
                        "betas": torch.as_tensor(r.betas, dtype=dtype)[None].repeat(2, 1),
                        "transl": torch.as_tensor(r.transl_m - c, dtype=dtype)[None].repeat(2, 1)}  # fmt: skip
                probs = torch.ones(2, pts_c.shape[1], NUM_JOINTS, dtype=dtype)
                t0 = time.perf_counter()
                out = refine(body, pts_c.repeat(2, 1, 1), probs, init, rc)
                sec = time.perf_counter() - t0
                for k, name in enumerate(("none", "mirror")):
                    v = out.vertices[k].detach().double().numpy()
                    rec[f"{name}@{iters}"] = {
                        "score": surface_score(pts - c, v, subset),
                        "v2v": float(np.linalg.norm(v + c - scan.vertices, axis=1).mean() * 100),
                    }
                rec[f"seconds@{iters}"] = sec
            records.append(rec)
            line = f"seed {seed} {scan.name:34s} {r.status:10s} fit {rec['fit']['score']:5.2f}/{rec['fit']['v2v']:6.2f}"
            for iters in a.iters:
                n_, m_ = rec[f"none@{iters}"], rec[f"mirror@{iters}"]
                line += (f" | {iters}: none {n_['score']:5.2f}/{n_['v2v']:6.2f} mirror {m_['score']:5.2f}/"
                         f"{m_['v2v']:6.2f} {rec[f'seconds@{iters}']:.1f}s")  # fmt: skip
            print(line, flush=True)
    for iters in a.iters:
        picked, first = [], []
        for rec in records:
            m_, n_ = rec[f"mirror@{iters}"], rec[f"none@{iters}"]
            base = min(n_, rec["fit"], key=lambda d: d["score"])
            picked.append(m_["v2v"] if m_["score"] < (1 - a.gain) * base["score"] else rec["fit"]["v2v"])
            first.append(rec["fit"]["v2v"])
        print(
            f"{iters} iterations: V2V mean {np.mean(first):.2f} -> {np.mean(picked):.2f} cm "
            f"(worst {np.max(first):.2f} -> {np.max(picked):.2f}), {len(records)} scans"
        )
    if a.json:
        Path(a.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
