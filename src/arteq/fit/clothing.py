"""The body under its clothes: a last refinement in which the scanned surface is the skin plus a stated
thickness of cloth.

A scan of a dressed person is the surface of the clothes. Fitted as it is, the body swells to it: on
``experiments/fitting/scan_defects.py``'s ``clothed`` scans (a T-shirt 1 cm and trousers 0.8 cm off the
skin) the waist comes out about 7 cm too large, on ``loose`` ones (2-2.5 cm) about 17 cm
(``experiments/fitting/clothing.md``). With ``arteq-fit --clothing CM`` the fit is refined once more from
its own result, with the surface matched to the scan being the body pushed out along its normals by ``CM``
on the parts the clothes cover (:attr:`ClothingConfig.parts`; bare head, neck, forearms, hands and feet by
default) and 0 elsewhere; the body returned is the skin under it. The thickness is the user's statement:
one scan cannot tell a thick sweater from a heavy body.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch

from arteq.body.skeleton import JOINT_NAMES
from arteq.fit.refine import RefineConfig, RefineOutput, refine

#: the parts a T-shirt and trousers cover (a part: the vertices its joint drives most)
COVERED = (
    "pelvis,spine1,spine2,spine3,left_collar,right_collar,left_shoulder,right_shoulder,"
    "left_hip,right_hip,left_knee,right_knee"
)


@dataclass(frozen=True)
class ClothingConfig:
    """``thickness_cm`` of cloth over the skin on ``parts`` (joint names, comma-separated: a part is what
    its joint drives most, ``left_shoulder`` the upper arm, ``left_elbow`` the forearm, ``left_knee`` the
    shin), fitted by ``iters`` refinement iterations from the fit of the clothed surface."""

    thickness_cm: float = 1.0
    parts: str = COVERED
    iters: int = 30

    def __post_init__(self) -> None:
        if not (0.0 <= float(self.thickness_cm) <= 10.0):
            raise ValueError(f"clothing thickness must be 0-10 cm, got {self.thickness_cm}")
        if int(self.iters) < 1:
            raise ValueError(f"clothing iters must be >= 1, got {self.iters}")
        self.part_ids()

    def part_ids(self) -> list[int]:
        names = [p.strip() for p in self.parts.split(",") if p.strip()]
        bad = [p for p in names if p not in JOINT_NAMES]
        if bad or not names:
            raise ValueError(
                f"clothing parts: unknown {bad or 'none given'}; choose from {', '.join(JOINT_NAMES)}"
            )
        return [JOINT_NAMES.index(p) for p in names]

    def offsets(self, part_labels: torch.Tensor) -> torch.Tensor:
        """``[V]`` metres of cloth over each vertex of a body with these ``part_labels [V]``."""
        ids = torch.as_tensor(self.part_ids(), device=part_labels.device)
        return torch.isin(part_labels, ids).to(torch.float64) * (float(self.thickness_cm) / 100.0)

    def refine_config(self, base: RefineConfig) -> RefineConfig:
        """The last refinement's knobs: ``base``'s terms at their final width, every shape component free
        from the start, the pose held near the clothed fit's, no searches (the pose is settled)."""
        return replace(base, iters=int(self.iters), sigma_start=base.sigma_end, early_betas=10_000,
                       w_delta_end=base.w_delta, gate_frac=0.0, swing_at=-1.0, twist_at=-1.0)  # fmt: skip


def under_clothes(
    body: torch.nn.Module,
    points: torch.Tensor,
    labels: torch.Tensor,
    init: dict[str, torch.Tensor],
    clothing: ClothingConfig,
    base: RefineConfig | None = None,
    m2s_visible=None,
) -> RefineOutput:
    """The bodies under the clothes of ``points [B, N, 3]`` (metres, with predicted parts ``labels [B, N]``),
    refined from ``init`` (``local_rotmats``, ``betas``, ``transl``: the fits of the clothed surfaces);
    ``m2s_visible``: for partial scans, as :func:`arteq.fit.refine.refine`'s."""
    k = len(JOINT_NAMES)
    if labels.shape != points.shape[:2]:
        raise ValueError(
            f"under_clothes: labels must be {tuple(points.shape[:2])}, got {tuple(labels.shape)}"
        )
    probs = torch.nn.functional.one_hot(labels.long().clamp(0, k - 1), k).to(points.dtype)
    cfg = clothing.refine_config(base or RefineConfig())
    offset = clothing.offsets(body.part_labels)
    return refine(body, points, probs, init, cfg, m2s_visible=m2s_visible, offset=offset)
