"""Anny parameters and body measurements of a fit, against ground truth (issue 19, item 5).

    PYTHONPATH=src OMP_NUM_THREADS=1 python experiments/fitting/anny_measure.py [--n 20]

The inversion + measurement part alone (``arteq.fit.anny_params.AnnyExport``), given ground-truth
meshes: held-out Anny bodies (Anny's own age-aware sampler, seed 4242, ``--n`` per age band; extreme
builds from the all-ages sampler), posed with a random pose (0.3 rad per joint). Their ground truth:
Anny's anthropometry of the true phenotype in Anny's rest pose. Three inputs per body:

- ``mesh``: the true T-posed mesh itself as the fitted rest shape (the inversion alone);
- ``anny_allages``: the true mesh projected on anny_allages' 16 betas (least squares: what a perfect fit
  with that body gives), posed by the body's LBS;
- ``anny22``: the same on anny22's 10 betas (the adult body of the shipped model).

Reported per band: stature, waist, mass, BMI and age errors (mean absolute / worst), the rebuild error
of the posed fitted mesh by the stock Anny model from the exported phenotype and world bone poses (mean
over vertices, averaged; worst vertex) and from the kinematic local-ref pose, and seconds per export
(phenotype, measurements and both poses). Also, for stature and waist, the same anthropometry
applied directly to the fitted T-pose mesh (``from T-pose``) instead of Anny's rest pose of the phenotype.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import replace

import numpy as np
import roma
import torch

BANDS = {
    "2-5 y": (2.0, 5.0, False),
    "5-12 y": (5.0, 12.0, False),
    "12-18 y": (12.0, 18.0, False),
    "18-40 y": (18.0, 40.0, False),
    "40-70 y": (40.0, 70.0, False),
    "70-90 y": (70.0, 90.0, False),
    "extreme builds 18-70 y": (18.0, 70.0, True),
}


def main() -> None:
    from arteq.body import anny_allages, anny_rig, load_body_model
    from arteq.fit.anny_params import PHENOTYPE_LABELS, AnnyExport

    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=20, help="bodies per band")
    a = ap.parse_args()
    bodies = {name: load_body_model(name).double() for name in ("anny_allages", "anny22")}
    ex = AnnyExport(bodies["anny_allages"])
    model, bake, C = ex.model, ex.bake, ex.C
    spec = anny_allages.spec()
    print(f"{a.n} held-out bodies per band; errors: mean absolute / worst\n")
    print("| band | input | stature cm | stature from T-pose cm | waist cm | waist from T-pose cm | mass kg "
          "| BMI | age y | rebuild mm, mean / worst vertex | kinematic pose rebuild mm "
          "| s per export |")  # fmt: skip
    print("|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    for bi, (band, (lo, hi, extreme)) in enumerate(BANDS.items()):

        def make(m, lo=lo, hi=hi, extreme=extreme):
            return anny_allages.make_sampler(m, (lo, hi), extreme_only=extreme, extreme_fraction=0.0)

        held = anny_rig.sample_shapes(replace(spec, make_sampler=make), model, bake, a.n, seed=4242 + bi)
        V = torch.as_tensor(held["vertices"])  # T-posed, pelvis at the origin, SMPL axes
        truth = []
        for i in range(a.n):
            phen = torch.tensor([held["phenotypes"][k][i] for k in PHENOTYPE_LABELS], dtype=torch.float64)
            truth.append((phen, ex.measurements(phen), float(held["ages"][i])))
        g = torch.Generator().manual_seed(bi)
        poses = roma.rotvec_to_rotmat(0.3 * torch.randn(a.n, 22, 3, generator=g, dtype=torch.float64))
        for inp in ("mesh", "anny_allages", "anny22"):
            rows = []
            for i in range(a.n):
                phen_gt, m_gt, age_gt = truth[i]
                if inp == "mesh":
                    rest = V[i]
                    body = bodies["anny_allages"]
                else:
                    body = bodies[inp]
                    sd = body.shapedirs.reshape(-1, body.num_betas)
                    betas = torch.linalg.lstsq(sd, (V[i] - body.v_template).reshape(-1, 1)).solution[:, 0]
                    rest = body.shape(betas[None])[0][0]
                t = time.perf_counter()
                phen, _ = ex.phenotype(rest)
                m = ex.measurements(phen)
                age = ex.age_years(phen)
                sec = time.perf_counter() - t
                direct = ex.anthropometry((rest @ C)[None])
                rb = kb = (float("nan"), float("nan"))
                if inp != "mesh":
                    ex.body = body
                    with torch.no_grad():
                        posed = body(betas=betas[None], pose=poses[i][None]).vertices[0]
                    t = time.perf_counter()
                    r = ex.export(betas.numpy(), poses[i].numpy(), posed.numpy())
                    sec = time.perf_counter() - t
                    rb = (r["rebuild_mm"]["mean"], r["rebuild_mm"]["max"])
                    kb = (r["kinematic_rebuild_mm"]["mean"], r["kinematic_rebuild_mm"]["max"])
                rows.append([
                    abs(m["stature_m"] - m_gt["stature_m"]) * 100,
                    abs(float(direct["height"][0]) - m_gt["stature_m"]) * 100,
                    abs(m["waist_circumference_m"] - m_gt["waist_circumference_m"]) * 100,
                    abs(float(direct["waist_circumference"][0]) - m_gt["waist_circumference_m"]) * 100,
                    abs(m["mass_kg"] - m_gt["mass_kg"]),
                    abs(m["bmi"] - m_gt["bmi"]),
                    abs(age - age_gt),
                    rb[0], rb[1], kb[0], kb[1], sec,
                ])  # fmt: skip
            r = np.array(rows)

            def cell(j, f=".2f", r=r):
                return f"{np.mean(r[:, j]):{f}} / {np.max(r[:, j]):{f}}"

            rebuild = "-" if inp == "mesh" else f"{np.mean(r[:, 7]):.2f} / {np.max(r[:, 8]):.1f}"
            kin = "-" if inp == "mesh" else f"{np.mean(r[:, 9]):.2f} / {np.max(r[:, 10]):.1f}"
            print(f"| {band} | {inp} | {cell(0)} | {cell(1)} | {cell(2)} | {cell(3)} | {cell(4, '.1f')} | "
                  f"{cell(5, '.2f')} | {cell(6, '.1f')} | {rebuild} | {kin} | {np.median(r[:, 11]):.2f} |",
                  flush=True)  # fmt: skip
        ex.body = bodies["anny_allages"]


if __name__ == "__main__":
    main()
