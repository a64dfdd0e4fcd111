"""Scans as real scanners make them: the same bodies with one defect each, fitted through the public API.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/scan_defects.py [--ckpt anny_scan] \
        [--bodies 8] [--out experiments/fitting/scan_defects.md] [--json ...]

The user-scan suite (``user_scans.py``) draws clean, complete surfaces: 5000 points, 5 mm noise. Scanners
give other clouds. Each body here (children 3-12 y and adults 18-70 y from anny's own sampler, everyday
templates, a scanner's frame: z up, any heading, 2 m off the origin; the ``user_scans.People`` ground
truth) is scanned once clean and once with each defect, all by this file's own sampler
(``user_scans.surface_scan``, 5 mm noise unless said):

- ``dense``: 200 000 points (a structured-light or photogrammetry cloud; the fitter resamples it);
- ``sparse``: 1000 points (a quick or distant scan);
- ``noisy``: 15 mm noise (a cheap depth sensor at range);
- ``no_soles``: the points within 3 cm of the lowest point removed (feet on a floor, soles unseen), the
  floor under the body added (a 2 x 2 m patch);
- ``no_crown``: the points within 8 cm of the highest point removed (the top of the head unseen);
- ``holes``: 8 holes, every point within 10 cm of 8 random surface points removed (occlusions, dark
  clothing);
- ``one_side``: the points whose outward normal faces away from a random horizontal direction kept with
  probability 0.15 (one side scanned densely, the other in passing);
- ``seat``: a 45 cm box under the hips touching the body from below, and the floor (a person on a stool);
  applied to every body, whatever its pose;
- ``clothed``: everyday fitted clothes, a T-shirt (trunk, collars, upper arms) 1.0 cm and trousers (pelvis,
  thighs, shins) 0.8 cm off the skin, each with folds of +-0.6 cm (:func:`garment_offsets`); the surface
  is moved out along its normals by that much before it is scanned; head, forearms, hands and feet bare;
- ``loose``: a sweatshirt (also the forearms) 2.5 +- 1.2 cm and sweatpants 2.0 +- 1.0 cm off the skin.

The truth stays the body under the clothes: what clothing does to V2V and (``--anny``) to stature and waist
is what these two rows measure.

Per body and defect: the status, the V2V (mean vertex distance to the true mesh) and the distance of the fit
to the clean scan's fit (mean vertex distance). Summary per defect: V2V mean / worst, how many bodies are
usable (V2V <= 3 cm), and the mean change from the clean scan.
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

DEFECTS = ("clean", "dense", "sparse", "noisy", "no_soles", "no_crown", "holes", "one_side", "seat", "clothed",
           "loose")  # fmt: skip
#: garments by body part (``arteq.body.skeleton.JOINT_NAMES``: a part is the vertices its joint drives most):
#: ``(parts, base cm, folds cm)`` per garment
GARMENTS = {
    "clothed": (
        (("spine1", "spine2", "spine3", "left_collar", "right_collar", "left_shoulder", "right_shoulder"), 1.0, 0.6),
        (("pelvis", "left_hip", "right_hip", "left_knee", "right_knee"), 0.8, 0.6),
    ),
    "loose": (
        (("spine1", "spine2", "spine3", "left_collar", "right_collar", "left_shoulder", "right_shoulder",
          "left_elbow", "right_elbow"), 2.5, 1.2),
        (("pelvis", "left_hip", "right_hip", "left_knee", "right_knee"), 2.0, 1.0),
    ),
}  # fmt: skip


def _normals(verts: np.ndarray, faces: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Outward normals at ``pts`` (those of the nearest vertex)."""
    from scipy.spatial import cKDTree

    from arteq.geometry.normals import vertex_normals

    vn = vertex_normals(torch.as_tensor(verts)[None], torch.as_tensor(faces))[0].numpy()
    return vn[cKDTree(verts).query(pts)[1]]


def _floor(verts: np.ndarray, up: np.ndarray, rng: np.random.Generator, size: float = 2.0) -> np.ndarray:
    h1 = np.cross(up, np.eye(3)[np.argmin(np.abs(up))])
    h1 /= np.linalg.norm(h1)
    h2 = np.cross(up, h1)
    c = verts.mean(0)
    low = float(((verts - c) @ up).min())
    s = rng.uniform(-0.5, 0.5, (int(300 * size * size), 2)) * size
    return c + (low - 0.005) * up + s[:, :1] * h1 + s[:, 1:] * h2 + rng.normal(0, 0.005, (len(s), 3))


