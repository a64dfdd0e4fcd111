"""Test metrics per age band and per build, for test sets drawn with the all-ages shape prior.

A test cloud drawn with ``data.shape_prior=allages`` records what body it is (:mod:`arteq.data.shapes`:
``age_years`` of the stored Anny sample it was drawn from, ``build_extreme``). Its groups:

* ``age`` (:data:`AGE_GROUPS`): children 2-12, teens 13-17, adults 18-64, elderly 65+ (years, by the stored
  sample's morphological age; the bands are half-open: 12.9 is a child, 13.0 a teen);
* ``build`` (:data:`BUILD_GROUPS`): ``typical`` (anny's per-age distribution of weight, muscle and
  proportions) or ``extreme`` (those three uniform over anny's range: a quarter of the stored samples);
* ``bmi`` (:data:`BMI_GROUPS`): the WHO adult bands of the ground-truth body's BMI, from its rest mesh
  (:func:`arteq.data.shapes.rest_measurements`: mass at 980 kg/m^3 over stature squared). Children's BMI
  is lower by nature (most 2-12-year-olds fall under 18.5): read it together with the age table.

:class:`GroupedBodyFitMetrics` accumulates :class:`arteq.training.metrics.BodyFitMetrics`' sums per group
(summed over devices like it), so a group's values are exactly those of ``BodyFitMetrics`` on the clouds of
that group. Results: ``{grouping: {group: {"count": n, "part_acc": ..., "v2v_cm": ..., "mpjpe_cm": ...,
"rot_err_deg": ...}}}`` per split, empty groups left out (``metrics.json["breakdown"][split]``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import torch
from torchmetrics import Metric

from arteq.body.skeleton import NUM_JOINTS
from arteq.geometry.rotations import geodesic_deg

#: Age bands: (label, lowest age, first age above), years.
AGE_GROUPS = (("2-12", 0.0, 13.0), ("13-17", 13.0, 18.0), ("18-64", 18.0, 65.0), ("65+", 65.0, math.inf))
#: The stored build label (``build_extreme`` 0 / 1).
BUILD_GROUPS = ("typical", "extreme")
#: BMI bands (kg/m^2): (label, lowest, first value above).
BMI_GROUPS = (
    ("under 18.5", 0.0, 18.5), ("18.5-25", 18.5, 25.0), ("25-30", 25.0, 30.0), ("30+", 30.0, math.inf),
)  # fmt: skip
#: The groupings, in table order, with their group labels.
GROUPINGS = {
    "age": tuple(g[0] for g in AGE_GROUPS),
    "build": BUILD_GROUPS,
    "bmi": tuple(g[0] for g in BMI_GROUPS),
}
#: Metric keys of a group (``count`` first), as in :data:`arteq.results.METRIC_KEYS`.
GROUP_KEYS = ("count", "part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg")


def has_shape_meta(batch: Mapping[str, Any]) -> bool:
    """Whether a batch's clouds record what body they are (drawn with the all-ages prior)."""
    return "age_years" in batch and "build_extreme" in batch


def _bands(values: torch.Tensor, bands) -> torch.Tensor:
    """Band index of each value (``-1``: NaN / outside every band)."""
    out = torch.full(values.shape, -1, dtype=torch.long, device=values.device)
    for i, (_, lo, hi) in enumerate(bands):
        out[(values >= lo) & (values < hi)] = i
    return out


def group_indices(batch: Mapping[str, torch.Tensor], body: torch.nn.Module) -> dict[str, torch.Tensor]:
    """``{grouping: [B] long}``: each cloud's group per :data:`GROUPINGS` (``-1``: not known, e.g. a body
    whose betas came from the pose source). ``body``: the body model of the ground-truth betas (BMI)."""
    from arteq.data.shapes import rest_measurements

    age = batch["age_years"].double()
    build = batch["build_extreme"].long()
    bmi = rest_measurements(body, batch["betas"])["bmi"].to(age.device)
    known = batch.get("shape_index")
    if known is not None:  # BMI only for bodies drawn from the prior (the age and build of the others: -1)
        bmi = torch.where(known.to(bmi.device) >= 0, bmi, torch.full_like(bmi, math.nan))
    return {
        "age": _bands(age, AGE_GROUPS),
        "build": torch.where((build == 0) | (build == 1), build, torch.full_like(build, -1)),
        "bmi": _bands(bmi, BMI_GROUPS),
    }


