"""Shape components: what the scanned truth and the refinement's betas do to the measurements.

    OMP_NUM_THREADS=1 python experiments/fitting/shape_betas.py --truth-betas 32 [--shape-betas 32] \
        --json experiments/fitting/shape_betas/truth32_fit16.json

The user-scan suite's children and adults (experiments/fitting/user_scans.py, seed 0), scanned from the
phenotype's mesh projected on ``--truth-betas`` of anny_allages' stored components and fitted by
``Fitter(ckpt, shape_betas=...)`` with the defaults of ``arteq-fit`` (the Anny export on); per scan V2V,
stature and waist error (cm) against the true phenotype's measurements. With ``--floor``: instead, each
stated adult build's true rest mesh projected on 16, 24 and 32 components (what a perfect fit gives) and
measured through the Anny export: the shape space's own floor.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def floor() -> None:
    import user_scans as us

    from arteq.body import anny_rig, load_body_model
    from arteq.fit.anny_params import PHENOTYPE_LABELS, AnnyExport

    people = us.People()
    for nb in (16, 24, 32):
        body = load_body_model("anny_allages", num_betas=nb).double()
        ex = AnnyExport(body)
        pinv = torch.linalg.pinv(body.shapedirs.reshape(-1, nb))
        for name, phen in us.stated_builds(people, 0).items():
            kw = {k: phen[i : i + 1].double() for i, k in enumerate(PHENOTYPE_LABELS)}
            v, j = anny_rig.anny_tpose(people.ex.model, kw, people.ex.bake)
            rest = (v[0] - j[0, :1]).double()
            betas = pinv @ (rest - body.v_template).reshape(-1)
            with torch.no_grad():
                verts = body(betas=betas[None], pose=torch.eye(3, dtype=torch.float64).expand(1, 22, 3, 3))
            verts = verts.vertices[0].numpy()
            off = np.linalg.norm(verts - rest.numpy(), axis=1).mean() * 1000
            m = ex.export(betas.numpy(), np.tile(np.eye(3), (22, 1, 1)), verts)["measurements"]
            truth = people.ex.measurements(phen)
            d = {k: (m[k] - truth[k]) * 100 for k in ("stature_m", "waist_circumference_m")}
            print(f"{nb} components, {name:14s}: mesh {off:.1f} mm off, stature {d['stature_m']:+.2f} cm, "
                  f"waist {d['waist_circumference_m']:+.2f} cm", flush=True)  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--truth-betas", type=int, default=32)
    ap.add_argument("--shape-betas", type=int, default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--floor", action="store_true", help="the shape space's floor instead (see above)")
    a = ap.parse_args()
    torch.set_num_threads(1)
    if a.floor:
        floor()
        return
    from user_scans import fit_scan, people_scans

    from arteq.fit import Fitter

    f = Fitter(ckpt=a.ckpt, device="cpu", anny=True, shape_betas=a.shape_betas)
    records = []
    for s in people_scans(0, truth_betas=a.truth_betas):
        if s.group not in ("adults", "children"):
            continue
        r = fit_scan(f, s)
        records.append(r)
        print(f"{r['group']:9s} {r['name']:40s} V2V {r.get('v2v_cm', np.nan):6.2f} stature "
              f"{r.get('stature_err_cm', np.nan):+6.2f} waist {r.get('waist_err_cm', np.nan):+6.2f}",
              flush=True)  # fmt: skip
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        Path(a.json).write_text(json.dumps({"args": vars(a), "records": records}, indent=1, default=float))


if __name__ == "__main__":
    main()
