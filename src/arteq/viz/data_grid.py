"""Picture of sampled clouds coloured by part: in-distribution row(s) next to out-of-distribution ones.

``python -m arteq.viz.data_grid --out experiments/figures/data_id_vs_ood.png [--body anny22|toy]``
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib
import numpy as np  # noqa: E402
import torch  # noqa: E402
from matplotlib.figure import Figure

from arteq.body import create_body  # noqa: E402
from arteq.data.dataset import BodyScanDataset  # noqa: E402
from arteq.data.poses import SyntheticIDPoses, SyntheticOODPoses  # noqa: E402


def part_colours(k: int = 22) -> np.ndarray:
    """``[k, 4]`` RGBA colours, neighbours in the tree get distinct hues."""
    cmap = matplotlib.colormaps["tab20"]
    extra = matplotlib.colormaps["Set1"]
    cols = [cmap(i) for i in range(20)] + [extra(i) for i in range(k - 20)]
    return np.asarray(cols[:k])


def draw_grid(samples: list[list[dict]], titles: list[str], out: Path, point_size: float = 0.8) -> None:
    """One row per entry of ``samples`` (list of sample dicts), front view (x right, y up)."""
    rows, cols = len(samples), max(len(r) for r in samples)
    fig = Figure(figsize=(1.6 * cols, 2.2 * rows))
    axes = fig.subplots(rows, cols, squeeze=False)
    colours = part_colours()
    for r, row in enumerate(samples):
        for c in range(cols):
            ax = axes[r, c]
            ax.set_axis_off()
            if c >= len(row):
                continue
            p = row[c]["points"].numpy()
            lab = row[c]["labels"].numpy()
            order = np.argsort(p[:, 2])  # painter's order: far (-z) first, viewer at +z
            ax.scatter(p[order, 0], p[order, 1], s=point_size, c=colours[lab[order]], linewidths=0)
            ax.set_aspect("equal")
            lim = 1.05
            ax.set_xlim(-lim, lim)
            ax.set_ylim(-lim, lim)
        axes[r, 0].text(-1.0, 1.0, titles[r], fontsize=8, ha="left", va="bottom")
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.96, wspace=0.0, hspace=0.12)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)


def main(argv: list[str] | None = None) -> Path:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("experiments/figures/data_id_vs_ood.png"))
    ap.add_argument("--body", default="anny22", help="body model name (anny22, smpl, toy)")
    ap.add_argument("--per-row", type=int, default=8)
    ap.add_argument("--rows", type=int, default=2, help="rows per distribution")
    ap.add_argument("--num-points", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    body = create_body(name=args.body)
    rows, titles = [], []
    for name, src in (
        ("ID (synthetic everyday motions)", SyntheticIDPoses()),
        ("OOD (extremes)", SyntheticOODPoses()),
    ):
        ds = BodyScanDataset(src, body, "viz", 10_000, seed=args.seed, num_points=args.num_points)
        for r in range(args.rows):
            rows.append([ds[r * args.per_row + i] for i in range(args.per_row)])
            titles.append(f"{name}, row {r + 1}: front view, colour = part")
    draw_grid(rows, titles, args.out)
    print(f"wrote {args.out}")
    return args.out


if __name__ == "__main__":
    torch.set_num_threads(1)
    main()
