"""Probe behind arteq.fit.crossing: every body of the user-scan suite, fitted without the crossed-limb step,
then refined again from each swapped limb pair and whole limb (and from itself), with the surface score of
each.

    OMP_NUM_THREADS=1 python experiments/fitting/crossing_probe.py [--ckpt anny_scan] [--cases reach_up] \
        --out crossing_probe.md

Per scan: the fit's V2V (cm, to the true mesh) and surface score (arteq.fit.crossing.surface_score, cm);
for ``none`` (the fit refined again) and each pair of arteq.fit.crossing.PAIRS: the gap between the pair's
two segments in the fit (cm), the score and the V2V after 30 ungated iterations from that start. It shows
what a score can and cannot tell apart; the rule of arteq.fit.crossing was chosen from it (and checked on
the check's labelled sets, which it was not chosen on: experiments/fitting/crossing.md).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from user_scans import people_scans

    from arteq.fit import Fitter
    from arteq.fit.crossing import CHAINS, PAIRS, CrossingConfig, segment_gap, surface_score, try_swaps

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="the Markdown table")
    ap.add_argument("--cases", default="", help="comma-separated substrings of the scan names to run (all)")
    a = ap.parse_args()
    lines = []

    def emit(text: str) -> None:
        lines.append(text)
        print(text, flush=True)
        Path(a.out).write_text("\n".join(lines) + "\n")

    torch.set_num_threads(1)
    f = Fitter(ckpt=a.ckpt, device="cpu", anny=False, check=False, crossing=False)
    body, dtype = f.body, f.body.v_template.dtype
    emit(f"{f.checkpoint_id}, user-scan suite seed {a.seed}; cells: gap cm / score cm / V2V cm\n")
    starts = [*PAIRS, *CHAINS]
    emit("| group | scan | V2V | score | none | " + " | ".join(starts) + " | kept |")
    emit("|---|---|---:|---:|---|" + "---|" * len(starts) + "---|")
    cases = [c for c in a.cases.split(",") if c]
    for s in people_scans(a.seed):
        if s.vertices is None or (cases and not any(c in s.name for c in cases)):
            continue
        r = f.fit_points(s.points, name=s.name)
        c = r.scan_points.mean(0).astype(np.float64)
        pts = r.scan_points.astype(np.float64) - c
        fit = {
            "local_rotmats": roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float64))[None],
            "global_rotmats": torch.as_tensor(r.global_rotmats, dtype=torch.float64)[None],
            "joints": torch.as_tensor(r.joints.astype(np.float64) - c)[None],
            "vertices": torch.as_tensor(r.vertices.astype(np.float64) - c)[None],
            "betas": torch.as_tensor(r.betas, dtype=dtype)[None],
            "transl": torch.as_tensor(r.transl_m - c, dtype=dtype)[None],
        }
        every = CrossingConfig(max_score_cm=float("inf"))  # try every fit; the rule's limit applied below
        out = try_swaps(body, [pts], fit, f.subset, [starts], f.refine_config, every, keep_all=True)[0]
        v2v = np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100
        joints = fit["joints"][0].numpy()
        cells = []
        for name in ("none", *starts):
            gap = f"{segment_gap(joints, name) * 100:.0f} / " if name in PAIRS else ""
            vh = out["all_vertices"][name].double().numpy() + c
            v = np.linalg.norm(vh - s.vertices, axis=1).mean() * 100
            cells.append(f"{gap}{out['tried'][name]:.3f} / {v:.1f}")
        taken = out["taken"] if out["score"] <= CrossingConfig().max_score_cm else ""
        v_after = v2v
        if taken:
            v_after = np.linalg.norm(out["vertices"].double().numpy() + c - s.vertices, axis=1).mean() * 100
        score = surface_score(pts, fit["vertices"][0].numpy(), f.subset)
        emit(f"| {s.group} | {s.name} | {v2v:.2f} | {score:.3f} | " + " | ".join(cells)
              + f" | {taken or '-'}, V2V {v_after:.2f} |")  # fmt: skip


if __name__ == "__main__":
    main()
