"""Test results as data: split names, the nested results dict, method names, the Markdown table.

One shape for every command that tests something (training, ``arteq.eval``, the fitter evaluation)::

    {"test_id": {"part_acc": 91.2, "v2v_cm": 2.1, "mpjpe_cm": 1.7, "rot_err_deg": 8.3,
                 "rot_err_deg_per_part": {"pelvis": 4.1, ...}},
     "test_ood": {...}}

built straight from the metric objects (:func:`split_results`), never parsed back from logger keys.
Test sets drawn with the all-ages shape prior are also broken down per age band and per build
(:mod:`arteq.training.breakdown`): ``{split: {grouping: {group: {"count": n, metric: value}}}}`` beside
the results (``metrics.json["breakdown"]``), as tables by :func:`breakdown_markdown`.
Method names come from the run's config (:func:`method_name`), so a PointNet++ run is labelled
"PointNet++". Plain Python only: no torch import at module level.

A body fitted to a batch of clouds, by test-time refinement (:func:`arteq.fit.refine.refine`) or by
optimisation from a standard start (:func:`arteq.optim_fit.fit_body`), comes back as one type,
:class:`BodyFitResult`.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # annotations only: importing this module does not import torch
    import torch

#: The evaluation splits, in the order the datamodule returns their loaders: ID, the hard OOD set, then
#: the graded OOD scale (one / two limbs out of distribution, OOD poses without self-contact).
TEST_SPLITS = ("test_id", "test_ood", "test_ood_limb1", "test_ood_limb2", "test_ood_contact")
#: The cached single-view test sets (``data.view_splits``, :mod:`arteq.data.single_view`): the ID test
#: bodies each seen by one depth camera from the front, a side, behind, above, or near in a 640 x 480 frame
#: (parts cut off), in this order. Their names
#: in ``data.view_splits``: :data:`VIEW_NAMES` or the split names (see :func:`view_split`).
VIEW_NAMES = ("front", "side", "back", "top", "near")
VIEW_SPLITS = tuple(f"test_view_{v}" for v in VIEW_NAMES)
#: Every split a test loop can report, in table order: the full-surface sets, then the view sets.
ALL_TEST_SPLITS = (*TEST_SPLITS, *VIEW_SPLITS)
#: The paper's two test sets: ID and the hard OOD set (the columns of its tables, the model cards' subsets).
PAPER_SPLITS = ("test_id", "test_ood")
#: Scalar metrics of :class:`arteq.training.metrics.BodyFitMetrics`, in table order.
METRIC_KEYS = ("part_acc", "v2v_cm", "mpjpe_cm", "rot_err_deg")
#: Column labels of the splits in tables.
SPLIT_LABELS = {
    "test_id": "ID", "test_ood": "OOD", "test_ood_limb1": "OOD-1limb", "test_ood_limb2": "OOD-2limb",
    "test_ood_contact": "OOD-nocontact",
    "test_view_front": "front-view", "test_view_side": "side-view", "test_view_back": "back-view",
    "test_view_top": "top-view", "test_view_near": "near-view (framed)",
}  # fmt: skip
#: Unit line under every metrics table.
UNITS_NOTE = "part_acc in %, v2v/mpjpe in cm (MPJPE over the 22 body joints), rot_err in degrees."
#: Row label of the mean-pose floor.
FLOOR_NAME = "mean pose (floor)"
#: The breakdowns' groupings (:mod:`arteq.training.breakdown`), in table order, with their table titles.
BREAKDOWN_TITLES = {
    "age": "per age band (years)",
    "build": "per build (the stored sample's: typical or extreme)",
    "bmi": "per BMI band (kg/m^2, the ground-truth body's rest mesh)",
}
#: Column label of each grouping.
BREAKDOWN_COLUMNS = {"age": "age", "build": "build", "bmi": "BMI"}
#: What the breakdown's groups are (under its tables).
BREAKDOWN_NOTE = (
    "Groups of the test clouds drawn with the all-ages shape prior: age = the morphological age (years) of "
    "the stored Anny sample a body was drawn from (2-12 children, 13-17 teens, 18-64 adults, 65+ elderly); "
    "build = that sample's build (typical: anny's per-age weight, muscle and proportions; extreme: those "
    "uniform over anny's range); BMI = mass (rest-mesh volume x 980 kg/m^3) / stature^2 of the ground-truth "
    "body, in the WHO adult bands (children's BMI is lower by nature: read it with the age table). "
    "clouds = the group's count; the groups of a grouping add up to the split's clouds (those whose body "
    "was drawn from the stored samples: all of them with the synthetic poses)."
)
#: Suffix of the method name per training augmentation.
AUGMENT_SUFFIX = {"none": "", "so3": " + SO(3) aug", "z": " + z aug"}


@dataclass
class BodyFitResult:
    """A body fitted to ``B`` clouds: its parameters, the posed mesh and how the fit went.

    Tensors are batched, detached and on the device the fit ran on. Returned by
    :func:`arteq.fit.refine.refine` (also named ``RefineOutput`` there) and
    :func:`arteq.optim_fit.fit_body` (``OptimFitResult``); ``result["betas"]`` reads a field too.
    """

    local_rotmats: torch.Tensor  # [B, 22, 3, 3] local rotations, root first
    betas: torch.Tensor  # [B, nb]
    transl: torch.Tensor  # [B, 3] metres
    vertices: torch.Tensor  # [B, V, 3] metres
    joints: torch.Tensor  # [B, 22, 3] metres
    global_rotmats: torch.Tensor  # [B, 22, 3, 3]
    history: list[dict[str, float]] = field(default_factory=list)  # objective terms per iteration
    iterations: int = 0
    seconds: float = 0.0  # wall clock
    #: ``[B, 22, 3]`` local axis-angle, from fitters that optimise it (``fit_body``); None otherwise.
    pose_aa: torch.Tensor | None = None

    @property
    def pose(self) -> torch.Tensor:
        """``local_rotmats`` under the name the body model's ``pose`` argument (and ``fit_body``'s
        ``init``) uses."""
        return self.local_rotmats

    def __getitem__(self, key: str) -> Any:  # dict-style access: result["pose"]
        return getattr(self, key)


def view_split(name: Any) -> str | None:
    """The view test set ``name`` names in ``data.view_splits``: ``front`` or ``test_view_front`` ->
    ``test_view_front`` (:data:`VIEW_SPLITS`); None for anything else."""
    if not isinstance(name, str):
        return None
    split = name if name.startswith("test_view_") else f"test_view_{name}"
    return split if split in VIEW_SPLITS else None


def _number(x: Any) -> float:
    return float(x.item() if hasattr(x, "item") else x)


def metric_values(values: Mapping[str, Any], per_part: bool = True) -> dict[str, Any]:
    """One split's results from ``BodyFitMetrics.compute()``: floats, and the per-part rotation
    error as ``{joint name: degrees}`` (dropped with ``per_part=False``)."""
    from arteq.body.skeleton import JOINT_NAMES

    out: dict[str, Any] = {}
    for key, v in values.items():
        if key == "rot_err_deg_per_part":
            if per_part:
                out[key] = {j: _number(x) for j, x in zip(JOINT_NAMES, v)}
        else:
            out[key] = _number(v)
    return out


def split_results(metrics: Mapping[str, Any] | Iterable[Any], per_part: bool = True) -> dict[str, dict]:
    """``{split: metric_values(metric.compute())}`` for metric objects given per split (a mapping
    ``split -> metric`` or a sequence in :data:`TEST_SPLITS` order). Metrics never updated are left out
    when they say so (``update_called`` of torchmetrics)."""
    items = metrics.items() if isinstance(metrics, Mapping) else zip(TEST_SPLITS, metrics)
    return {
        split: metric_values(m.compute(), per_part=per_part)
        for split, m in items
        if getattr(m, "update_called", True)
    }


def config_get(cfg: Mapping[str, Any] | None, dotted: str, default: Any = None) -> Any:
    """``cfg["a"]["b"]`` for ``"a.b"`` in a plain or OmegaConf mapping, ``default`` when absent."""
    cur: Any = cfg
    for part in dotted.split("."):
        if not isinstance(cur, Mapping) or part not in cur:
            return default
        cur = cur[part]
    return cur


def architecture(cfg: Mapping[str, Any] | None) -> str:
    """The network's registry name (``model.net.arch``, default ``arteq``)."""
    return str(config_get(cfg, "model.net.arch", "arteq"))


