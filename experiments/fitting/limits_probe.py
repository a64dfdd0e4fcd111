"""Probe: can joint limits tell a crossed-limb fit from its uncrossed twin where the surface cannot?

    OMP_NUM_THREADS=1 python experiments/fitting/limits_probe.py [--ckpt anny_scan] [--cases reach_up,...] \
        --out limits_probe.md

Like crossing_probe.py (the user-scan suite, each fit without the crossed-limb step, then refined again from
each swapped pair and from itself), with, per start, the pose's excess over the sampler's joint limits
(arteq.data.poses.JOINT_LIMITS_DEG; degrees beyond the limits summed over axes and joints, the smaller of
the two Euler decompositions) next to the surface score and the V2V. Cells: score cm / excess deg / V2V cm.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import roma
import torch

from arteq.data.poses import joint_limit_bounds

sys.path.insert(0, str(Path(__file__).resolve().parent))


def euler_xyz_deg(rot: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """The two intrinsic XYZ Euler decompositions (``R = Rx(a) Ry(b) Rz(c)``) of ``[..., 3, 3]``, degrees
    ``[..., 3]`` each, wrapped to (-180, 180]: ``|b| <= 90`` and its twin ``(a + 180, 180 - b, c + 180)``."""
    r00, r01, r02 = rot[..., 0, 0], rot[..., 0, 1], rot[..., 0, 2]
    r12, r22 = rot[..., 1, 2], rot[..., 2, 2]
    b = torch.atan2(r02, torch.sqrt(r00 * r00 + r01 * r01))
    first = torch.stack([torch.atan2(-r12, r22), b, torch.atan2(-r01, r00)], -1)
    second = first + torch.tensor([torch.pi, 0.0, torch.pi], dtype=rot.dtype, device=rot.device)
    second[..., 1] = torch.pi - b
    wrap = lambda x: torch.remainder(x + torch.pi, 2 * torch.pi) - torch.pi  # noqa: E731
    return torch.rad2deg(wrap(first)), torch.rad2deg(wrap(second))


def limit_excess_deg(local: torch.Tensor) -> torch.Tensor:
    """Degrees beyond the joint limits per joint ``[..., 22]`` of local rotations ``[..., 22, 3, 3]``: the
    sum over the three Euler axes of the distance outside ``[lo, hi]``, the smaller of the two
    decompositions; 0 for the root (it has no limit)."""
    lo, hi = (t.to(local) for t in joint_limit_bounds())
    out = []
    for e in euler_xyz_deg(local):
        out.append((torch.relu(lo - e) + torch.relu(e - hi)).sum(-1))
    excess = torch.minimum(*out)
    excess[..., 0] = 0.0
    return excess


def main() -> None:
    from user_scans import people_scans

    from arteq.fit import Fitter
    from arteq.fit.crossing import PAIRS, CrossingConfig, surface_score, try_swaps

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--cases", default="", help="comma-separated substrings of the scan names (default: all)")
    ap.add_argument("--iters", type=int, default=CrossingConfig.iters, help="iterations from each start")
    ap.add_argument("--out", required=True, help="the Markdown table")
    a = ap.parse_args()
    cases = [c for c in a.cases.split(",") if c]
    lines = []

    def emit(text: str) -> None:
        lines.append(text)
        print(text, flush=True)
        Path(a.out).write_text("\n".join(lines) + "\n")

    torch.set_num_threads(1)
    f = Fitter(ckpt=a.ckpt, device="cpu", anny=False, check=False, crossing=False)
    body, dtype = f.body, f.body.v_template.dtype
    emit(f"{f.checkpoint_id}, user-scan suite seed {a.seed}; cells: score cm / limit excess deg / V2V cm\n")
    emit("| group | scan | fit: score / excess / V2V | none | " + " | ".join(PAIRS) + " |")
    emit("|---|---|---|---|" + "---|" * len(PAIRS))
    for s in people_scans(a.seed):
        if s.vertices is None or (cases and not any(c in s.name for c in cases)):
            continue
        r = f.fit_points(s.points, name=s.name)
        c = r.scan_points.mean(0).astype(np.float64)
        pts = r.scan_points.astype(np.float64) - c
        local = roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float64))
        fit = {
            "local_rotmats": local[None],
            "global_rotmats": torch.as_tensor(r.global_rotmats, dtype=torch.float64)[None],
            "joints": torch.as_tensor(r.joints.astype(np.float64) - c)[None],
            "vertices": torch.as_tensor(r.vertices.astype(np.float64) - c)[None],
            "betas": torch.as_tensor(r.betas, dtype=dtype)[None],
            "transl": torch.as_tensor(r.transl_m - c, dtype=dtype)[None],
        }
        every = CrossingConfig(max_score_cm=float("inf"), stop_at=-1, iters=a.iters)
        out = try_swaps(body, [pts], fit, f.subset, [list(PAIRS)], f.refine_config, every, keep_all=True)[0]
        v2v = np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100
        score = surface_score(pts, fit["vertices"][0].numpy(), f.subset)
        cells = [f"{score:.3f} / {float(limit_excess_deg(local).sum()):.0f} / {v2v:.1f}"]
        for name in ("none", *PAIRS):
            vh = out["all_vertices"][name].double().numpy() + c
            v = np.linalg.norm(vh - s.vertices, axis=1).mean() * 100
            ex = float(limit_excess_deg(out["all_local"][name].double()).sum())
            cells.append(f"{out['tried'][name]:.3f} / {ex:.0f} / {v:.1f}")
        emit(f"| {s.group} | {s.name} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
