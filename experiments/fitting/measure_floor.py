"""The measurement floor of the all-ages body's shape space for the user-scan suite's stated adult builds:
each true phenotype's T-posed Anny mesh projected on ``anny_allages``' 16 betas (what a perfect fit gives),
then measured through the Anny export as a fit is; stature and waist error against the true phenotype's.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/measure_floor.py 2>/dev/null | grep cm \
        > experiments/fitting/converge/measure_floor.txt
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    import user_scans as us

    people = us.People()
    for name, phen in us.stated_builds(people, 0).items():
        person = people.person(phen)
        betas = person["betas"]
        rest = torch.eye(3, dtype=torch.float64).expand(1, 22, 3, 3)
        with torch.no_grad():
            verts = people.body(betas=betas[None].double(), pose=rest).vertices[0].numpy()
        m = people.ex.export(betas.numpy(), np.tile(np.eye(3), (22, 1, 1)), verts)["measurements"]
        stature = (m["stature_m"] - person["stature_m"]) * 100
        waist = (m["waist_circumference_m"] - person["waist_circumference_m"]) * 100
        print(f"{name:14s} stature {stature:+.2f} cm, waist {waist:+.2f} cm (true waist "
              f"{person['waist_circumference_m'] * 100:.1f} cm)")  # fmt: skip


if __name__ == "__main__":
    main()