def base_method_name(cfg: Mapping[str, Any] | None) -> str:
    """Method without its augmentation suffix: ``ArtEq``, ``ArtEq nc`` (no parent conditioning),
    ``ArtEq invariant-parent`` (the parent's group-mean feature instead of its token at the same group
    element), ``ArtEq part-local ...`` (``model=arteq_local``: count-normalised neighbourhoods),
    ``PointNet++``..."""
    from arteq.models.heads import parent_mode
    from arteq.models.registry import display_name

    arch = architecture(cfg)
    name = display_name(arch)
    if arch == "arteq":
        if config_get(cfg, "model.net.backbone.normalize", False):  # model=arteq_local: neighbour means
            name += " part-local"
        mode = parent_mode(config_get(cfg, "model.net.parent_conditioning", True))
        name += {"none": " nc", "invariant": " invariant-parent"}.get(mode, "")
    return name


def method_name(cfg: Mapping[str, Any] | None) -> str:
    """Method label of a training config: architecture, ``nc`` and the training augmentation
    (``ArtEq + SO(3) aug``). The point count is not part of it (reports give it a column)."""
    augment = str(config_get(cfg, "data.augment", "none"))
    return base_method_name(cfg) + AUGMENT_SUFFIX.get(augment, f" + {augment} aug")


