"""What limits the stature goal: the refinement started from the truth (issue 19: stature within 1.5 cm).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/stature_probe.py --seeds 0 1 \
        --out experiments/fitting/stature/probe.md [--set KEY=VALUE ...] [--no-pipeline]

For the user-scan suite's ``children`` and ``adults`` (``user_scans.py``, the same scans), three statures
against the truth's (anny's anthropometry of the true phenotype), each the height of the rest mesh of a set of
``anny_allages`` betas (the stature anny's anthropometry gives, to within 0.06 cm on these bodies):

- ``pipeline``: the betas of ``arteq-fit``'s fit (``Fitter`` defaults, the shipped ``anny_scan``);
- ``truth``: the true phenotype's betas on the model's components (what the body can represent);
- ``from truth``: :func:`arteq.fit.refine.refine` (``RefineConfig`` defaults, or ``--set``) started at the
  true pose, betas and translation with the true part of every point (its nearest true vertex's) as its
  labels: where the refinement's objective itself takes the shape. Its V2V is printed beside it.

The difference between ``from truth`` and ``truth`` is the objective's bias; between ``pipeline`` and
``from truth`` what the network's start adds.
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
    from scipy.spatial import cKDTree

    from arteq.body import load_body_model
    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig, refine

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--groups", nargs="+", default=["children", "adults"])
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="RefineConfig of 'from truth'")
    ap.add_argument("--no-pipeline", action="store_true", help="skip arteq-fit's own fit")
    ap.add_argument("--rescan", type=float, default=None, metavar="NOISE_MM",
                    help="scan each true mesh again, uniformly (no density waves), with this much noise")
    ap.add_argument("--curved", action="store_true",
                    help="with --rescan: scan the smooth surface through the mesh's vertices, not its flat faces")
    ap.add_argument("--betas", type=int, default=None, help="shape components of 'from truth' (the body's 16)")
    ap.add_argument("--out", default=None, help="write the Markdown table here")
    a = ap.parse_args(argv)
    torch.set_num_threads(int(os.environ.get("OMP_NUM_THREADS", "1")))

    fitter = None if a.no_pipeline else Fitter(ckpt="anny_scan", device="cpu", points=5000, anny=False)
    body = load_body_model("anny_allages", num_betas=a.betas).double()
    nb, labels = body.num_betas, body.part_labels.numpy()
    cfg = RefineConfig.from_strings(a.set)
    rest_pose = torch.eye(3, dtype=torch.float64).expand(1, 22, 3, 3)

    def stature_cm(betas: torch.Tensor) -> float:
        v = body(betas=betas[:nb].reshape(1, nb).double(), pose=rest_pose).vertices[0]
        return float(v[:, 1].max() - v[:, 1].min()) * 100  # the rest pose stands along +y

    rows, t0 = [], time.perf_counter()
    for seed in a.seeds:
        for s in us.people_scans(seed):
            if s.group not in a.groups or s.betas is None:
                continue
            truth = s.truth["stature_m"] * 100
            if a.rescan is not None:
                rng = np.random.default_rng(seed)
                s.points = us.surface_scan(s.vertices, body.faces.numpy(), len(s.points), rng, a.rescan / 1000, 0.0,
                                           curved=a.curved)
            tb = s.betas[:nb].double()
            centre = s.points.mean(0)
            probs = torch.nn.functional.one_hot(torch.as_tensor(labels[cKDTree(s.vertices).query(s.points)[1]]),
                                                body.part_labels.max().item() + 1).double()  # fmt: skip
            init = {"local_rotmats": s.pose[None].double(), "betas": tb[None].clone(),
                    "transl": torch.as_tensor(s.transl - centre)[None]}  # fmt: skip
            out = refine(body, torch.as_tensor(s.points - centre)[None], probs[None], init, cfg)
            v2v = float(np.linalg.norm(out.vertices[0].numpy() + centre - s.vertices, axis=1).mean() * 100)
            row = {"seed": seed, "group": s.group, "name": s.name, "truth": stature_cm(tb) - truth,
                   "from_truth": stature_cm(out.betas[0]) - truth, "from_truth_v2v": v2v}  # fmt: skip
            if fitter is not None:
                row["pipeline"] = stature_cm(torch.as_tensor(fitter.fit_points(s.points).betas)) - truth
            rows.append(row)
            print(f"{seed} {s.group:9s} {s.name:42s} " + " ".join(
                f"{k} {row[k]:+.2f}" for k in ("pipeline", "truth", "from_truth") if k in row), flush=True)
    cols = [k for k in ("pipeline", "truth", "from_truth") if k in rows[0]]
    lines = [
        f"# {__doc__.splitlines()[0]}", "", "```",
        "OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/stature_probe.py " + " ".join(argv or sys.argv[1:]),
        "```", "",
        f"{len(rows)} scans, {time.perf_counter() - t0:.0f} s; refinement: `RefineConfig` "
        f"{'defaults' if not a.set else ' '.join(a.set)}"
        + ("" if a.rescan is None else f"; scans made again: uniform, {a.rescan:g} mm noise")
        + (", of the curved surface through the mesh's vertices" if a.rescan is not None and a.curved else "")
        + ". Stature error cm (fit minus truth; the rest mesh's height).",
        "", "| group | summary | " + " | ".join(cols) + " |", "|---|---|" + "---:|" * len(cols),
    ]  # fmt: skip
    for g in a.groups:
        sel = [r for r in rows if r["group"] == g]
        for label, fn in (("mean", np.mean), ("mean abs", lambda x: np.mean(np.abs(x))),
                          ("worst abs", lambda x: np.max(np.abs(x)))):  # fmt: skip
            lines.append(f"| {g} | {label} | " + " | ".join(f"{fn([r[c] for r in sel]):+.2f}" for c in cols) + " |")
    lines += ["", "| seed | group | scan | " + " | ".join(cols) + " | from truth: V2V cm |",
              "|---|---|---|" + "---:|" * (len(cols) + 1)]  # fmt: skip
    for r in rows:
        vals = " | ".join(f"{r[c]:+.2f}" for c in cols)
        lines.append(f"| {r['seed']} | {r['group']} | {r['name']} | {vals} | {r['from_truth_v2v']:.2f} |")
    text = "\n".join(lines) + "\n"
    us.report(text, a.out)


if __name__ == "__main__":
    main()