def _box(lo: np.ndarray, hi: np.ndarray, frame: np.ndarray, origin: np.ndarray, per_m2: float,
         rng: np.random.Generator) -> np.ndarray:  # fmt: skip
    """Points on the surface of an axis-aligned box ``[lo, hi]`` of ``frame`` (rows: axes) at ``origin``."""
    out = []
    for ax in range(3):
        a, b = [k for k in range(3) if k != ax]
        area = (hi[a] - lo[a]) * (hi[b] - lo[b])
        for side in (lo[ax], hi[ax]):
            n = int(per_m2 * area)
            p = np.empty((n, 3))
            p[:, ax] = side
            p[:, a] = rng.uniform(lo[a], hi[a], n)
            p[:, b] = rng.uniform(lo[b], hi[b], n)
            out.append(p)
    p = np.concatenate(out)
    return origin + p @ frame + rng.normal(0, 0.005, p.shape)


def garment_offsets(kind: str, verts: np.ndarray, labels: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``[V]`` metres between skin and cloth for the garments of :data:`GARMENTS` ``[kind]``: per garment its
    base plus folds, a sum of four plane waves over the posed vertices (wavelengths 8-25 cm, random
    directions), scaled to +-folds; never below 2 mm; 0 on bare parts."""
    from arteq.body.skeleton import JOINT_NAMES

    out = np.zeros(len(verts))
    for parts, base, folds in GARMENTS[kind]:
        on = np.isin(labels, [JOINT_NAMES.index(p) for p in parts])
        k = rng.normal(size=(4, 3))
        k *= (2 * np.pi / rng.uniform(0.08, 0.25, 4) / np.linalg.norm(k, axis=1))[:, None]
        wave = np.sin(verts[on] @ k.T + rng.uniform(0, 2 * np.pi, 4)).sum(1)
        wave /= max(float(np.abs(wave).max()), 1e-9)
        out[on] = np.maximum(base + folds * wave, 0.2) / 100.0
    return out


def defect_scan(kind: str, verts: np.ndarray, joints: np.ndarray, faces: np.ndarray, up: np.ndarray,
                rng: np.random.Generator, labels: np.ndarray | None = None) -> np.ndarray:  # fmt: skip
    """The scan of a posed body (``verts``, ``joints``, metres; ``up`` the scanner's up) with one defect
    (``labels``: the body's ``part_labels``, for the garments)."""
    from user_scans import surface_scan

    if kind in GARMENTS:
        if labels is None:
            raise ValueError(f"defect {kind!r} needs the body's part labels")
        from arteq.geometry.normals import vertex_normals

        vn = vertex_normals(torch.as_tensor(verts)[None], torch.as_tensor(faces))[0].numpy()
        return surface_scan(verts + vn * garment_offsets(kind, verts, labels, rng)[:, None], faces, 5000, rng)
    if kind == "dense":
        return surface_scan(verts, faces, 200_000, rng)
    if kind == "sparse":
        return surface_scan(verts, faces, 1000, rng)
    if kind == "noisy":
        return surface_scan(verts, faces, 5000, rng, noise=0.015)
    pts = surface_scan(verts, faces, 5000, rng)
    h = pts @ up
    if kind == "clean":
        return pts
    if kind == "no_soles":
        return np.concatenate([pts[h > h.min() + 0.03], _floor(verts, up, rng)])
    if kind == "no_crown":
        return pts[h < h.max() - 0.08]
    if kind == "holes":
        centres = pts[rng.choice(len(pts), 8, replace=False)]
        far = np.linalg.norm(pts[:, None] - centres[None], axis=-1).min(1) > 0.10
        return pts[far]
    if kind == "one_side":
        d = np.cross(up, rng.normal(size=3))
        d /= np.linalg.norm(d)
        facing = _normals(verts, faces, pts) @ d > 0
        return pts[facing | (rng.random(len(pts)) < 0.15)]
    if kind == "seat":
        h1 = np.cross(up, np.eye(3)[np.argmin(np.abs(up))])
        h1 /= np.linalg.norm(h1)
        frame = np.stack([h1, np.cross(up, h1), up])  # rows: box axes
        pelvis = joints[0]
        rel = (verts - pelvis) @ frame.T
        near = np.linalg.norm(rel[:, :2], axis=1) < 0.2
        top = float(rel[near, 2].min()) if near.any() else -0.1  # the body's lowest point over the seat
        bottom = float(rel[:, 2].min())
        if top - bottom < 0.1:  # the hips are near the floor (a squat, a sitting child): a low box
            bottom = top - 0.1
        lo = np.array([-0.225, -0.225, bottom])
        hi = np.array([0.225, 0.225, top - 0.003])
        box = _box(lo, hi, frame, pelvis, 1500.0, rng)
        return np.concatenate([pts, box, _floor(verts, up, rng)])
    raise ValueError(f"unknown defect {kind!r}")


def main() -> None:
    from user_scans import EVERYDAY, People, measurement_errors, pose_from_template, z_up_heading

    from arteq.fit import Fitter

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--bodies", type=int, default=8, help="half children, half adults")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--defects", default=",".join(DEFECTS))
    ap.add_argument("--out", default=None, help="the Markdown tables")
    ap.add_argument("--json", default=None, help="every fit's record")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="RefineConfig fields")
    ap.add_argument("--clean", nargs="*", default=[], metavar="KEY=VALUE", help="CleanConfig fields")
    ap.add_argument("--crossing", nargs="*", default=[], metavar="KEY=VALUE", help="CrossingConfig fields")
    ap.add_argument("--net-draws", type=int, default=None, help="Fitter(net_draws=...) (default: the Fitter's)")
    ap.add_argument("--anny", action="store_true", help="also the Anny export: stature and waist against the truth")
    ap.add_argument("--clothing", type=float, default=None, help="Fitter(clothing=CM): the skin under CM of cloth")
    ap.add_argument("--clothing-iters", type=int, default=None, help="ClothingConfig.iters (default: its own)")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    defects = [d for d in a.defects.split(",") if d]
    if "clean" not in defects:
        defects = ["clean", *defects]
    t0 = time.time()
    people = People()
    faces = people.faces
    labels = people.body.part_labels.numpy()
    from arteq.fit.clean import CleanConfig
    from arteq.fit.clothing import ClothingConfig
    from arteq.fit.crossing import CrossingConfig

    clothing = None
    if a.clothing is not None:
        clothing = ClothingConfig(a.clothing, **({"iters": a.clothing_iters} if a.clothing_iters else {}))
    from arteq.fit.refine import RefineConfig

    fitter = Fitter(ckpt=a.ckpt, device="cpu", anny=a.anny, refine_config=RefineConfig.from_strings(a.set),
                    net_draws=a.net_draws, clean_config=CleanConfig.from_strings(a.clean), clothing=clothing,
                    crossing=CrossingConfig.from_strings(a.crossing))
    kids = a.bodies // 2
    phens = people.sample(kids, (3.0, 12.0), 9100 + a.seed)
    phens += people.sample(a.bodies - kids, (18.0, 70.0), 9200 + a.seed)
    poses = list(EVERYDAY)
    rng = np.random.default_rng(9300 + a.seed)
    records = []
    for k, phen in enumerate(phens):
        p = people.person(phen)
        pose_name = poses[k % len(poses)]
        rot = z_up_heading(rng)
        v, j = people.posed(p, pose_from_template(EVERYDAY[pose_name], rng), rot, rng.uniform(-2, 2, 3))
        up = rot @ np.array([0.0, 1.0, 0.0])
        who = f"{'child' if k < kids else 'adult'} {p['age_years']:.0f} y, {pose_name}"
        clean_fit = None
        for kind in defects:
            pts = defect_scan(kind, v, j, faces, up, np.random.default_rng([a.seed, k, DEFECTS.index(kind)]),
                              labels=labels)
            r = fitter.fit_points(pts, name=f"{who}: {kind}")
            rec = {"body": who, "defect": kind, "points": len(pts), "status": r.status,
                   "reason": r.uncertain_reason or r.message, "fit_s": r.timings.get("total"),
                   "clothing_s": r.timings.get("clothing")}  # fmt: skip
            rec.update({k: (r.quality or {}).get(k) for k in ("inlier_frac", "coverage", "surface_ratio",
                                                              "off_group_frac", "off_group_cm")})
            if r.vertices is not None:
                rec["v2v_cm"] = float(np.linalg.norm(r.vertices - v, axis=1).mean() * 100)
                if kind == "clean":
                    clean_fit = r.vertices
                elif clean_fit is not None:
                    rec["vs_clean_cm"] = float(np.linalg.norm(r.vertices - clean_fit, axis=1).mean() * 100)
            if r.anny:
                rec.update(measurement_errors(r.anny, p))
            records.append(rec)
            print(f"{who:28s} {kind:9s} {r.status:16s} V2V {rec.get('v2v_cm', float('nan')):6.2f} "
                  f"vs clean {rec.get('vs_clean_cm', float('nan')):6.2f} {rec['reason'] or ''}", flush=True)  # fmt: skip
    lines = [f"# Scan defects: {fitter.checkpoint_id}\n",
             "Written by `experiments/fitting/scan_defects.py` (scans, defects and columns: its docstring):\n",
             "```", f"OMP_NUM_THREADS={a.threads} python experiments/fitting/scan_defects.py --ckpt {a.ckpt} "
             f"--bodies {a.bodies} --seed {a.seed} --threads {a.threads}"
             + (f" --out {a.out}" if a.out else "") + (f" --json {a.json}" if a.json else "")
             + (f" --set {' '.join(a.set)}" if a.set else "")
             + (f" --defects {a.defects}" if a.defects != ",".join(DEFECTS) else "")
             + (f" --net-draws {a.net_draws}" if a.net_draws is not None else "")
             + (f" --clean {' '.join(a.clean)}" if a.clean else "")
             + (f" --crossing {' '.join(a.crossing)}" if a.crossing else "") + (" --anny" if a.anny else "")
             + (f" --clothing {a.clothing:g}" if a.clothing is not None else "")
             + (f" --clothing-iters {a.clothing_iters}" if a.clothing_iters else ""), "```\n",
             f"{a.bodies} bodies ({kids} children 3-12 y, {a.bodies - kids} adults 18-70 y), "
             f"{time.time() - t0:.0f} s in all; V2V usable at <= 3 cm.\n",
             "| defect | points | written (ok / uncertain) | refused | V2V mean / worst cm | usable | "
             "from the clean fit, mean / worst cm |" + (" stature err mean / worst cm | waist err mean / worst cm |"
                                                         if a.anny else ""),
             "|---|---:|---|---:|---|---:|---|" + ("---|---|" if a.anny else "")]  # fmt: skip
    for kind in defects:
        rs = [r for r in records if r["defect"] == kind]
        ok = sum(r["status"] == "ok" for r in rs)
        unc = sum(r["status"] == "uncertain" for r in rs)
        v = [r["v2v_cm"] for r in rs if "v2v_cm" in r]
        c = [r["vs_clean_cm"] for r in rs if "vs_clean_cm" in r]
        pts = int(np.median([r["points"] for r in rs]))
        vtxt = f"{np.mean(v):.2f} / {np.max(v):.2f}" if v else "-"
        ctxt = f"{np.mean(c):.2f} / {np.max(c):.2f}" if c else "-"
        usable = sum(x <= 3.0 for x in v)
        row = f"| {kind} | {pts} | {ok} / {unc} | {len(rs) - ok - unc} | {vtxt} | {usable} of {len(rs)} | {ctxt} |"
        if a.anny:
            for key in ("stature_err_cm", "waist_err_cm"):
                e = [r[key] for r in rs if key in r]
                worst = max(e, key=abs) if e else None
                row += f" {np.mean(e):+.2f} / {worst:+.2f} |" if e else " - |"
        lines.append(row)
    lines += ["", "| body | " + " | ".join(defects) + " |", "|---|" + "---:|" * len(defects)]
    for who in dict.fromkeys(r["body"] for r in records):
        cells = []
        for kind in defects:
            r = next(x for x in records if x["body"] == who and x["defect"] == kind)
            mark = {"ok": "", "uncertain": " (u)"}.get(r["status"], f" ({r['status']})")
            cells.append(f"{r['v2v_cm']:.2f}{mark}" if "v2v_cm" in r else r["status"])
        lines.append(f"| {who} | " + " | ".join(cells) + " |")
    lines.append("\nCells: V2V cm; (u): written as uncertain; a status alone: nothing written.")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.out:
        Path(a.out).write_text(text)
    if a.json:
        Path(a.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
