"""The measurement floor of the all-ages body's shape space for the user-scan suite's stated adult builds:
each true phenotype's T-posed Anny mesh projected on ``anny_allages``' first ``--betas`` components (what a
perfect fit gives), then measured through the Anny export as a fit is; stature and waist error against the
true phenotype's, and the projected mesh's mean distance to the true one.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/measure_floor.py [--betas 16 24 32] 2>/dev/null \
        | grep cm > experiments/fitting/shape_betas/floor.txt
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    import user_scans as us

    from arteq.body import anny_rig, load_body_model
    from arteq.fit.anny_params import PHENOTYPE_LABELS, AnnyExport

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--betas", type=int, nargs="+", default=[16], help="component counts (16: the model's)")
    a = ap.parse_args()
    people = us.People()
    for nb in a.betas:
        body = load_body_model("anny_allages", num_betas=nb).double()
        ex = AnnyExport(body)
        pinv = torch.linalg.pinv(body.shapedirs.reshape(-1, nb))
        rest_pose = torch.eye(3, dtype=torch.float64).expand(1, 22, 3, 3)
        for name, phen in us.stated_builds(people, 0).items():
            kw = {k: phen[i : i + 1].double() for i, k in enumerate(PHENOTYPE_LABELS)}
            v, j = anny_rig.anny_tpose(people.ex.model, kw, people.ex.bake)
            rest = (v[0] - j[0, :1]).double()  # pelvis at the origin, as the body's samples
            betas = pinv @ (rest - body.v_template).reshape(-1)
            with torch.no_grad():
                verts = body(betas=betas[None], pose=rest_pose).vertices[0].numpy()
            off = np.linalg.norm(verts - rest.numpy(), axis=1).mean() * 1000
            m = ex.export(betas.numpy(), np.tile(np.eye(3), (22, 1, 1)), verts)["measurements"]
            truth = people.ex.measurements(phen)
            stature = (m["stature_m"] - truth["stature_m"]) * 100
            waist = (m["waist_circumference_m"] - truth["waist_circumference_m"]) * 100
            print(f"{nb} components, {name:14s}: mesh {off:.1f} mm off, stature {stature:+.2f} cm, "
                  f"waist {waist:+.2f} cm (true waist {truth['waist_circumference_m'] * 100:.1f} cm)",
                  flush=True)  # fmt: skip


if __name__ == "__main__":
    main()