def format_value(x: Any, digits: int = 2) -> str:
    """A table cell: ``–`` for missing or NaN values."""
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "–"
    return f"{x:.{digits}f}"


def metrics_table(rows: Mapping[str, Mapping[str, Mapping[str, Any]]]) -> str:
    """Markdown table: one row per method (``{name: results}``), a column per metric and split (the splits
    of :data:`ALL_TEST_SPLITS` that some row has: the view sets after the full-surface ones)."""
    splits = [s for s in ALL_TEST_SPLITS if any(s in res for res in rows.values())] or list(PAPER_SPLITS)
    head = "| method | " + " | ".join(f"{SPLIT_LABELS[s]} {m}" for m in METRIC_KEYS for s in splits) + " |"
    lines = [head, "|---|" + "---:|" * (len(METRIC_KEYS) * len(splits))]
    for name, res in rows.items():
        cells = [format_value(res.get(s, {}).get(m)) for m in METRIC_KEYS for s in splits]
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def metrics_markdown(title: str, rows: Mapping[str, Mapping[str, Any]], note: str = UNITS_NOTE) -> str:
    """The ``metrics.md`` of a run: ``# <title>: test metrics``, the table, a note line."""
    return "\n".join([f"# {title}: test metrics", "", metrics_table(rows), "", note])


def summary_rows(summary: Mapping[str, Any], name: str) -> dict[str, Mapping[str, Any]]:
    """Table rows of a run summary: the method's results, then the mean-pose floor if present."""
    rows = {name: summary.get("metrics", {})}
    if "mean_pose_baseline" in summary:
        rows[FLOOR_NAME] = summary["mean_pose_baseline"]
    return rows


def breakdown_table(
    breakdown: Mapping[str, Mapping[str, Any]], grouping: str, splits: Iterable[str] | None = None
) -> str:
    """Markdown table of one grouping (``age``, ``build``, ``bmi``) of a breakdown ``{split: {grouping:
    {group: {count, metric: value}}}}``: a row per split (in :data:`ALL_TEST_SPLITS` order, or ``splits``')
    and group, the cloud count and :data:`METRIC_KEYS`."""
    known = [s for s in ALL_TEST_SPLITS if s in breakdown]
    order = list(splits) if splits is not None else known + [s for s in breakdown if s not in known]
    col = BREAKDOWN_COLUMNS.get(grouping, grouping)
    lines = [f"| split | {col} | clouds | part acc % | V2V cm | MPJPE cm | rot err deg |",
             "|---|---|---:|---:|---:|---:|---:|"]  # fmt: skip
    for split in order:
        for group, m in (breakdown.get(split) or {}).get(grouping, {}).items():
            cells = [str(int(m.get("count", 0)))] + [format_value(m.get(k)) for k in METRIC_KEYS]
            lines.append(f"| {SPLIT_LABELS.get(split, split)} | {group} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def breakdown_markdown(breakdown: Mapping[str, Mapping[str, Any]], splits: Iterable[str] | None = None,
                       level: str = "##") -> str:  # fmt: skip
    """The breakdown's tables, one per grouping that some split has (``level``: the headings' level)."""
    splits = list(splits) if splits is not None else None
    parts = []
    groupings = [g for g in BREAKDOWN_TITLES if any(g in (v or {}) for v in breakdown.values())]
    groupings += [g for v in breakdown.values() for g in (v or {}) if g not in groupings]
    for grouping in dict.fromkeys(groupings):
        title = BREAKDOWN_TITLES.get(grouping, f"per {grouping}")
        parts += [f"{level} Test metrics {title}", "", breakdown_table(breakdown, grouping, splits), ""]
    return "\n".join([*parts, BREAKDOWN_NOTE])
