"""Single views of dressed people: one depth camera's scan of a body in clothes, fitted as it is and with
``Fitter(clothing=T)`` (``arteq-fit --clothing T``).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/clothing_probe.py [--bodies 8] [--seed 0] \
        [--defect clothed|loose] [--clothing 1.0] [--views front side back] [--json OUT.json]

Bodies, poses and garments as ``experiments/fitting/scan_defects.py`` (the ``user_scans.People`` truth,
4 children 3-12 y and 4 adults 18-70 y from anny's sampler, everyday templates; ``garment_offsets``); each
dressed body is scanned by ``arteq.data.single_view.single_view_scan`` from each view (the simulator's
defaults: noise, missing pixels, edge effects) and fitted twice. Printed per view: V2V to the skin (cm),
stature and waist error of the Anny export (cm), both arms.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "fitting"))


def main() -> None:
    from scan_defects import garment_offsets
    from user_scans import EVERYDAY, People, measurement_errors, pose_from_template

    from arteq.data.single_view import single_view_scan
    from arteq.fit import Fitter
    from arteq.geometry.normals import vertex_normals

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--bodies", type=int, default=8)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--defect", default="clothed", choices=("clothed", "loose"))
    ap.add_argument("--clothing", type=float, default=1.0)
    ap.add_argument("--views", nargs="+", default=["front", "side", "back"])
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    people = People()
    body = people.body
    labels = body.part_labels.numpy()
    arms = {"as_is": Fitter(ckpt=a.ckpt, device="cpu", anny=True),
            f"clothing_{a.clothing:g}": Fitter(ckpt=a.ckpt, device="cpu", anny=True, clothing=a.clothing)}  # fmt: skip
    kids = a.bodies // 2
    phens = people.sample(kids, (3.0, 12.0), 9100 + a.seed) + people.sample(
        a.bodies - kids, (18.0, 70.0), 9200 + a.seed
    )
    rng = np.random.default_rng(9300 + a.seed)
    records = []
    for k, phen in enumerate(phens):
        p = people.person(phen)
        pose_name = list(EVERYDAY)[k % len(EVERYDAY)]
        with torch.no_grad():
            out = body(betas=p["betas"][None], pose=pose_from_template(EVERYDAY[pose_name], rng)[None])
        v = out.vertices[0].numpy()
        vn = vertex_normals(out.vertices, body.faces)[0].numpy()
        dressed = v + vn * garment_offsets(a.defect, v, labels, np.random.default_rng([a.seed, k, 99]))[:, None]
        who = f"{'child' if k < kids else 'adult'} {p['age_years']:.0f} y, {pose_name}"
        for j, view in enumerate(a.views):
            g = torch.Generator().manual_seed(1000 * a.seed + 10 * k + j)
            scan = single_view_scan(torch.as_tensor(dressed), body.faces, body.lbs_weights, out.joints[0, 0],
                                    out.global_rotmats[0, 0], 5000, g, view=view)  # fmt: skip
            pts = scan["points"].numpy()
            for arm, fitter in arms.items():
                r = fitter.fit_points(pts, name=f"{who} {view}")
                rec = {"body": who, "view": view, "arm": arm, "status": r.status, "mode": r.scan_mode}
                if r.vertices is not None:
                    rec["v2v_cm"] = float(np.linalg.norm(r.vertices - v, axis=1).mean() * 100)
                if r.anny:
                    rec.update(measurement_errors(r.anny, p))
                records.append(rec)
                print(json.dumps(rec), flush=True)
    print(f"\n{a.defect} scans, {a.bodies} bodies, seed {a.seed}; mean V2V / stature err / waist err (cm):")
    for view in a.views:
        for arm in arms:
            rs = [r for r in records if r["view"] == view and r["arm"] == arm and "v2v_cm" in r]
            ws = [r["waist_err_cm"] for r in rs if "waist_err_cm" in r]
            ss = [r["stature_err_cm"] for r in rs if "stature_err_cm" in r]
            print(f"  {view:6s} {arm:14s} V2V {np.mean([r['v2v_cm'] for r in rs]):5.2f}  "
                  f"stature {np.mean(ss):+6.2f}  waist {np.mean(ws):+6.2f} (worst {max(ws, key=abs):+6.2f})  "
                  f"partial {sum(r['mode'] == 'partial' for r in rs)} of {len(rs)}")  # fmt: skip
    if a.json:
        Path(a.json).write_text(json.dumps(records, indent=1))


if __name__ == "__main__":
    main()
