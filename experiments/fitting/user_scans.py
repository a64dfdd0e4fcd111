"""Scans unlike the training set, fitted by the shipped model through the public API.

    PYTHONPATH=src OMP_NUM_THREADS=1 python experiments/fitting/user_scans.py --n 6 [--no-refine]

Cases (each: ``--n`` generated bodies with known ground truth, 5000 points, 5 mm noise):
- ``upright, y up``: everyday (ID) motions, heading random about the vertical, the body's own up axis;
- ``z up`` / ``upside down`` / ``lying``: the same bodies with the up axis along +z, -y, or x;
- ``extreme builds``: betas drawn with 2.5x the training spread (|beta| up to ~6 sigma: very tall / short,
  heavy / thin), random orientation;
- ``acrobatic``: the out-of-distribution extreme poses, random orientation;
- ``millimetres, 300 m away``: the upright case written in mm and moved 300 m (``units="mm"``);
- ``10% stray points`` / ``room: floor, wall, box, 10% stray``: the upright case with the clutter of
  ``arteq.fit.demo.add_clutter`` (stray points in a 4 m box; a 2.5 m floor under the feet, a wall 0.4 m
  behind, a 0.3 m box 0.6 m beside); also reported: the mean vertex distance to the fit of the same scan
  without its clutter (``vs clean fit``) and, as the floor of that number, between two fits of the clean
  scan that differ only in the resampling seed (``clean vs clean, other seed``: the network sees another
  random subset of the points).
Reported: mean and median V2V (cm, in metres after unit conversion), MPJPE is not available for
arbitrary inputs so it is left out; the status counts (``ok`` / ``uncertain`` / ``not_single_body`` /
``error``; ``uncertain`` since the check's calibration, experiments/fitting/check_calibration.md), seconds
per scan.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def rot_about(axis: str, deg: float) -> np.ndarray:
    a = np.deg2rad(deg)
    c, s = np.cos(a), np.sin(a)
    return {
        "x": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
        "y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
        "z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]),
    }[axis]


CLUTTER = {
    "10% stray points": ("stray",),
    "room: floor, wall, box, 10% stray": ("stray", "floor", "wall", "box"),
}


def scans(body, case: str, n: int) -> list[dict]:
    from arteq.data.dataset import BodyScanDataset
    from arteq.data.poses import SyntheticIDPoses, SyntheticOODPoses

    split = "ood" if case == "acrobatic" else "id"
    src = SyntheticOODPoses() if split == "ood" else SyntheticIDPoses()
    beta_scale = 2.5 if case == "extreme builds" else 1.0
    ds = BodyScanDataset(src, body, f"user_{case}", n, seed=7, num_points=5000, noise_std=0.005,
                         augment="so3" if case in ("extreme builds", "acrobatic") else "none",
                         beta_scale=beta_scale)  # fmt: skip
    rng = np.random.default_rng(3)
    out = []
    for i in range(n):
        s = ds[i]
        with torch.no_grad():
            gt = body(betas=s["betas"][None], pose=s["pose"][None], transl=s["transl"][None])
        verts, pts = gt.vertices[0].double().numpy(), s["points"].double().numpy()
        r = rot_about("y", rng.uniform(0, 360))  # heading about the body's up axis (+y)
        r = {"z up": rot_about("x", 90), "upside down": rot_about("z", 180), "lying": rot_about("z", 90)}.get(
            case, np.eye(3)
        ) @ r
        off = rng.uniform(-2, 2, 3)
        if case == "millimetres, 300 m away":
            off = off + np.array([300.0, 0.0, -120.0])
        verts, pts = verts @ r.T + off, pts @ r.T + off
        item = {"points": pts, "vertices": verts, "betas": s["betas"].numpy()}
        if case in CLUTTER:
            from arteq.fit.demo import add_clutter

            item["clean_points"] = pts
            up = r @ np.array([0.0, 1.0, 0.0])
            item["points"], _ = add_clutter(pts, verts, body.faces.numpy(), up, CLUTTER[case], seed=i)
        out.append(item)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=6)
    ap.add_argument("--ckpt", default="anny22")
    ap.add_argument("--no-refine", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--cases", default="", help="comma-separated substrings of the case names to run")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    from arteq.fit.api import Fitter

    # the Anny export is timed apart (experiments/fitting/anny_measure.py): off here
    fitter = Fitter(ckpt=a.ckpt, device="cpu", refine=not a.no_refine, points=5000, check=True, anny=False)
    body = fitter.body
    cases = ["upright, y up", "z up", "upside down", "lying", "extreme builds", "acrobatic",
             "millimetres, 300 m away", *CLUTTER]  # fmt: skip
    if a.cases:
        cases = [c for c in cases if any(k in c for k in a.cases.split(","))]
    print(f"checkpoint {fitter.checkpoint_id}, refine={not a.no_refine}, {a.n} scans per case\n")
    print("| case | V2V cm mean | V2V cm median | max | ok / uncertain / not_single_body / error "
          "| s per scan | vs clean fit cm, mean / max | clean vs clean, other seed |")  # fmt: skip
    print("|---|---:|---:|---:|---|---:|---:|---:|")
    other = None
    for case in cases:
        errs, secs, vs_clean, spread = [], [], [], []
        status = {"ok": 0, "uncertain": 0, "not_single_body": 0, "error": 0}
        for s in scans(body, case, a.n):
            mm = case.startswith("millimetres")
            t = time.perf_counter()
            r = fitter.fit_points(s["points"] * (1000.0 if mm else 1.0), units="mm" if mm else "m")
            secs.append(time.perf_counter() - t)
            status[r.status] = status.get(r.status, 0) + 1
            if r.vertices is not None:
                v = r.vertices / (1000.0 if mm else 1.0)
                errs.append(float(np.linalg.norm(v - s["vertices"], axis=1).mean() * 100))
            if "clean_points" in s and r.vertices is not None:
                c = fitter.fit_points(s["clean_points"])
                if c.vertices is not None:
                    vs_clean.append(float(np.linalg.norm(r.vertices - c.vertices, axis=1).mean() * 100))
                    if other is None:
                        other = Fitter(ckpt=a.ckpt, device="cpu", refine=not a.no_refine, points=5000, seed=1,
                                       anny=False)
                    c2 = other.fit_points(s["clean_points"])
                    spread.append(float(np.linalg.norm(c2.vertices - c.vertices, axis=1).mean() * 100))
        e = np.array(errs) if errs else np.array([np.nan])
        print(f"| {case} | {e.mean():.2f} | {np.median(e):.2f} | {e.max():.2f} | "
              f"{status['ok']} / {status['uncertain']} / {status['not_single_body']} / {status['error']} | "
              f"{np.median(secs):.2f} | "
              + (f"{np.mean(vs_clean):.2f} / {np.max(vs_clean):.2f} | " if vs_clean else "- | ")
              + (f"{np.mean(spread):.2f} / {np.max(spread):.2f} |" if spread else "- |"),
              flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
