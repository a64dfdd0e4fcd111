"""Probe: what the refinement does on single-view scans from a good start (not the network's).

The start is the ground truth perturbed as in ``benchmarks/bench_fit.py --mode perturbed`` (every joint
rotated 0.15 rad about a random axis, betas +0.5 sigma, translation 3 cm off; 20 % of the part labels
random, soft labels 0.7 + 0.3 / 22), on the cached view test sets of ``run.py``. Both refinements run from
the same starts: ``full`` (model -> scan on every vertex) and ``partial`` (model -> scan on the vertices seen
from the camera direction that :func:`arteq.fit.partial.one_sidedness` estimates from the scan). If the
partial refinement reaches the goals from here, what stops the pipeline is the network's start.

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python experiments/single_view/oracle_start.py --scans 8
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import roma
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from run import SPLITS, scans  # noqa: E402


def main() -> None:
    from arteq.body.factory import create_body
    from arteq.fit.partial import one_sidedness, visibility_function
    from arteq.fit.refine import RefineConfig, refine

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=8)
    args = ap.parse_args()
    torch.set_num_threads(1)
    body = create_body({"name": "anny22"})
    data = scans(max(16, args.scans), body)  # the cached sets of run.py (16 per view)
    g = torch.Generator().manual_seed(1)
    rows = []
    for split in SPLITS:
        d = {k: v[: args.scans] for k, v in data[split].items()}
        n = args.scans
        lab = d["labels"]
        wrong = torch.rand(lab.shape, generator=g) < 0.2
        lab = torch.where(wrong, torch.randint(0, 22, lab.shape, generator=g), lab)
        probs = torch.nn.functional.one_hot(lab, 22).float() * 0.7 + 0.3 / 22
        axis = torch.nn.functional.normalize(torch.randn(n, 22, 3, generator=g), dim=-1)
        off = torch.nn.functional.normalize(torch.randn(n, 3, generator=g), dim=-1)
        init = {
            "local_rotmats": d["pose"] @ roma.rotvec_to_rotmat(axis * 0.15),
            "betas": d["betas"] + 0.5 * torch.randn(n, 10, generator=g),
            "transl": d["transl"] + 0.03 * off,
        }
        with torch.no_grad():
            gt = body(betas=d["betas"], pose=d["pose"], transl=d["transl"])
            start = body(betas=init["betas"], pose=init["local_rotmats"], transl=init["transl"])
        views = [(None, one_sidedness(p.double().numpy())[1]) for p in d["points"]]
        v2v0 = float((start.vertices - gt.vertices).norm(dim=-1).mean() * 100)
        res = {"split": split, "start_v2v_cm": v2v0}
        for arm, visible in (("full", None), ("partial", visibility_function(body.faces, views))):
            t0 = time.perf_counter()
            out = refine(body, d["points"], probs, init, RefineConfig(), m2s_visible=visible)
            res[f"{arm}_seconds"] = (time.perf_counter() - t0) / n
            res[f"{arm}_v2v_cm"] = float((out.vertices - gt.vertices).norm(dim=-1).mean() * 100)
            res[f"{arm}_mpjpe_cm"] = float((out.joints - gt.joints).norm(dim=-1).mean() * 100)
        rows.append(res)
        print(json.dumps(res))
    (HERE / "results").mkdir(exist_ok=True)
    (HERE / "results" / "oracle_start.json").write_text(json.dumps(rows, indent=1))
    print("| split | start V2V | full: V2V / MPJPE | partial: V2V / MPJPE | s per scan (full / partial) |")
    print("|---|---:|---:|---:|---:|")
    for r in rows:
        print(
            f"| {r['split'].replace('test_view_', '')} | {r['start_v2v_cm']:.2f} | {r['full_v2v_cm']:.2f} / "
            f"{r['full_mpjpe_cm']:.2f} | {r['partial_v2v_cm']:.2f} / {r['partial_mpjpe_cm']:.2f} | "
            f"{r['full_seconds']:.2f} / {r['partial_seconds']:.2f} |"
        )


if __name__ == "__main__":
    main()
