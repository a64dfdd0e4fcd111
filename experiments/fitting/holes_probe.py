"""The holes defect of ``scan_defects.py`` probed: which fits it loses and why (experiments/fitting/holes.md).

    OMP_NUM_THREADS=1 python experiments/fitting/holes_probe.py fits [--ckpt CKPT] [ARM ...]
    OMP_NUM_THREADS=1 python experiments/fitting/holes_probe.py clean [--seeds 0 1 2 3]

``fits``: the 8 bodies of ``scan_defects.py --seed 0`` with its ``holes`` defect (8 holes of 10 cm), fitted
through ``arteq.fit.Fitter`` per arm: ``default``, ``norefine`` (the network alone) or ``KEY=VALUE``
RefineConfig settings (space-separated in one argument); V2V cm per body, and for fits above 3 cm the five
worst joints (cm). ``clean``: the clean-up alone (``arteq.fit.clean.clean_scan``) on the ``holes``,
``one_side``, ``sparse`` and ``clean`` scans of 8 bodies per seed, with ``keep_near_m`` 0.2 (before
2026-12-06) and 0.3: the points removed as separate clusters (every one a body point: these scans hold no
clutter) and the gap of the nearest other cluster, where either removes any.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def bodies(seed: int):
    """``(name, up, vertices, joints, faces)`` of ``scan_defects.py``'s bodies for ``seed``, in its order."""
    from user_scans import EVERYDAY, People, pose_from_template, z_up_heading

    people = People()
    phens = people.sample(4, (3.0, 12.0), 9100 + seed) + people.sample(4, (18.0, 70.0), 9200 + seed)
    poses = list(EVERYDAY)
    rng = np.random.default_rng(9300 + seed)
    for k, phen in enumerate(phens):
        p = people.person(phen)
        name = poses[k % len(poses)]
        rot = z_up_heading(rng)
        v, j = people.posed(p, pose_from_template(EVERYDAY[name], rng), rot, rng.uniform(-2, 2, 3))
        yield k, f"{k} {name}", rot @ np.array([0.0, 1.0, 0.0]), v, j, people.faces


def fits(a) -> None:
    from scan_defects import DEFECTS, defect_scan

    from arteq.body.skeleton import JOINT_NAMES
    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig

    scans = [(name, defect_scan("holes", v, j, f, up, np.random.default_rng([0, k, DEFECTS.index("holes")])), v, j)
             for k, name, up, v, j, f in bodies(0)]  # fmt: skip
    for arm in a.arms or ["default"]:
        items = arm.split()
        fitter = Fitter(ckpt=a.ckpt, device="cpu", anny=False, refine="norefine" not in items,
                        refine_config=RefineConfig.from_strings([x for x in items if "=" in x]))  # fmt: skip
        errs = []
        for name, pts, v, j in scans:
            r = fitter.fit_points(pts, name=name)
            e = float(np.linalg.norm(r.vertices - v, axis=1).mean() * 100)
            errs.append(e)
            if e > 3:
                je = np.linalg.norm(r.joints - j[:22], axis=1) * 100
                worst = [(JOINT_NAMES[t], round(float(je[t]), 1)) for t in np.argsort(-je)[:5]]
                print(f"    {name}: {e:.2f} cm, worst joints {worst}; {r.message}", flush=True)
        print(f"{arm}: " + " ".join(f"{e:6.2f}" for e in errs) + f"  mean {np.mean(errs):.2f}", flush=True)


def clean(a) -> None:
    from scan_defects import DEFECTS, defect_scan

    from arteq.fit.clean import CleanConfig, clean_scan

    print("seed body defect points: (cluster-removed points, gap m) at keep_near_m 0.2 | 0.3")
    for seed in a.seeds:
        for k, name, up, v, j, f in bodies(seed):
            for kind in ("holes", "one_side", "sparse", "clean"):
                pts = defect_scan(kind, v, j, f, up, np.random.default_rng([seed, k, DEFECTS.index(kind)]))
                out = []
                for near in (0.2, 0.3):
                    c = clean_scan(pts, CleanConfig(keep_near_m=near))
                    out.append(f"{c.counts['cluster']} ({(c.second_cluster.get('gap_m') or 0):.3f})")
                if any(not o.startswith("0 ") for o in out):
                    print(f"{seed} {name} {kind} {len(pts)}: {' | '.join(out)}", flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    f = sub.add_parser("fits")
    f.add_argument("--ckpt", default="anny_scan")
    f.add_argument("arms", nargs="*")
    c = sub.add_parser("clean")
    c.add_argument("--seeds", type=int, nargs="*", default=[0, 1, 2, 3])
    a = ap.parse_args()
    torch.set_num_threads(1)
    fits(a) if a.mode == "fits" else clean(a)


if __name__ == "__main__":
    main()
