"""Which start limits the adults' goals: the fitter with its network's pose or shape replaced by the truth.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/start_probe.py --start pipeline|true_betas|true_pose \
        --seeds 0 1 --out experiments/fitting/stature/start_<START>.md

The user-scan suite's adults (``user_scans.py``, the same scans) through ``arteq-fit``'s ``Fitter`` (its
defaults, the shipped ``anny_scan``), with every start the refinement gets (the network's and the second
network's) changed before it refines:

- ``pipeline``: unchanged;
- ``true_betas``: the shape replaced by the true phenotype's components (the networks' poses kept);
- ``true_pose``: the local rotations replaced by the true pose (the networks' shapes and translations kept).

Per scan: stature error (cm, the rest mesh's height minus the truth's, anny's anthropometry of the true
phenotype) of the fit and of the network's own shape, and the fit's V2V (cm).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main(argv: list[str] | None = None) -> None:
    import user_scans as us

    import arteq.fit.api as api
    from arteq.body import load_body_model
    from arteq.fit import Fitter

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--start", choices=("pipeline", "true_betas", "true_pose"), default="pipeline")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--out", default=None, help="write the Markdown table here")
    a = ap.parse_args(argv)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))

    fitter = Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
    body = load_body_model("anny_allages").double()
    nb = body.num_betas
    rest = torch.eye(3, dtype=torch.float64).expand(1, 22, 3, 3)

    def stature_cm(b) -> float:
        v = body(betas=torch.as_tensor(b[:nb]).reshape(1, nb).double(), pose=rest).vertices[0]
        return float(v[:, 1].max() - v[:, 1].min()) * 100  # the rest pose stands along +y

    truth: dict = {}
    seen: dict = {}
    refine = api.refine

    def refine_from(body_, points, probs, starts, cfg, **kw):
        seen["net_betas"] = starts["betas"][0].detach().clone()
        starts = dict(starts)
        if a.start == "true_betas":
            b = starts["betas"].clone()
            b[:] = truth["betas"][: b.shape[-1]].to(b.dtype)
            starts["betas"] = b
        elif a.start == "true_pose":
            r = starts["local_rotmats"].clone()
            r[:] = truth["pose"].to(r.dtype)
            starts["local_rotmats"] = r
        return refine(body_, points, probs, starts, cfg, **kw)

    api.refine = refine_from
    rows, t0 = [], time.perf_counter()
    try:
        for seed in a.seeds:
            for s in us.people_scans(seed):
                if s.group != "adults" or s.betas is None:
                    continue
                truth.update(betas=s.betas.double(), pose=s.pose.double())
                true_cm = s.truth["stature_m"] * 100
                r = fitter.fit_points(s.points, name=s.name)
                rows.append({"seed": seed, "name": s.name, "fit": stature_cm(r.betas) - true_cm,
                             "net": stature_cm(seen["net_betas"].numpy()) - true_cm,
                             "v2v": float(np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100)})  # fmt: skip
                print(" ".join(f"{k} {v:+.2f}" if isinstance(v, float) else str(v) for k, v in rows[-1].items()),
                      flush=True)  # fmt: skip
    finally:
        api.refine = refine
    fit, v2v = np.array([r["fit"] for r in rows]), np.array([r["v2v"] for r in rows])
    lines = [
        f"# {__doc__.splitlines()[0]}", "", "```",
        "OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/start_probe.py " + " ".join(argv or sys.argv[1:]),
        "```", "",
        f"Start `{a.start}`; {len(rows)} adults, seeds {', '.join(map(str, a.seeds))}; {time.perf_counter() - t0:.0f} s. "
        f"Stature error of the fit, mean {fit.mean():+.2f}, mean |.| {np.abs(fit).mean():.2f}, worst |.| "
        f"{np.abs(fit).max():.2f} cm; V2V mean {v2v.mean():.2f}, worst {v2v.max():.2f} cm.",
        "", "| seed | scan | stature err, fit cm | stature err, network's shape cm | V2V cm |",
        "|---|---|---:|---:|---:|",
    ]  # fmt: skip
    lines += [f"| {r['seed']} | {r['name']} | {r['fit']:+.2f} | {r['net']:+.2f} | {r['v2v']:.2f} |" for r in rows]
    text = "\n".join(lines) + "\n"
    us.report(text, a.out)


if __name__ == "__main__":
    main()
