"""Probe: would the crossed-limb step's swaps help single views? Each held-out single-view scan is fitted by
the default fitter; its fit is then refined again (30 ungated iterations, the partial objective: model ->
scan only on the vertices the estimated camera sees) from itself (``none``) and from every left / right
swap of :mod:`arteq.fit.crossing` (pairs and whole limbs). Per start: V2V to the truth (cm) and the
partial score (:func:`arteq.fit.partial.hypothesis_score`), so that both what a swap could gain (the best
V2V) and whether a score could find it show.

    OMP_NUM_THREADS=1 python experiments/single_view/swap_probe.py --scans 16 --splits side back \
        --out experiments/single_view/readings/swap_probe.md
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    from run import scans

    from arteq.body.skeleton import NUM_JOINTS
    from arteq.fit.api import Fitter
    from arteq.fit.crossing import CHAINS, PAIRS, swap_start
    from arteq.fit.partial import hypothesis_score, visibility_function
    from arteq.fit.refine import body_tables, refine

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scans", type=int, default=16)
    ap.add_argument("--splits", nargs="*", default=["side", "back"])
    ap.add_argument("--ckpt", default=None)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    torch.set_num_threads(1)
    fitter = Fitter(ckpt=a.ckpt, device="cpu", anny=False)
    body = fitter.body
    data = scans(a.scans, fitter.module.body)
    starts = ["none", *PAIRS, *CHAINS]
    lines = [f"{fitter.checkpoint_id}; cells: V2V cm / partial score (lower is better); **bold**: lowest score\n",
             "| view | scan | fit V2V | " + " | ".join(starts) + " | best V2V | picked by score |",
             "|---|---|---:|" + "---|" * len(starts) + "---:|---:|"]  # fmt: skip
    summary: dict[str, list] = {}
    incidence = body_tables(body, fitter.refine_config.m2s_vertices).incidence
    rc = dataclasses.replace(
        fitter.refine_config, iters=30, gate_frac=0.0, top_parts=NUM_JOINTS, swing_at=-1.0
    )
    rc.sigma_start = rc.sigma_end
    for split in a.splits:
        d = data[f"test_view_{split}"]
        for i in range(a.scans):
            res = fitter.fit_points(d["points"][i].double().numpy(), name=f"{split}_{i}")
            if res.vertices is None or res.scan_mode != "partial":
                continue
            with torch.no_grad():
                gt = fitter.module.body(betas=d["betas"][i : i + 1], pose=d["pose"][i : i + 1],
                                        transl=d["transl"][i : i + 1]).vertices[0].double().numpy()  # fmt: skip
            c = res.scan_points.mean(0).astype(np.float64)
            pts = res.scan_points.astype(np.float64) - c
            local = roma.rotvec_to_rotmat(torch.as_tensor(res.pose_aa, dtype=torch.float64)).numpy()
            joints = res.joints.astype(np.float64) - c
            locs = [
                local if s == "none" else swap_start(local, res.global_rotmats, joints, s) for s in starts
            ]
            n = len(starts)
            dtype = body.v_template.dtype
            init = {
                "local_rotmats": torch.as_tensor(np.stack(locs), dtype=dtype),
                "betas": torch.as_tensor(res.betas, dtype=dtype)[None].expand(n, -1).clone(),
                "transl": torch.as_tensor(res.transl_m - c, dtype=dtype)[None].expand(n, -1).clone(),
            }
            view = (None, res.view_dir)
            visible = visibility_function(body.faces, [view] * n, incidence)
            p = torch.as_tensor(pts, dtype=dtype)[None].expand(n, -1, -1).contiguous()
            probs = torch.ones(n, len(pts), NUM_JOINTS, dtype=dtype)
            out = refine(body, p, probs, init, rc, m2s_visible=visible)
            verts = out.vertices.detach().double().numpy()
            vis = visible(out.vertices.detach()).numpy()
            v2v = [float(np.linalg.norm(verts[k] + c - gt, axis=1).mean() * 100) for k in range(n)]
            score = [hypothesis_score(verts[k], pts, fitter.subset, vis[k], None, res.view_dir)["score"]
                     for k in range(n)]  # fmt: skip
            fit_v2v = float(np.linalg.norm(res.vertices - gt, axis=1).mean() * 100)
            pick = int(np.argmin(score))
            cells = [("**" if k == pick else "") + f"{v2v[k]:.1f} / {score[k]:.2f}" + ("**" if k == pick else "")
                     for k in range(n)]  # fmt: skip
            tail = f" | {min(v2v):.1f} | {v2v[pick]:.1f} |"
            lines.append(f"| {split} | {i} | {fit_v2v:.1f} | " + " | ".join(cells) + tail)
            summary.setdefault(split, []).append((fit_v2v, v2v[0], min(v2v), v2v[pick]))
            print(lines[-1], flush=True)
            Path(a.out).write_text("\n".join(lines) + "\n")
    lines.append("\n| view | scans | fit V2V mean | `none` | best start (oracle) | picked by the score |")
    lines.append("|---|---:|---:|---:|---:|---:|")
    for split, rows in summary.items():
        m = np.mean(rows, axis=0)
        lines.append(f"| {split} | {len(rows)} | {m[0]:.2f} | {m[1]:.2f} | {m[2]:.2f} | {m[3]:.2f} |")
    Path(a.out).write_text("\n".join(lines) + "\n")
    print("\n".join(lines[-(len(summary) + 2) :]))


if __name__ == "__main__":
    main()