class GroupedBodyFitMetrics(Metric):
    """:class:`~arteq.training.metrics.BodyFitMetrics` per group: the same sums, one per group index."""

    full_state_update = False
    higher_is_better = False

    def __init__(self, num_groups: int, num_parts: int = NUM_JOINTS, **kwargs):
        super().__init__(**kwargs)
        self.num_groups, self.num_parts = int(num_groups), num_parts
        g = self.num_groups
        self.add_state("v2v_sum", torch.zeros(g, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("mpjpe_sum", torch.zeros(g, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("rot_sum", torch.zeros(g, num_parts, dtype=torch.float64), dist_reduce_fx="sum")
        self.add_state("bodies", torch.zeros(g, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("correct", torch.zeros(g, dtype=torch.long), dist_reduce_fx="sum")
        self.add_state("points", torch.zeros(g, dtype=torch.long), dist_reduce_fx="sum")

    def update(
        self,
        groups: torch.Tensor,
        pred_vertices: torch.Tensor,
        gt_vertices: torch.Tensor,
        pred_joints: torch.Tensor,
        gt_joints: torch.Tensor,
        pred_rotmats: torch.Tensor,
        gt_rotmats: torch.Tensor,
        pred_labels: torch.Tensor,
        gt_labels: torch.Tensor,
    ) -> None:
        """``groups [B]`` long (``-1``: in no group, left out); the rest as ``BodyFitMetrics.update``."""
        groups = groups.to(self.bodies.device).long()
        keep = (groups >= 0) & (groups < self.num_groups)
        if not bool(keep.any()):
            return
        g = groups[keep]
        v2v = (pred_vertices - gt_vertices).norm(dim=-1).mean(dim=-1).double() * 100
        mpjpe = (pred_joints - gt_joints).norm(dim=-1).mean(dim=-1).double() * 100
        rot = geodesic_deg(pred_rotmats.double(), gt_rotmats.double())
        self.v2v_sum.index_add_(0, g, v2v[keep])
        self.mpjpe_sum.index_add_(0, g, mpjpe[keep])
        self.rot_sum.index_add_(0, g, rot[keep])
        self.bodies.index_add_(0, g, torch.ones_like(g))
        correct = (pred_labels == gt_labels).reshape(len(groups), -1)
        self.correct.index_add_(0, g, correct[keep].sum(1).long())
        self.points.index_add_(0, g, torch.full_like(g, correct.shape[1]))

    def compute(self) -> dict[str, torch.Tensor]:
        """Per group ``[G]``: ``count``, ``part_acc``, ``v2v_cm``, ``mpjpe_cm``, ``rot_err_deg``."""
        n = self.bodies.clamp_min(1)
        return {
            "count": self.bodies,
            "part_acc": 100.0 * self.correct.double() / self.points.clamp_min(1),
            "v2v_cm": self.v2v_sum / n,
            "mpjpe_cm": self.mpjpe_sum / n,
            "rot_err_deg": (self.rot_sum / n[:, None]).mean(1),
        }


class SplitBreakdown(torch.nn.Module):
    """One split's :class:`GroupedBodyFitMetrics`, one per grouping of :data:`GROUPINGS`."""

    def __init__(self) -> None:
        super().__init__()
        self.metrics = torch.nn.ModuleDict({k: GroupedBodyFitMetrics(len(v)) for k, v in GROUPINGS.items()})

    @property
    def update_called(self) -> bool:
        return any(m.update_called for m in self.metrics.values())

    def update(self, batch: Mapping[str, torch.Tensor], body: torch.nn.Module, pred, gt) -> None:
        """Add a batch (``pred`` / ``gt`` as the module's metric update takes them)."""
        for name, groups in group_indices(batch, body).items():
            self.metrics[name].update(
                groups,
                pred["vertices"], gt["vertices"], pred["joints"], gt["joints"],
                pred["global_rotmats"], gt["global_rotmats"], pred["seg_logits"].argmax(-1), gt["labels"],
            )  # fmt: skip

    def compute(self) -> dict[str, dict[str, dict[str, float | int]]]:
        """``{grouping: {group: {count, metrics...}}}``, groups without clouds left out."""
        out: dict[str, dict[str, dict[str, float | int]]] = {}
        for name, labels in GROUPINGS.items():
            values = self.metrics[name].compute()
            rows = {}
            for i, label in enumerate(labels):
                count = int(values["count"][i])
                if count:
                    rows[label] = {"count": count} | {k: float(values[k][i]) for k in GROUP_KEYS[1:]}
            out[name] = rows
        return out

    def reset(self) -> None:
        for m in self.metrics.values():
            m.reset()
