"""Articulated equivariance of old against new architecture, at random initialisation and trained.

    python benchmarks/bench_articulation.py [--poses 4] [--elements 2] [--candidates] \
        [--trained old=anny22 new=outputs/compare/local_invariant ...]

Rows: the old configuration (``conf/model/arteq.yaml``, the shipped ``anny22`` network's: radii scaled to
0.25-0.51 m at 500 points, plain neighbour sums, 125 deep centres, aligned parent conditioning) and the
part-local one (``conf/model/arteq_local.yaml``) at random initialisation with the same seed, then every
``--trained NAME=CKPT``
(a checkpoint, run folder or shipped model name). Columns: :data:`arteq.models.articulation.METRICS`,
means over the elbows, knees, shoulders and hips (both sides), ``--poses`` everyday poses and up to
``--elements`` order-5 group elements per joint that keep the turned limb clear of the body
(:func:`arteq.models.articulation.articulated_equivariance`). ``--json`` writes the rows too.
"""

from __future__ import annotations

import argparse
import copy
import json

import torch

from arteq.body.factory import create_body
from arteq.models.articulation import METRICS, articulated_equivariance, default_net_config
from arteq.models.registry import build_net

#: ``--candidates``: the locality variants compared at initialisation when the new default was chosen.
CANDIDATES = {
    "old + neighbour mean": {"normalize": True},
    "metric radii, plain sums, strides 2-1-2-1": {"radii": [0.08, 0.113, 0.16, 0.16], "normalize": False},
    "metric radii, neighbour mean, strides 2-1-2-1": {"radii": [0.08, 0.113, 0.16, 0.16], "normalize": True},
    "smaller radii 0.06-0.11, neighbour mean, strides 2-1-1-1": {
        "radii": [0.06, 0.08, 0.11, 0.11], "normalize": True, "strides": [2, 1, 1, 1],
        "neighbours": [32, 16, 16, 16],
    },
    "metric radii, neighbour mean, strides 1-1-1-1": {
        "radii": [0.08, 0.113, 0.16, 0.16], "normalize": True, "strides": [1, 1, 1, 1],
        "neighbours": [16, 16, 16, 16],
    },
}  # fmt: skip


def configs(points: int, candidates: bool = False) -> dict[str, dict]:
    new = default_net_config(points, "arteq_local")
    old = default_net_config(points, "arteq")
    out = {"old (random init)": old, "new (random init)": new}
    for name, bb in CANDIDATES.items() if candidates else ():
        cfg = copy.deepcopy(old)
        cfg["backbone"] |= bb
        out[f"{name} (random init)"] = cfg
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--poses", type=int, default=4)
    ap.add_argument("--elements", type=int, default=2)
    ap.add_argument("--points", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--trained", nargs="*", default=[], metavar="NAME=CKPT")
    ap.add_argument("--candidates", action="store_true", help="also the locality variants at random init")
    ap.add_argument("--json")
    args = ap.parse_args()
    body = create_body({"name": "anny22"})
    nets = {}
    for name, cfg in configs(args.points, args.candidates).items():
        torch.manual_seed(args.seed)
        nets[name] = build_net(cfg)
    from arteq.pretrained.card import load_module

    for item in args.trained:
        name, _, path = item.partition("=")
        nets[f"{name} (trained)"] = load_module(path).net
    rows = {}
    for name, net in nets.items():
        res = articulated_equivariance(
            net, body, num_poses=args.poses, elements_per_joint=args.elements, num_points=args.points,
            seed=args.seed,
        )  # fmt: skip
        rows[name] = res.mean
        print(f"{name}: {res.moves} moves", flush=True)
    head = "| network | " + " | ".join(METRICS) + " |"
    lines = [head, "|---|" + "---:|" * len(METRICS)]
    for name, m in rows.items():
        cells = [f"{m[k]:.3f}" if k.startswith("feat") else f"{m[k]:.1f}" for k in METRICS]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    print("\n".join(lines))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
