"""Holes in full-surface training clouds (``data.holes``): what occlusion and dark clothing do to a scan.

A scanner leaves holes: an arm in front of the torso, a dark belt, the crotch and armpits, a thigh hidden by
the other leg. The full-surface sampler draws complete surfaces only. With probability ``prob`` a training
cloud is sampled with extra points, then ``count`` balls centred on random points of it (radius uniform in
``radius_m``) are emptied and ``num_points`` of the points left are kept: the same point count, the same
labels, a surface with holes.

A hole that would leave fewer than ``num_points`` points is skipped, so a cloud never repeats points. Only
the training stream gets holes (the validation and test sets are unchanged, their cache keys too); the
decision and the holes have their own random stream, so a cloud without holes is the cloud drawn before
the option existed. Measured in 400-step arms and not adopted (test sets level, fits of scans with holes no
better): ``experiments/fitting/holes.md``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch

#: points sampled before carving, per point kept (holes of up to ~40 % of the surface keep ``num_points``)
OVERSAMPLE = 1.75


@dataclass
class HoleConfig:
    """``data.holes``: ``prob`` the share of full-surface training clouds with holes, ``count`` the number
    of holes ``[min, max]`` (uniform), ``radius_m`` their radius ``[min, max]`` in metres (uniform)."""

    prob: float = 0.0
    count: tuple[int, int] = (1, 8)
    radius_m: tuple[float, float] = (0.03, 0.12)

    def __post_init__(self) -> None:
        if not 0.0 <= float(self.prob) <= 1.0:
            raise ValueError(f"data.holes.prob is a probability in [0, 1], got {self.prob}")
        self.prob = float(self.prob)
        count, radius = tuple(self.count), tuple(self.radius_m)
        whole = len(count) == 2 and all(float(c) == int(c) for c in count)
        if not whole or not 1 <= count[0] <= count[1] <= 64:
            raise ValueError(f"data.holes.count must be [min, max] whole numbers in 1-64, got {self.count}")
        if len(radius) != 2 or not 0.0 < float(radius[0]) <= float(radius[1]) <= 0.5:
            raise ValueError(
                "data.holes.radius_m must be [min, max] in metres, 0 < min <= max <= 0.5, "
                f"got {self.radius_m}"
            )
        self.count = (int(count[0]), int(count[1]))
        self.radius_m = (float(radius[0]), float(radius[1]))

    @classmethod
    def from_mapping(cls, cfg: Any) -> HoleConfig:
        """From ``data.holes`` (a mapping, a config, or None: no holes); unknown keys are errors."""
        from arteq.config import dataclass_from_mapping

        return dataclass_from_mapping(cls, cfg, "data.holes")


def carve_holes(
    points: torch.Tensor, keep: int, config: HoleConfig, generator: torch.Generator
) -> tuple[torch.Tensor, torch.Tensor]:
    """``(kept [keep] long, centres [H, 3])``: indices of ``keep`` points of ``points [N, 3]`` outside the
    holes, in their order (``points`` in random order, as the surface sampler draws them, makes the first
    ``keep`` a random subset), and the centres of the holes made. Holes are drawn one after another; one
    that would leave fewer than ``keep`` points is skipped. Raises ``ValueError`` when ``N < keep``."""
    n = points.shape[0]
    if n < keep:
        raise ValueError(f"carve_holes: {n} points cannot keep {keep}")
    lo, hi = config.count
    holes = int(torch.randint(lo, hi + 1, (), generator=generator))
    centres_idx = torch.randint(0, n, (holes,), generator=generator)
    radii = torch.empty(holes, dtype=torch.float64).uniform_(*config.radius_m, generator=generator)
    x = points.detach().double()
    inside = torch.zeros(n, dtype=torch.bool)
    made = []
    for c, r in zip(centres_idx.tolist(), radii.tolist(), strict=True):
        hole = (x - x[c]).square().sum(-1) < r * r
        if int((~(inside | hole)).sum()) < keep:
            continue
        inside |= hole
        made.append(c)
    kept = torch.nonzero(~inside)[:keep, 0]
    return kept, x[made].to(points.dtype)
