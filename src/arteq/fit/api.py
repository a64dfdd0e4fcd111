"""Fit the body model to scans: the Python API behind ``arteq-fit``.

A scan's path: ``arteq.io.scans`` reads it -> units to metres, clutter removal (``arteq.fit.clean``:
floors and walls, stray points, separate objects), size check, centring (float64) ->
resampling to the network's point count -> the ArtEq network (parts, rotations, shape; translation by
centroids) -> scan mode (full, or partial: one depth camera's view, detected or given; ``arteq.fit.partial``)
-> optional refinement (``arteq.fit.refine``) -> quality check
(``arteq.fit.quality``) -> everything mapped back to the scan's own frame and units.

    from arteq.fit import fit_points, fit_files
    res = fit_points(points)            # [N, 3] metres -> FitResult (vertices, joints, betas, ...)
    summary = fit_files(["scans/"], "fits/")   # what the command does
"""

from __future__ import annotations

import hashlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from arteq.fit.clean import CleanConfig, CleanResult, clean_scan
from arteq.fit.clothing import ClothingConfig
from arteq.fit.conditions import denoise, scan_conditions
from arteq.fit.crossing import CrossingConfig, pairs_to_try, try_swaps
from arteq.fit.quality import (
    REFUSE_FLAGS,
    QualityThresholds,
    describe_flags,
    fit_quality,
    off_group_distances,
    verdict,
)
from arteq.fit.reach import PREFIX as REACH
from arteq.fit.reach import reach_starts
from arteq.fit.refine import RefineConfig, body_tables, refine, refine_iteration
from arteq.fit.torso_turns import torso_starts
from arteq.io.scans import MIN_POINTS, UNITS, ScanError, check_body_size, clean_points

#: Status values of a :class:`FitResult`: ``ok``; ``uncertain`` (a body, but the check doubts the fit:
#: written and flagged, ``uncertain_reason`` says why); ``not_single_body`` (not one body: nothing
#: written); ``refused`` (an uncertain fit refused by ``strict``: nothing written); ``error`` (bad input);
#: ``skipped`` (outputs exist).
STATUSES = ("ok", "uncertain", "not_single_body", "refused", "error", "skipped")
#: the second start of a model on the all-ages body (:class:`Fitter`'s ``second_start``)
SECOND_START = "anny22"
#: Shape coefficients the refinement fits by default, per body name (:class:`Fitter`'s ``shape_betas``):
#: all 32 that ``anny_allages`` stores, so that a build outside the network's 16 (a very thin waist: 3.4 cm
#: off at 16) is measured right (experiments/fitting/shape_betas.md); other bodies: the network's own.
DEFAULT_SHAPE_BETAS = {"anny_allages": 32}
#: When the two starts of a scan stop being refined together: at each ``(fraction of the iterations,
#: margin)``, the start whose surface score exceeds the other's by more than the margin stops there
#: (at 0.6 the worse one always does), so most scans refine one start for most of the iterations
#: (experiments/fitting/stops.md).
SECOND_START_STOPS = ((0.2, 0.10), (0.4, 0.02), (0.6, 0.0))
#: Statuses whose outputs are written.
WRITTEN_STATUSES = ("ok", "uncertain")
#: A part is *seen* when at least this share of the fitted points is predicted on it...
MIN_PART_SHARE = 0.002
#: ... and at least this many points.
MIN_PART_POINTS = 10


#: A camera position given with a scan (:meth:`Fitter.prepare`'s ``viewpoint``) nearer the body's centre than
#: this (metres) is an error: no camera sees a body from inside it.
MIN_CAMERA_GAP_M = 0.3


@dataclass
class FitResult:
    """The fit of one scan. Geometry is in the scan's frame and units unless the name says metres.

    ``vertices [V, 3]``, ``faces [F, 3]``, ``joints [22, 3]``: fitted mesh and joints (scan units).
    ``betas [nb]``; ``pose_aa [22, 3]`` local axis-angle (root first: the global orientation);
    ``global_rotmats [22, 3, 3]`` world rotation of each part; ``transl_m [3]`` translation in metres
    such that ``body(betas, pose_aa, transl_m).vertices / scale_to_m`` is ``vertices``.
    ``point_labels [N]`` predicted part of each input row (-1 for dropped NaN rows and removed clutter),
    ``point_confidence [N]`` its probability, ``point_fit_labels [N]`` part of the nearest fitted
    vertex, ``point_distance [N]`` distance to it (scan units, inf for dropped NaN rows),
    ``point_clutter [N]`` what clutter removal did with each row (:data:`arteq.fit.clean.CODES`: 0 kept,
    1 plane, 2 outlier, 3 separate cluster, 4 a flat object touching the body; -1 NaN). ``clean``: the
    :class:`CleanResult` (or None).
    ``quality``: :func:`arteq.fit.quality.fit_quality` values; ``uncertain_reason``: why the check
    doubts the fit (status ``uncertain`` or ``refused``; empty otherwise); ``timings`` in seconds.
    ``scan_mode``: ``full`` or ``partial`` (one camera's view), ``scan_mode_reason`` how it was chosen,
    ``view_dir [3]`` the direction from the body toward the camera (partial scans), ``one_sidedness`` the
    score of :func:`arteq.fit.partial.one_sidedness`; ``part_points [22]`` the fitted points (``points``)
    predicted on each part, ``parts_seen [22]`` whether that is enough to call the part seen
    (:data:`MIN_PART_SHARE` of the points, at least :data:`MIN_PART_POINTS`). ``start_hypothesis``: for a
    refined partial scan, the refinement's start (:func:`arteq.fit.partial.pick_starts`'s info: ``picked``
    ``network`` / ``untwisted`` / ``turned <deg>``, the parts untwisted, every start's score); for a full
    scan refined from a second start too (``Fitter(second_start=...)``), ``picked`` (``network`` or the
    second model's name), both starts' surface scores (cm) and the ``iteration`` where they were compared
    (the worse one stopped there; the refinement's count: both ran to the end).
    ``crossing``: for a full scan that tried swapped limb pairs (:mod:`arteq.fit.crossing`), the fit's
    score, each pair's score (cm; where it stopped for those in ``stopped``) and the pair taken (``""``:
    none); ``lost_hand``: the lost-hand step's record where it ran (:func:`arteq.fit.lost_hand.fit_lost_hand`;
    an arm it put back is also in ``taken``, ``hand_<arm>``); None when nothing was tried. ``retry``: for a
    doubtful full scan fitted again (``Fitter(retries=K)``), every fit's surface score (cm; the first
    fit's first), which reading each fit started from (``reads``: ``first``, ``retry K``, ``torso
    turned``) and the index of the one kept; None otherwise.
    ``clothing``: for a fit refined as the skin under clothes (``Fitter(clothing=...)``), the thickness (cm),
    the covered parts, the iterations and how far the vertices moved from the clothed fit (``moved_cm``,
    mean); None otherwise. Vertices, joints, pose, shape, point distances and the Anny export are then the
    skin's; ``quality`` is the clothed fit's.
    ``hand_curl [2]``: the fingers' curl of the left and right hand (0 Anny's flat hand .. 1 closed;
    :mod:`arteq.fit.hands`, the last pass before the Anny export; vertices, wrists' pose and point distances
    are then the curled hands'; ``quality`` is the check's, before it); None where the pass did not run.
    """

    name: str
    status: str = "ok"
    message: str = ""
    units: str = "m"
    scale_to_m: float = 1.0
    vertices: np.ndarray | None = None
    faces: np.ndarray | None = None
    joints: np.ndarray | None = None
    betas: np.ndarray | None = None
    pose_aa: np.ndarray | None = None
    global_rotmats: np.ndarray | None = None
    transl_m: np.ndarray | None = None
    point_labels: np.ndarray | None = None
    point_confidence: np.ndarray | None = None
    point_fit_labels: np.ndarray | None = None
    point_distance: np.ndarray | None = None
    scan_points: np.ndarray | None = None  # the points fitted (file units), for meshes and previews
    scan_labels: np.ndarray | None = None  # predicted part of each of scan_points
    point_clutter: np.ndarray | None = None
    clean: CleanResult | None = None
    clutter_points: np.ndarray | None = None  # up to 5000 of the removed points (file units), for previews
    anny: dict | None = None  # arteq.fit.anny_params.AnnyExport.export: phenotype, pose, measurements
    anny_note: str = ""  # why there is no Anny export (anny not installed, not an Anny body, failed)
    quality: dict = field(default_factory=dict)
    uncertain_reason: str = ""
    timings: dict = field(default_factory=dict)
    body_model: str = ""
    checkpoint: str = ""
    refined: bool = False
    warnings: list[str] = field(default_factory=list)
    scan_mode: str = "full"
    scan_mode_reason: str = ""
    view_dir: np.ndarray | None = None
    one_sidedness: float | None = None
    part_points: np.ndarray | None = None
    parts_seen: np.ndarray | None = None
    start_hypothesis: dict | None = None  # the refinement's start: partial scans' or the second start's pick
    crossing: dict | None = None  # full scans: swapped limb pairs tried (fit.crossing.try_swaps)
    retry: dict | None = None  # full scans fitted again (Fitter's retries): every fit's score, the one kept
    clothing: dict | None = None  # the skin under the clothes (Fitter's clothing): thickness, parts, moved
    hand_curl: np.ndarray | None = None  # [2] the fitted fingers' curl, left and right hand (Fitter's hands)

    def seen_names(self, seen: bool = True) -> list[str]:
        """Names of the parts seen (or, ``seen=False``, not seen) in the scan."""
        from arteq.body.skeleton import JOINT_NAMES

        if self.parts_seen is None:
            return []
        return [n for n, s in zip(JOINT_NAMES, self.parts_seen) if bool(s) == seen]

    @property
    def ok(self) -> bool:
        return self.status == "ok"

    @property
    def written(self) -> bool:
        """Whether this fit's outputs are written (``ok`` or ``uncertain``)."""
        return self.status in WRITTEN_STATUSES

    def arrays(self) -> dict[str, Any]:
        """The ``.npz`` content (see docs/fitting.md)."""
        q = {f"quality_{k}": v for k, v in self.quality.items() if k != "flags" and not isinstance(v, str)}
        c = self.clean.counts if self.clean is not None else {}
        planes = self.clean.planes if self.clean is not None else []
        clutter = {
            "point_clutter": self.point_clutter,
            "clutter_removed": np.bool_(self.clean is not None),
            **{f"clutter_{k}": np.int64(c.get(k, 0)) for k in ("plane", "outlier", "cluster", "object")},
            # each removed plane as [nx, ny, nz, d] with n.p + d = 0 for p in the scan's units
            "clutter_planes": np.array(
                [[*pl["normal"], pl["offset"] / self.scale_to_m] for pl in planes], dtype=np.float64
            ).reshape(-1, 4),
        }
        from arteq.fit.anny_params import npz_arrays

        return {
            "betas": self.betas,
            "pose": self.pose_aa,
            "global_rotmats": self.global_rotmats,
            "transl": self.transl_m,
            "joints": self.joints,
            "vertices": self.vertices,
            "point_labels": self.point_labels,
            "point_confidence": self.point_confidence,
            "point_fit_labels": self.point_fit_labels,
            "point_distance": self.point_distance,
            "body_model": np.str_(self.body_model),
            "checkpoint": np.str_(self.checkpoint),
            "units": np.str_(self.units),
            "scale_to_m": np.float64(self.scale_to_m),
            "refined": np.bool_(self.refined),
            "status": np.str_(self.status),
            "uncertain_reason": np.str_(self.uncertain_reason),
            "quality_flags": np.str_(" ".join(self.quality.get("flags", []))),
            "scan_mode": np.str_(self.scan_mode),
            "scan_mode_reason": np.str_(self.scan_mode_reason),
            "view_dir": np.asarray(self.view_dir if self.view_dir is not None else np.full(3, np.nan)),
            "one_sidedness": np.float64(np.nan if self.one_sidedness is None else self.one_sidedness),
            "part_points": self.part_points,
            "parts_seen": self.parts_seen,
            "crossing_taken": np.str_((self.crossing or {}).get("taken", "")),
            # cm of cloth the body was fitted under (Fitter's clothing; 0: the scanned surface itself)
            "clothing_cm": np.float64((self.clothing or {}).get("thickness_cm", 0.0)),
            # the fingers' curl, left and right hand, 0 flat .. 1 closed (Fitter's hands; NaN: not fitted)
            "hand_curl": np.asarray(self.hand_curl if self.hand_curl is not None else np.full(2, np.nan)),
            **clutter,
            **npz_arrays(self.anny),
            **{k: np.asarray(v, dtype=np.float64) for k, v in q.items()},
        }

    def to_json(self, source: str = "") -> dict[str, Any]:
        """``<name>.json``: the fit in words and numbers a person can read (arrays stay in the npz)."""
        from arteq.fit.anny_params import json_section

        q = {k: (round(v, 4) if isinstance(v, float) else v) for k, v in self.quality.items()}
        return {
            "name": self.name,
            "source": source,
            "status": self.status,
            "message": self.message,
            "uncertain_reason": self.uncertain_reason,
            "units": self.units,
            "body_model": self.body_model,
            "checkpoint": self.checkpoint,
            "refined": self.refined,
            "scan_mode": self.scan_mode,
            "scan_mode_reason": self.scan_mode_reason,
            "view_dir": [round(float(x), 4) for x in self.view_dir] if self.view_dir is not None else None,
            "parts_seen": self.seen_names(True),
            "parts_unseen": self.seen_names(False),
            "betas": [round(float(b), 4) for b in self.betas] if self.betas is not None else None,
            "quality": q,
            "clutter_removed": self.clean.counts if self.clean is not None else None,
            # flat objects touching the body removed after a doubted fit (step 6c): points, extent_m, band_m
            "clutter_objects": self.clean.objects if self.clean is not None else None,
            "start": self.start_hypothesis,
            "crossing": self.crossing,
            "retry": self.retry,
            "clothing": self.clothing,
            "hand_curl": None if self.hand_curl is None else [round(float(x), 3) for x in self.hand_curl],
            "anny": json_section(self.anny, self.anny_note),
            "seconds": {k: round(v, 3) for k, v in self.timings.items()},
        }

    def summary_row(self) -> dict[str, Any]:
        q = self.quality
        return {
            "name": self.name,
            "status": self.status,
            "message": self.message,
            "uncertain_reason": self.uncertain_reason,
            "inlier_frac": q.get("inlier_frac"),
            "rmse_in_cm": q.get("rmse_in_cm"),
            "mean_dist_cm": q.get("mean_dist_cm"),
            "coverage": q.get("coverage"),
            "label_agree": q.get("label_agree"),
            "parts_covered": q.get("parts_covered"),
            "max_abs_beta": q.get("max_abs_beta"),
            "extent_m": q.get("extent_m"),
            "noise_mm": q.get("noise_mm"),
            "denoised": q.get("denoised"),
            "flags": " ".join(q.get("flags", [])),
            "scan_mode": self.scan_mode,
            "parts_seen": int(self.parts_seen.sum()) if self.parts_seen is not None else None,
            "parts_unseen": " ".join(self.seen_names(False)),
            "start": (self.start_hypothesis or {}).get("picked", ""),
            "crossing": (self.crossing or {}).get("taken", ""),
            "retry": "" if self.retry is None else self.retry["picked"],
            "clothing_cm": (self.clothing or {}).get("thickness_cm", 0.0),
            **{
                f"removed_{k}": (self.clean.counts[k] if self.clean is not None else None)
                for k in ("plane", "outlier", "cluster", "object")
            },
            **_anny_row(self.anny),
            "seconds": self.timings.get("total"),
            "anny_seconds": self.timings.get("anny"),
        }


def _anny_row(anny: dict | None) -> dict[str, Any]:
    """Summary columns of the Anny export (None without one)."""
    m = anny["measurements"] if anny else {}
    return {
        "stature_cm": round(m["stature_m"] * 100, 2) if anny else None,
        "waist_cm": round(m["waist_circumference_m"] * 100, 2) if anny else None,
        "mass_kg": round(m["mass_kg"], 2) if anny else None,
        "bmi": round(m["bmi"], 2) if anny else None,
        "age_years": round(anny["age_years"], 1) if anny else None,
        "anny_rebuild_mm": round(anny["rebuild_mm"]["mean"], 2) if anny else None,
    }


class Hyperparameters(dict):
    """A checkpoint's hyper-parameters (``net``, ``body_model``, ``data``...): a dict whose keys also read as
    attributes, like Lightning's ``hparams``."""

    def __getattr__(self, key: str) -> Any:
        try:
            return self[key]
        except KeyError:
            raise AttributeError(key) from None


def turn_back(pred: dict[str, torch.Tensor], turn: torch.Tensor) -> dict[str, torch.Tensor]:
    """The outputs of a network that read clouds turned by ``turn [B, 3, 3]`` (``points @ turn^T``), in the
    clouds' own frame: the global rotations (``global_rotmats``, ``rot_mean``) and the root's local rotation
    turned by ``turn^T``; per-point outputs, the other joints' local rotations and the shape need nothing
    (``rot_weights``, over the group's elements, stay the turned cloud's). The translation is not turned:
    :class:`FitNetwork` places the body on the cloud again."""
    out = dict(pred)
    back = turn.transpose(-1, -2)[:, None]
    for k in ("global_rotmats", "rot_mean"):
        if k in out:
            out[k] = back.to(out[k].dtype) @ out[k]
    local = out["local_rotmats"].clone()
    local[:, 0] = back[:, 0].to(local.dtype) @ local[:, 0]
    out["local_rotmats"] = local
    return out


class FitNetwork(torch.nn.Module):
    """A trained network with its body, for inference without Lightning: what
    :class:`arteq.training.ArtEqModule` computes at test time, for the fields fitting needs (the network's
    outputs plus ``transl [B, 3]``, the translation placing the predicted body on the cloud).

    Built by :func:`load_network` from a checkpoint's ``hyper_parameters`` (``net``: the network config for
    :func:`arteq.models.registry.build_net`; ``body_model``: the body for :func:`arteq.body.create_body`)
    and the ``net.*`` weights of its ``state_dict``."""

    def __init__(self, net: torch.nn.Module, body: torch.nn.Module, hparams: dict[str, Any]):
        from arteq.models.placement import body_centroid_matrix

        super().__init__()
        self.net, self.body = net, body
        self.hparams = Hyperparameters(hparams)
        for p in self.body.parameters():
            p.requires_grad_(False)
        self.register_buffer("centroid_matrix", body_centroid_matrix(body, net.num_parts), persistent=False)

    def forward(
        self,
        points: torch.Tensor,
        turn: torch.Tensor | None = None,
        torso_shift: torch.Tensor | None = None,
        turn_torso: torch.Tensor | None = None,
    ) -> dict[str, torch.Tensor]:
        """``turn [B, 3, 3]`` (optional): the network reads each cloud turned by it and its outputs are turned
        back into the cloud's frame (:func:`turn_back`): another reading of the same cloud, for a network
        equivariant to a finite group of rotations only. ``torso_shift [B, 3]`` (optional, the clouds'
        frame): moves the torso centre that splits left from right (:class:`arteq.models.ArtEqNet`); for
        networks without that centre it is ignored. ``turn_torso [B]`` bool (optional): those clouds' torso
        read turned round (:class:`arteq.models.ArtEqNet`'s ``turn_torso``; an error for networks without
        it)."""
        from arteq.models.placement import estimate_translation
        from arteq.models.precision import full_precision, upcast

        kw = {}
        if torso_shift is not None and getattr(self.net, "accepts_torso_shift", False):
            shift = torso_shift.to(points.dtype)  # turned with its cloud
            kw["torso_shift"] = shift if turn is None else (turn.to(shift.dtype) @ shift[..., None])[..., 0]
        if turn_torso is not None:
            kw["turn_torso"] = turn_torso
        if turn is None:
            pred = self.net(points, **kw)
        else:
            pred = turn_back(self.net(points @ turn.transpose(-1, -2).to(points.dtype), **kw), turn)
        with full_precision(points):  # the body model (LBS) and placement in float32 at least
            posed = self.body(betas=upcast(pred["betas"]), pose=upcast(pred["local_rotmats"]))
            pred["transl"] = estimate_translation(
                posed.vertices, self.centroid_matrix, points, pred["pool_weights"]
            )
        return pred


def load_network(path: str | Path) -> FitNetwork:
    """The :class:`FitNetwork` of a checkpoint file (read by :func:`arteq.io.runs.read_checkpoint`,
    weights-only), in eval mode on the CPU; imports neither Lightning nor the training code.
    Raises ``ValueError`` naming the file when it is not a trained arteq model."""
    from arteq.body.factory import create_body
    from arteq.io.runs import read_checkpoint
    from arteq.models.registry import build_net

    state = read_checkpoint(path)
    hp = state.get("hyper_parameters") if isinstance(state, dict) else None
    if not isinstance(hp, dict) or "state_dict" not in state or "net" not in hp:
        keys = sorted(state) if isinstance(state, dict) else type(state).__name__
        raise ValueError(
            f"{path}: not an arteq checkpoint (needs state_dict and hyper_parameters.net; has {keys})"
        )
    body = create_body(hp.get("body_model") or {})
    net_cfg = dict(hp["net"])
    net_cfg.setdefault("num_betas", body.num_betas)  # as ArtEqModule builds it
    net = build_net(net_cfg)
    weights = {k[4:]: v for k, v in state["state_dict"].items() if k.startswith("net.")}
    missing, unexpected = net.load_state_dict(weights, strict=False)
    if missing or unexpected:
        raise ValueError(
            f"{path}: the weights do not match the network its config builds "
            f"(missing {missing[:5]}, unexpected {unexpected[:5]})"
        )
    return FitNetwork(net, body, hp).eval()


def resolve_device(device: str) -> torch.device:
    if device == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if device not in ("cpu", "cuda") and not device.startswith("cuda:"):
        raise ValueError(f"device must be cpu, cuda or auto, got {device!r}")
    if device.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError("device cuda asked for, but torch sees no CUDA GPU (use --device cpu or auto)")
    return torch.device(device)


def resample(points: np.ndarray, count: int, rng: np.random.Generator, jitter: float = 0.002) -> np.ndarray:
    """``count`` rows of ``points``: a random subset without replacement when there are enough, else all
    of them plus random repeats moved by ``jitter`` (metres, Gaussian) so that no two coincide."""
    n = len(points)
    if n >= count:
        return points[np.sort(rng.choice(n, count, replace=False))]
    extra = points[rng.choice(n, count - n, replace=True)] + rng.normal(0, jitter, (count - n, 3))
    return np.concatenate([points, extra])


#: :class:`Fitter`'s ``net_draws``: the network's prediction averaged over this many random subsets of a scan
#: (experiments/fitting/net_draws.md)
NET_DRAWS = 4
#: :class:`Fitter`'s ``retries`` (``arteq-fit --retries K``): a full scan's fit the check doubts and whose
#: surface score (:func:`arteq.fit.crossing.surface_score`, cm) is above :data:`RETRY_ABOVE_CM` is fitted
#: again K times, from the network's reading of the scan with other draws and then turned by
#: :func:`retry_turns`, and the best one kept if it beats the first fit by :data:`RETRY_MIN_GAIN`. One by
#: default since 2026-12-05: on the check's labelled sets 1-2 more usable fits of 45 per seed (3 retries:
#: 2-3) and none lost, some lost fits further off, 21 % more time there (57 % with 3), nothing on scans the
#: check passes (experiments/fitting/retries.md, last section).
RETRIES = 1
RETRY_ABOVE_CM = 2.0
#: a retry is kept only when its surface score is below the first fit's by this share at least (as
#: :attr:`arteq.fit.crossing.CrossingConfig.min_gain`): near ties are coin flips between a fit and a lost one
#: (experiments/scan_model/spine/README.md, the torso retry).
RETRY_MIN_GAIN = 0.005
#: :class:`Fitter`'s ``torso_retry``: the retries of a doubtful full scan (as for :data:`RETRIES`) include
#: one from the network's reading with the torso turned round (:class:`arteq.models.ArtEqNet`'s
#: ``turn_torso``: the back read as the front, so every limb took its mirror's side; the lost bows,
#: experiments/scan_model/spine/README.md), for networks that split sides in the torso's frame.
TORSO_RETRY = True


def retry_turns(count: int) -> np.ndarray:
    """``[count, 3, 3]`` fixed rotations for :class:`Fitter`'s retries: the identity (other draws only), then
    uniform random ones (seed 0: the same on every run)."""
    q = np.random.default_rng(0).normal(size=(max(count, 0), 4))
    q[:1] = [1.0, 0.0, 0.0, 0.0]
    w, x, y, z = (q / np.linalg.norm(q, axis=1, keepdims=True)).T
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], 1)  # fmt: skip


def mean_prediction(pred: dict[str, torch.Tensor], draws: int) -> dict[str, torch.Tensor]:
    """The network's predictions for ``draws`` clouds of each scan (rows ``i * draws + d``) averaged per
    scan: the chordal mean of each joint's global rotation (local rotations rebuilt from them), the mean
    betas and translation. ``[B * draws, ...]`` -> ``[B, ...]`` for those three keys."""
    import roma

    from arteq.body.skeleton import PARENTS, local_to_global

    local = pred["local_rotmats"]
    glob = local_to_global(local.double()).reshape(-1, draws, *local.shape[1:])
    g = roma.special_procrustes(glob.sum(1))  # [B, K, 3, 3]
    out_local = g[:, [max(p, 0) for p in PARENTS]].transpose(-1, -2) @ g
    out_local[:, 0] = g[:, 0]
    return {
        "local_rotmats": out_local.to(local.dtype),
        **{k: pred[k].reshape(-1, draws, *pred[k].shape[1:]).mean(1) for k in ("betas", "transl")},
    }


class Fitter:
    """A loaded model ready to fit clouds (keeps the network, body and tables between calls).

    Args:
        ckpt: checkpoint path or shipped model name (default: :data:`arteq.pretrained.DEFAULT_MODEL`,
            the scan-fitting model ``anny_scan``).
        device: ``cpu``, ``cuda`` or ``auto``.
        refine: run :func:`arteq.fit.refine.refine` after the network.
        points: points of the input used by refinement and the quality check (resampled).
        refine_config: :class:`RefineConfig`; ``thresholds``: :class:`QualityThresholds`.
        clean: remove clutter (floors, walls, stray points, separate objects) before the network;
            ``clean_config``: :class:`CleanConfig`.
        anny: Anny's phenotype, pose and body measurements per fit (:mod:`arteq.fit.anny_params`):
            ``True`` (error without ``anny`` or for a body not in Anny's topology), ``False``, or ``None``
            (default: when ``anny`` is installed and the body is an Anny body).
        check: apply the quality check (:mod:`arteq.fit.quality`): a scan that is not one body gets
            ``not_single_body`` (nothing written), a doubtful fit ``uncertain`` (written, flagged); off,
            every fit is ``ok`` and a failed check is a warning only.
        strict: refuse uncertain fits too (status ``refused``, nothing written).
        seed: resampling seed (each scan is resampled with it: results do not depend on batching).
        partial: ``None`` (default): detect one-sided scans (:mod:`arteq.fit.partial`); ``True``: treat
            every scan as one camera's view (the direction estimated unless ``view_dir`` or the file gives
            it); ``False``: every scan is a full surface. A partial scan is placed by
            :func:`arteq.models.placement.align_translation` and refined with the model -> scan term on
            the vertices its camera sees.
        view_dir: ``[3]`` direction from the body toward the camera, in the scans' frame (implies partial).
        hypotheses: partial scans' refinement starts (:func:`arteq.fit.partial.pick_starts`): ``True``
            (default, :class:`arteq.fit.partial.HypothesisConfig`: the network's pose with the parts it
            turned the wrong way round turned back), a ``HypothesisConfig``, or ``False`` (the network's
            start only). Full scans never use them.
        crossing: crossed limbs on full scans (:mod:`arteq.fit.crossing`): ``True`` (default,
            :class:`arteq.fit.crossing.CrossingConfig`), a ``CrossingConfig``, or ``False``: a refined fit
            the check doubts, or one with a left / right pair of limb segments close together, is refitted
            with each pair swapped and the swap kept when it explains the scan better; with
            ``CrossingConfig.reach`` also from each limb placed on the points the fit leaves off
            (:mod:`arteq.fit.reach`).
        second_start: a second network whose pose starts a second refinement of every full scan; the fit
            that explains the scan better (:func:`arteq.fit.crossing.surface_score`) is kept, the worse
            start stopping as soon as it is clearly worse (:data:`SECOND_START_STOPS`;
            experiments/fitting/second_start.md). ``None`` (default): :data:`SECOND_START` (the research
            model ``anny22``, everyday adults, more precise in its poses) for a model on the all-ages body,
            none otherwise; a checkpoint path or shipped name; ``False``: none. It lends its local rotations
            and part probabilities; the shape stays this model's, the translation is placed for it.
        denoise_above_mm: a full scan whose noise (:func:`arteq.fit.conditions.scan_conditions`) is above
            this reaches the network smoothed (:func:`arteq.fit.conditions.denoise`; the refinement and the
            check use the raw points); ``None``: never (experiments/fitting/scan_defects.md).
        net_draws: the network reads this many random subsets of its input size (``num_points`` of its
            training, 500 for the shipped models) from each scan and its pose, shape and translation are
            averaged over them (:func:`mean_prediction`; the refinement's part labels too): one subset's
            prediction moves by centimetres from draw to draw. ``None``: :data:`NET_DRAWS`
            (experiments/fitting/net_draws.md).
        shape_betas: shape coefficients the refinement fits (and the fit's ``betas`` hold): ``None``
            (default) the body's entry in :data:`DEFAULT_SHAPE_BETAS` (``anny_allages``: all 32 it stores),
            else the network's own count; more than the network's (up to what the body's file stores) adds
            components the network does not predict, started at 0 and fitted to the scan; the network's own
            count fits only those (experiments/fitting/shape_betas.md).
        clothing: the scans are of dressed people: ``None`` (default) fits the scanned surface; a
            :class:`arteq.fit.clothing.ClothingConfig` (or a thickness in cm, the default parts) refines every
            written fit once more as the skin under that much cloth
            (:func:`arteq.fit.clothing.under_clothes`; experiments/fitting/clothing.md). The check judges the
            clothed fit; ``FitResult.clothing`` records the pass.
        retries, retry_above_cm: a doubtful full scan's fit whose surface score is above
            ``retry_above_cm`` (cm) is fitted again ``retries`` times from other readings of the scan
            (:meth:`_retry`; ``None``: :data:`RETRIES`, :data:`RETRY_ABOVE_CM`).
        torso_retry: those retries include one from the network's reading with the torso turned round
            (``None``: :data:`TORSO_RETRY`; networks that do not split sides in the torso's frame never).
        hands: the hands' last pass on every written full scan's fit (:func:`arteq.fit.hands.fit_hands`:
            each hand's finger curl and wrist fitted to the points it explains; bodies built from Anny
            only): ``True`` (default) or a :class:`arteq.fit.hands.HandsConfig`; ``False`` leaves the hands
            flat as the refinement fits them (experiments/fitting/native_anny/README.md).
    """

    def __init__(
        self,
        ckpt: str | Path | None = None,
        device: str = "auto",
        refine: bool = True,
        points: int = 5000,
        refine_config: RefineConfig | None = None,
        thresholds: QualityThresholds | None = None,
        check: bool = True,
        seed: int = 0,
        clean: bool = True,
        clean_config: CleanConfig | None = None,
        anny: bool | None = None,
        strict: bool = False,
        partial: bool | None = None,
        view_dir: np.ndarray | list[float] | None = None,
        hypotheses: Any = True,
        crossing: CrossingConfig | bool = True,
        second_start: str | Path | bool | None = None,
        denoise_above_mm: float | None = 10.0,
        shape_betas: int | None = None,
        net_draws: int | None = None,
        retries: int | None = None,
        retry_above_cm: float | None = None,
        clothing: Any = None,
        torso_retry: bool | None = None,
        hands: Any = True,
    ) -> None:
        from arteq.pretrained import resolve_checkpoint
        from arteq.runtime import tune_cpu_allocator

        # large temporaries (the network's neighbour gathers) reused, not page-faulted in again on every
        # call: the network pass 1.66 -> 0.92 s per 16 clouds on two cores (experiments/fitting/speed.md)
        tune_cpu_allocator()
        if view_dir is not None:
            view_dir = np.asarray(view_dir, dtype=np.float64).reshape(-1)
            if view_dir.shape != (3,) or not np.isfinite(view_dir).all() or not np.linalg.norm(view_dir) > 0:
                raise ValueError(f"view_dir must be 3 finite numbers, not all 0, got {view_dir.tolist()}")
            view_dir = view_dir / np.linalg.norm(view_dir)
            if partial is False:
                raise ValueError("view_dir is for partial scans: it cannot go with partial=False")
        self.partial, self.view_dir = partial, view_dir
        if hypotheses is True:
            from arteq.fit.partial import HypothesisConfig

            hypotheses = HypothesisConfig()
        self.hypotheses = hypotheses or None
        self.crossing = CrossingConfig() if crossing is True else (crossing or None)

        if points < MIN_POINTS:
            raise ValueError(f"points must be >= {MIN_POINTS}, got {points}")
        self.device = resolve_device(device)
        self.ckpt_path = resolve_checkpoint(ckpt)
        try:
            module = load_network(self.ckpt_path)
        except ValueError:
            raise
        except Exception as exc:  # noqa: BLE001 - name the file whatever went wrong
            raise ValueError(
                f"{self.ckpt_path}: cannot load the checkpoint ({type(exc).__name__}: {exc})"
            ) from exc
        self.module = module.eval().to(self.device)
        self.body = self._shape_body(shape_betas)
        data = dict(self.module.hparams.get("data") or {})
        self.net_points = int(data.get("num_points") or 5000)
        digest = hashlib.sha256(self.ckpt_path.read_bytes()).hexdigest()[:12]
        self.checkpoint_id = f"{self.ckpt_path.name}@sha256:{digest}"
        self.refine = refine
        self.points = int(points)
        self.refine_config = refine_config or RefineConfig()
        self.thresholds = thresholds or QualityThresholds()
        self.check = check
        self.strict = strict
        self.seed = seed
        net_draws = NET_DRAWS if net_draws is None else net_draws
        if int(net_draws) < 1:
            raise ValueError(f"net_draws must be >= 1, got {net_draws}")
        self.net_draws = int(net_draws)
        self.retries = RETRIES if retries is None else int(retries)
        if self.retries < 0:
            raise ValueError(f"retries must be >= 0, got {retries}")
        self.retry_above_cm = RETRY_ABOVE_CM if retry_above_cm is None else float(retry_above_cm)
        torso_retry = TORSO_RETRY if torso_retry is None else bool(torso_retry)
        self.torso_retry = torso_retry and getattr(self.module.net, "sides", None) in ("torso", "roots")
        self.clean = clean
        self.clean_config = clean_config or CleanConfig()
        if clothing is not None and not isinstance(clothing, ClothingConfig):
            clothing = ClothingConfig(thickness_cm=float(clothing))
        if clothing is not None and not refine:
            raise ValueError("clothing is a last refinement: it needs refine=True (drop --no-refine)")
        self.clothing = clothing
        off = "off (hands=False)" if hands is False else "off (no refinement)"
        self.hand_curl, self.hands_config, self.hands_note = None, None, off
        if hands is not False and refine:
            from arteq.body.hands import hands_for
            from arteq.fit.hands import HandsConfig

            try:
                self.hand_curl = hands_for(self.body)
                no_bones = f"off: {self.body.name} has no finger bones"
                self.hands_note = "" if self.hand_curl is not None else no_bones
            except RuntimeError as exc:  # not cached and no anny to build it: the hands stay flat
                self.hands_note = f"off: {exc}"
            self.hands_config = hands if isinstance(hands, HandsConfig) else HandsConfig()
        self.denoise_above_mm = denoise_above_mm
        self.faces = self.body.faces.cpu().numpy()
        self.vertex_parts = self.body.part_labels.cpu().numpy()
        self.subset = body_tables(self.body, self.refine_config.m2s_vertices).m2s_subset.cpu().numpy()
        self.second, self.second_name = self._second_network(second_start)
        self.anny_export, self.anny_note = None, "off (anny=False)"
        if anny is not False:
            from arteq.fit.anny_params import AnnyExport, AnnyUnavailable

            try:
                self.anny_export = AnnyExport(self.body)
                self.anny_note = ""
            except AnnyUnavailable as exc:
                if anny:
                    raise
                self.anny_note = f"off: {exc}"
        # modules every fit uses, imported at set-up with the model rather than inside the first scan's timed
        # stages (scipy.spatial alone took 0.7 s of a first scan's "clean" time)
        import scipy.spatial  # noqa: F401

        import arteq.fit.partial  # noqa: F401

    def _shape_body(self, shape_betas: int | None) -> torch.nn.Module:
        """The body the refinement fits: the network's, or the same body with ``shape_betas`` components
        (the network's betas are padded with zeros: :meth:`_network`)."""
        from arteq.body.factory import create_body

        own = self.module.body
        default = shape_betas is None
        if default:
            shape_betas = DEFAULT_SHAPE_BETAS.get(getattr(own, "name", ""), own.num_betas)
        if int(shape_betas) == own.num_betas:
            return own
        if int(shape_betas) < own.num_betas:
            raise ValueError(
                f"shape_betas={shape_betas}: fewer than the {own.num_betas} the network predicts "
                f"({self.ckpt_path.name})"
            )
        spec = {**dict(self.module.hparams.get("body_model") or {}), "num_betas": int(shape_betas)}
        try:
            body = create_body(spec)
        except ValueError as exc:
            if default:  # a body file that stores fewer components than the default: the network's own
                import warnings

                warnings.warn(f"{self.ckpt_path.name}: fitting the network's {own.num_betas} shape "
                              f"components ({exc})", stacklevel=3)  # fmt: skip
                return own
            raise ValueError(f"shape_betas={shape_betas}: {exc}") from exc
        for p in body.parameters():
            p.requires_grad_(False)
        return body.to(self.device)

    def _second_network(self, spec: str | Path | bool | None) -> tuple[Any, str | None]:
        """The second start's network (:class:`FitNetwork`) and name, or ``(None, None)``; see the class
        docstring."""
        from arteq.pretrained import resolve_checkpoint

        if spec is False or (spec is None and getattr(self.body, "name", "") != "anny_allages"):
            return None, None
        path = resolve_checkpoint(SECOND_START if spec is None or spec is True else spec)
        if path.resolve() == self.ckpt_path.resolve():
            return None, None  # the model itself: nothing to add
        try:
            net = load_network(path)
        except Exception as exc:  # noqa: BLE001 - name the file whatever went wrong
            raise ValueError(
                f"second_start {path}: cannot load the checkpoint ({type(exc).__name__}: {exc})"
            ) from exc
        own, other = self.module.net.num_parts, net.net.num_parts
        pa, pb = net.body.parents.cpu(), self.body.parents.cpu()
        if other != own or pa.shape != pb.shape or not torch.equal(pa, pb):
            raise ValueError(
                f"second_start {path}: its network has {other} parts on a {len(pa)}-joint skeleton, this "
                f"model {own} on {len(pb)} (or other parents): the pose cannot be carried over"
            )
        return net.eval().to(self.device), path.stem

    # ------------------------------------------------------------------ core (metres)
    def prepare(
        self, points: np.ndarray, units: str = "m", name: str = "points", viewpoint: np.ndarray | None = None
    ) -> dict[str, Any]:
        """Validate one cloud and convert it to metres; raises :class:`ScanError` naming ``name``.
        ``viewpoint``: the camera's position (``units``, the cloud's frame) when the file gives it."""
        if units not in UNITS:
            raise ValueError(f"units must be one of {sorted(UNITS)}, got {units!r}")
        pts = np.asarray(points, dtype=np.float64)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ScanError(f"{name}: points must be [N, 3], got shape {list(pts.shape)}")
        if len(pts) == 0:
            raise ScanError(f"{name}: no points")
        finite, keep = clean_points(pts, name)
        warnings = []
        if not keep.all():
            warnings.append(f"dropped {int((~keep).sum())} points with NaN/inf coordinates")
        if len(finite) < MIN_POINTS:
            raise ScanError(f"{name}: only {len(finite)} usable points, at least {MIN_POINTS} are needed")
        scale = UNITS[units]
        metres = finite * scale
        cleaned = None
        t0 = time.perf_counter()
        if self.clean:
            # units first (a millimetre file read as metres is not a room to clean), loosely: the room counts
            check_body_size(metres, name, units, limits_m=(0.4, 8.0))
            camera = None if viewpoint is None else np.asarray(viewpoint, float) * scale
            cleaned = clean_scan(metres, self.clean_config, viewpoint=camera)  # plane bands grow with range
            if cleaned.keep.sum() < MIN_POINTS:
                raise ScanError(
                    f"{name}: only {int(cleaned.keep.sum())} points left after clutter removal "
                    f"({cleaned.describe()}), at least {MIN_POINTS} are needed (try --no-clean)"
                )
        t_clean = time.perf_counter() - t0
        return self._item(name, metres, keep, cleaned, warnings, scale, units, viewpoint, t_clean)

    def _item(
        self, name: str, metres: np.ndarray, finite: np.ndarray, cleaned: CleanResult | None,
        warnings: list[str], scale: float, units: str, viewpoint: np.ndarray | None, t_clean: float,
    ) -> dict[str, Any]:  # fmt: skip
        """:meth:`prepare`'s item of the finite points ``metres`` (rows ``finite [N]`` of the file's) after
        clutter removal ``cleaned`` (None: off)."""
        t0 = time.perf_counter()
        clutter = np.full(len(finite), -1, dtype=np.int8)
        clutter[finite] = 0
        base_warnings = list(warnings)
        warnings = list(warnings)
        if cleaned is not None:
            clutter[finite] = cleaned.codes
            if cleaned.describe():
                warnings.append(cleaned.describe())
            body_m = metres[cleaned.keep]
        else:
            body_m = metres
        check_body_size(body_m, name, units)
        center = body_m.mean(0)
        if viewpoint is not None:
            gap = float(np.linalg.norm(np.asarray(viewpoint, float) * scale - center))
            if not gap >= MIN_CAMERA_GAP_M:  # NaN too
                where = np.round(np.asarray(viewpoint, float), 3).tolist()
                raise ScanError(
                    f"{name}: the file's camera position {where} lies {gap:.2f} m from the body's centre: "
                    "not where a camera saw it from (fit it with --no-partial, or fix the file's viewpoint)"
                )
        # measured on at most ``points`` distinct points, as many as the refinement and the check see
        sub = None
        if len(body_m) > self.points:
            sub = np.random.default_rng(self.seed).choice(len(body_m), self.points, replace=False)
        conditions = scan_conditions(body_m if sub is None else body_m[sub], seed=self.seed)
        t_clean += time.perf_counter() - t0
        return {"name": name, "centred": body_m - center, "center": center, "keep": clutter == 0,
                "conditions": conditions, "subsample": sub,
                "finite": finite, "finite_centred": metres - center, "clutter": clutter, "clean": cleaned,
                "clean_seconds": t_clean, "scale": scale, "units": units, "warnings": warnings,
                "base_warnings": base_warnings,
                "viewpoint": None if viewpoint is None else np.asarray(viewpoint, float) * scale - center,
                }  # fmt: skip

    @torch.no_grad()
    def _network(
        self, clouds: list[np.ndarray], turns: np.ndarray | None = None, shifts: np.ndarray | None = None,
        torso: np.ndarray | None = None,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        def tensor(a: np.ndarray | None) -> torch.Tensor | None:
            return None if a is None else torch.as_tensor(a, dtype=torch.float32, device=self.device)

        flags = None if torso is None else torch.as_tensor(torso, dtype=torch.bool, device=self.device)
        return self.module(tensor(np.stack(clouds)), tensor(turns), tensor(shifts), flags)

    @staticmethod
    def _torso_shifts(modes: list[dict[str, Any]], repeat: int = 1) -> np.ndarray | None:
        """``[len(modes) * repeat, 3]``: each partial scan's :func:`arteq.fit.partial.torso_shift` from its
        camera direction (zero for full scans) ``repeat`` times; None when no scan has one."""
        from arteq.fit.partial import torso_shift

        if not any(m["partial"] and m["view_dir"] is not None for m in modes):
            return None
        rows = [torso_shift(m["view_dir"]) if m["partial"] and m["view_dir"] is not None else np.zeros(3)
                for m in modes]  # fmt: skip
        return np.repeat(np.stack(rows), repeat, axis=0)

    def _turns(self, items: list[dict[str, Any]], repeat: int = 1) -> np.ndarray | None:
        """``[len(items) * repeat, 3, 3]``: each item's ``turn`` (a retry's, :meth:`_retry`; the identity for
        the others) ``repeat`` times; None when no item has one."""
        if all(it.get("turn") is None for it in items):
            return None
        turns = [np.eye(3) if it.get("turn") is None else np.asarray(it["turn"], np.float64) for it in items]
        return np.repeat(np.stack(turns), repeat, axis=0)

    def fit_prepared(self, items: list[dict[str, Any]]) -> list[FitResult]:
        """Fit a batch of :meth:`prepare` outputs."""
        import roma

        results, exports = self._fit_batch(items)
        if self.clean and self.clean_config.objects and self.refine and self.check:
            self._objects(items, results, exports)
        if (self.retries or self.torso_retry) and self.refine and self.check:
            self._retry(items, results, exports)
        if self.refine and self.check:
            self._second_person(items, results)
        if self.clothing is not None:  # refine is on (checked when built)
            self._under_clothes(items, results, exports)
        if self.hand_curl is not None:
            self._hands(items, results, exports)
        for r, (betas, pose_aa, verts_m) in zip(results, exports, strict=True):
            r.anny_note = self.anny_note
            if self.anny_export is not None and r.written:
                rot = roma.rotvec_to_rotmat(torch.as_tensor(pose_aa, dtype=torch.float64)).numpy()
                try:
                    r.anny = self.anny_export.export(betas, rot, verts_m, hand_curl=r.hand_curl)
                    r.timings["anny"] = r.anny["seconds"]
                except Exception as exc:  # noqa: BLE001 - the fit stands without its Anny export
                    r.anny_note = f"failed: {type(exc).__name__}: {exc}"
                    r.warnings.append(f"Anny export {r.anny_note}")
        return results

    def _under_clothes(
        self, items: list[dict[str, Any]], results: list[FitResult], exports: list[tuple]
    ) -> None:
        """Every written fit refined once more as the skin under :attr:`clothing`
        (:func:`arteq.fit.clothing.under_clothes`; a partial scan's model -> scan term on what its camera
        sees, as in its first refinement): ``results`` and ``exports`` updated in place."""
        import roma
        from scipy.spatial import cKDTree

        from arteq.fit.clothing import under_clothes
        from arteq.fit.partial import visibility_function

        rows = [i for i, r in enumerate(results) if r.written and r.vertices is not None]
        if not rows:
            return
        t0 = time.perf_counter()
        views = []
        for i in rows:
            mode = items[i].get("mode") or {}
            views.append((mode["camera"], mode["view_dir"]) if mode.get("partial") else None)
        visible = None
        if any(v is not None for v in views):
            incidence = body_tables(self.body, self.refine_config.m2s_vertices).incidence
            visible = visibility_function(self.body.faces, views, incidence)
        dtype = self.body.v_template.dtype
        pts, labels, rot, betas, transl = [], [], [], [], []
        for i in rows:
            r, c, s = results[i], items[i]["center"], results[i].scale_to_m
            pts.append(r.scan_points.astype(np.float64) * s - c)
            labels.append(r.scan_labels.astype(np.int64))
            rot.append(roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float64)))
            betas.append(torch.as_tensor(r.betas, dtype=torch.float64))
            transl.append(torch.as_tensor(r.transl_m - c, dtype=torch.float64))
        init = {"local_rotmats": torch.stack(rot), "betas": torch.stack(betas), "transl": torch.stack(transl)}
        out = under_clothes(
            self.body,
            torch.as_tensor(np.stack(pts), dtype=dtype, device=self.device),
            torch.as_tensor(np.stack(labels), device=self.device),
            {k: v.to(dtype=dtype, device=self.device) for k, v in init.items()},
            self.clothing,
            self.refine_config,
            m2s_visible=visible,
        )
        seconds = (time.perf_counter() - t0) / len(rows)
        pose_aa = roma.rotmat_to_rotvec(roma.special_procrustes(out.local_rotmats.double())).cpu().numpy()
        verts, joints = out.vertices.double().cpu().numpy(), out.joints.double().cpu().numpy()
        for j, i in enumerate(rows):
            r, it = results[i], items[i]
            c, s = it["center"], r.scale_to_m
            before = r.vertices.astype(np.float64) * s - c
            r.vertices = ((verts[j] + c) / s).astype(np.float32)
            r.joints = ((joints[j] + c) / s).astype(np.float32)
            r.betas = out.betas[j].double().cpu().numpy().astype(np.float32)
            r.pose_aa = pose_aa[j].astype(np.float32)
            r.global_rotmats = out.global_rotmats[j].double().cpu().numpy().astype(np.float32)
            r.transl_m = out.transl[j].double().cpu().numpy() + c
            finite = it.get("finite", it["keep"])
            d, vi = cKDTree(verts[j]).query(it.get("finite_centred", it["centred"]))
            r.point_fit_labels[finite] = self.vertex_parts[vi]
            r.point_distance[finite] = d / s
            moved = float(np.linalg.norm(verts[j] - before, axis=1).mean() * 100)
            r.clothing = {"thickness_cm": float(self.clothing.thickness_cm), "parts": self.clothing.parts,
                          "iters": int(self.clothing.iters), "moved_cm": round(moved, 3)}  # fmt: skip
            r.timings["clothing"] = seconds
            r.timings["total"] += seconds
            exports[i] = (out.betas[j].double().cpu().numpy(), pose_aa[j], verts[j] + c)

    def _hands(self, items: list[dict[str, Any]], results: list[FitResult], exports: list[tuple]) -> None:
        """The hands' last pass (:func:`arteq.fit.hands.fit_hands`) on every written full scan's fit:
        ``results`` and ``exports`` updated in place, the curls in :attr:`FitResult.hand_curl`."""
        import roma
        from scipy.spatial import cKDTree

        from arteq.fit.hands import fit_hands

        rows = [i for i, r in enumerate(results)
                if r.written and r.vertices is not None and r.scan_mode == "full"]  # fmt: skip
        if not rows:
            return
        t0 = time.perf_counter()
        dtype = self.body.v_template.dtype
        pts, rot, betas, transl = [], [], [], []
        for i in rows:
            r, c, s = results[i], items[i]["center"], results[i].scale_to_m
            pts.append(r.scan_points.astype(np.float64) * s - c)
            rot.append(roma.rotvec_to_rotmat(torch.as_tensor(r.pose_aa, dtype=torch.float64)))
            betas.append(torch.as_tensor(r.betas, dtype=torch.float64))
            transl.append(torch.as_tensor(r.transl_m - c, dtype=torch.float64))
        init = {k: torch.stack(v).to(dtype=dtype, device=self.device)
                for k, v in (("local_rotmats", rot), ("betas", betas), ("transl", transl))}  # fmt: skip
        out = fit_hands(self.body, self.hand_curl, pts, init, self.hands_config)
        seconds = (time.perf_counter() - t0) / len(rows)
        pose_aa = roma.rotmat_to_rotvec(out["local_rotmats"].double()).cpu().numpy()
        verts = out["vertices"].double().cpu().numpy()
        for j, i in enumerate(rows):
            r, it = results[i], items[i]
            c, s = it["center"], r.scale_to_m
            r.hand_curl = out["curl"][j].double().cpu().numpy()
            r.timings["hands"] = seconds
            r.timings["total"] += seconds
            if not out["kept"][j].any():
                continue
            r.vertices = ((verts[j] + c) / s).astype(np.float32)
            r.pose_aa = pose_aa[j].astype(np.float32)
            r.global_rotmats = out["global_rotmats"][j].double().cpu().numpy().astype(np.float32)
            finite = it.get("finite", it["keep"])
            d, vi = cKDTree(verts[j]).query(it.get("finite_centred", it["centred"]))
            r.point_fit_labels[finite] = self.vertex_parts[vi]
            r.point_distance[finite] = d / s
            exports[i] = (exports[i][0], pose_aa[j], verts[j] + c)

    def _objects(self, items: list[dict[str, Any]], results: list[FitResult], exports: list[tuple]) -> None:
        """Fit again, without them, the full scans whose fit the check doubts or refuses (but not two bodies
        found by clutter removal) and that hold flat objects touching the body: a chair, a stool, which the
        cluster step keeps with the body they touch (:func:`arteq.fit.clean.touching_planes`, among all the
        points, then among those off the fit). The refit is kept (``items``, ``results`` and
        ``exports`` replaced in place; the points removed coded ``object`` in :attr:`FitResult.point_clutter`)
        when at most ``object_max_on_fit`` of the removed points lie within ``object_on_fit_m`` of it and its
        surface score on the points left is lower than the first fit's; the check then judges it on those."""
        from scipy.spatial import cKDTree

        from arteq.fit.clean import touching_planes
        from arteq.fit.crossing import surface_score

        cfg = self.clean_config
        todo = list(range(len(results)))
        for _ in range(cfg.object_rounds):  # a refit kept and still doubted: its points off it looked at
            rows, tries = [], []
            for i in todo:
                r, it = results[i], items[i]
                flags = (r.quality or {}).get("flags") or []
                if r.scan_mode != "full" or r.vertices is None or not flags or "second_body" in flags:
                    continue  # (two clusters each a body: two people, nothing flat to remove)
                t_search = time.perf_counter()
                verts = r.vertices.astype(np.float64) * r.scale_to_m - it["center"]
                dist = cKDTree(verts).query(it["centred"])[0]
                noise = it["conditions"].get("noise_m")
                # objects as large as the body first (a child on a chair), searched among all the points,
                # then the others among those the fit leaves off it
                removed, planes = touching_planes(it["centred"], np.full(len(dist), np.inf), cfg, noise)
                more, planes2 = touching_planes(it["centred"], np.where(removed, 0.0, dist), cfg, noise)
                removed, planes = removed | more, planes + planes2
                t_search = time.perf_counter() - t_search
                r.timings["objects"] = r.timings.get("objects", 0.0) + t_search
                r.timings["total"] += t_search
                if not planes:
                    continue
                try:
                    tries.append(self._without(it, removed, planes))
                except ScanError:  # too few points left: the fit stands
                    continue
                rows.append((i, removed))
            if not tries:
                return
            t0 = time.perf_counter()
            res_t, exp_t = self._fit_batch(tries)
            seconds = (time.perf_counter() - t0) / len(tries)
            todo = []
            for (i, removed), it2, r2, e2 in zip(rows, tries, res_t, exp_t, strict=True):
                first = results[i]
                first.timings["objects"] = first.timings.get("objects", 0.0) + seconds
                first.timings["total"] += seconds
                if r2.vertices is None:
                    continue
                c2 = it2["center"]
                v2 = r2.vertices.astype(np.float64) * r2.scale_to_m - c2
                gone = items[i]["centred"][removed] + items[i]["center"] - c2
                on_fit = float((cKDTree(v2).query(gone)[0] < cfg.object_on_fit_m).mean())
                pts = r2.scan_points.astype(np.float64) * r2.scale_to_m - c2
                v1 = first.vertices.astype(np.float64) * first.scale_to_m - c2
                if on_fit > cfg.object_max_on_fit or surface_score(pts, v2, self.subset) >= surface_score(
                    pts, v1, self.subset
                ):
                    continue
                r2.timings = dict(first.timings)  # the first fit's steps, and the refits' time
                self._flag_refit(r2, first.uncertain_reason or describe_flags(first.quality))
                results[i], exports[i], items[i] = r2, e2, it2
                todo.append(i)

    def _second_person(self, items: list[dict[str, Any]], results: list[FitResult]) -> None:
        """Refuse (``second_person``, status ``not_single_body``) the written full fits that the scan covers
        (``person_min_coverage``) and whose largest group of points off the fit (the check's ``off_group_*``)
        is at least ``person_group_frac`` of the points and ``person_group_cm`` across, and is a body of its
        own: fitted alone (network, refinement and check, without the recovery steps), a plausible body
        that its own check does not refuse, with at least ``person_inliers`` of the group on it, covered
        (``person_coverage``) with at least ``person_ratio`` of its surface (:class:`QualityThresholds`).
        A child standing by an adult, touching, is one cluster, so clutter removal does not find two people,
        and the adult's fit leaves the child off it; a limb fitted elsewhere leaves its fit uncovered and a
        group that fits no whole body. The values go into the fit's quality (``second_person_*``) whenever
        the group was fitted; the seconds into ``timings["second_person"]``."""
        from arteq.fit.reach import off_group

        th = self.thresholds
        rows, tries = [], []
        for i, (r, it) in enumerate(zip(results, items, strict=True)):
            q = r.quality or {}
            big = q.get("off_group_frac", 0.0) >= th.person_group_frac
            big = big and q.get("off_group_cm", 0.0) >= th.person_group_cm
            big = big and q.get("coverage", 0.0) >= th.person_min_coverage
            if r.scan_mode != "full" or not r.written or not big:
                continue
            s = r.scale_to_m
            far_m, link_m = off_group_distances(th, q.get("inlier_cm", th.inlier_cm), it.get("conditions"))
            group = off_group(
                r.scan_points.astype(np.float64) * s, r.vertices.astype(np.float64) * s, far_m, link_m
            )
            kept = np.ones(len(group), bool)
            try:
                name = f"{r.name} (points off its fit)"
                tries.append(self._item(name, group, kept, None, [], 1.0, "m", None, 0.0))
            except ScanError:  # too few points, or too small for a body
                continue
            rows.append(i)
        if not tries:
            return
        t0 = time.perf_counter()
        crossing, self.crossing = self.crossing, None  # the group's first fit only
        try:
            found, _ = self._fit_batch(tries)
        finally:
            self.crossing = crossing
        seconds = (time.perf_counter() - t0) / len(tries)
        for i, r2 in zip(rows, found, strict=True):
            r, q2 = results[i], r2.quality or {}
            r.timings["second_person"] = seconds
            r.timings["total"] += seconds
            values = {"inliers": q2.get("inlier_frac", 0.0), "coverage": q2.get("coverage", 0.0),
                      "ratio": q2.get("surface_ratio", 0.0)}  # fmt: skip
            q, flags = r.quality, q2.get("flags") or []
            q.update({f"second_person_{k}": float(v) for k, v in values.items()})
            q.update(second_person_frac=q["off_group_frac"], second_person_cm=q["off_group_cm"],
                     second_person_flags=" ".join(flags))  # fmt: skip
            body = r2.vertices is not None and verdict(flags) != "not_single_body"
            body = body and "implausible_shape" not in flags
            on = values["inliers"] >= th.person_inliers and values["coverage"] >= th.person_coverage
            if not (body and on and values["ratio"] >= th.person_ratio):
                continue
            q["flags"].append("second_person")
            hard = [f for f in q["flags"] if f in REFUSE_FLAGS]
            r.status, r.uncertain_reason = "not_single_body", ""
            r.message = f"{r.name}: not a single body ({describe_flags(q, hard)})" + (
                "; " + "; ".join(r.warnings) if r.warnings else ""
            )

    def _flag_refit(self, r: FitResult, first_doubt: str) -> None:
        """A refit of a doubted fit that the check passes stays flagged (``refitted``): it was picked by its
        surface, which wrong vertices can explain too (experiments/fitting/crossing.md)."""
        if r.status != "ok":
            return
        r.quality["flags"].append("refitted")
        r.quality["first_doubt"] = first_doubt
        r.uncertain_reason = describe_flags(r.quality)
        r.status = "refused" if self.strict else "uncertain"
        what = "refused (--strict)" if self.strict else "written, check it"
        r.message = f"{r.name}: uncertain fit, {what} ({r.uncertain_reason})" + (
            "; " + "; ".join(r.warnings) if r.warnings else ""
        )

    def _without(self, item: dict[str, Any], removed: np.ndarray, planes: list[dict]) -> dict[str, Any]:
        """``item`` (:meth:`prepare`'s, cleaned) with its points ``removed [M]`` (rows of ``item["centred"]``)
        removed as flat objects (``planes``: :func:`arteq.fit.clean.touching_planes`'s)."""
        import dataclasses

        from arteq.fit.clean import CODES

        cleaned = item["clean"]
        rows = np.flatnonzero(cleaned.keep)[removed]  # rows of the finite points
        codes, keep = cleaned.codes.copy(), cleaned.keep.copy()
        codes[rows], keep[rows] = CODES["object"], False
        if keep.sum() < MIN_POINTS:  # flat all over (a box): nothing of a body left to fit
            raise ScanError(f"{item['name']}: only {int(keep.sum())} points left off flat objects")
        cleaned = dataclasses.replace(cleaned, codes=codes, keep=keep, objects=cleaned.objects + planes)
        metres = item["finite_centred"] + item["center"]
        return self._item(item["name"], metres, item["finite"], cleaned, item["base_warnings"], item["scale"],
                          item["units"], None, item["clean_seconds"])  # fmt: skip

    def _retry(self, items: list[dict[str, Any]], results: list[FitResult], exports: list[tuple]) -> None:
        """Fit again the full scans whose fit the check doubts and whose surface score is above
        ``retry_above_cm``: ``retries`` times each, from the network's reading of the scan turned by one of
        :func:`retry_turns` (with draws of its own), and with ``torso_retry`` once more from the first fit's
        draws read with the torso turned round (its second start left out: the first fit had it), every step
        as for the first fit; the retry with the lowest surface score on the first fit's points is kept where
        that score is below the first fit's by :data:`RETRY_MIN_GAIN` (``results`` and ``exports`` replaced
        in place) and recorded in :attr:`FitResult.retry` (``reads``: which reading each score is of). A
        retry kept stays ``uncertain`` (flag ``refitted``) even where the check passes it: it was picked by
        its surface, which wrong vertices can explain too."""
        from arteq.fit.crossing import surface_score

        def score(r: FitResult, pts: np.ndarray, centre: np.ndarray) -> float:
            if r.vertices is None:
                return float("inf")
            return surface_score(pts, r.vertices.astype(np.float64) * r.scale_to_m - centre, self.subset)

        doubted, first = [], {}
        for i, r in enumerate(results):
            if r.scan_mode != "full" or r.vertices is None or not r.uncertain_reason:
                continue
            pts = r.scan_points.astype(np.float64) * r.scale_to_m - items[i]["center"]
            first[i] = (pts, score(r, pts, items[i]["center"]))
            if first[i][1] > self.retry_above_cm:
                doubted.append(i)
        if not doubted:
            return
        t0 = time.perf_counter()
        turns = retry_turns(self.retries)
        reads = [{"retry": t + 1, "turn": turns[t]} for t in range(self.retries)]
        names = ["first"] + [f"retry {t + 1}" for t in range(self.retries)]
        if self.torso_retry:
            reads.append({"turn_torso": True})
            names.append("torso turned")
        n = len(reads)
        tries = [{**items[i], **read} for i in doubted for read in reads]
        res_t, exp_t = self._fit_batch(tries)
        seconds = (time.perf_counter() - t0) / len(doubted)
        kept = []  # (scan, the reading of the fit kept, its score)
        for j, i in enumerate(doubted):
            pts, own = first[i]
            cands = [(own, results[i], exports[i])]
            cands += [(score(res_t[j * n + t], pts, items[i]["center"]), res_t[j * n + t], exp_t[j * n + t])
                      for t in range(n)]  # fmt: skip
            best = 1 + int(np.argmin([c[0] for c in cands[1:]]))
            if not cands[best][0] < (1 - RETRY_MIN_GAIN) * own:
                best = 0
            picked = cands[best][1]
            picked.retry = {"scores_cm": [round(float(c[0]), 4) for c in cands], "picked": best,
                            "reads": names}  # fmt: skip
            if best:  # a retry the check passes stays flagged, as a crossing refit
                self._flag_refit(picked, results[i].uncertain_reason)
            picked.timings = {**results[i].timings, "retry": seconds}
            picked.timings["total"] += seconds
            results[i], exports[i] = picked, cands[best][2]
            kept.append((i, reads[best - 1] if best else {}, cands[best][0]))
        if self._torso_deferred:
            self._torso_once(items, results, exports, kept)

    @property
    def _torso_deferred(self) -> bool:
        """The torso step left out of every fit but the one the retries keep (``CrossingConfig.torso_once``
        with retries on: :meth:`_torso_once`)."""
        c = self.crossing
        retrying = (self.retries or self.torso_retry) and self.refine and self.check
        return bool(c is not None and c.torso and c.torso_once and retrying)

    def _torso_once(
        self, items: list[dict[str, Any]], results: list[FitResult], exports: list[tuple],
        kept: list[tuple[int, dict, float]],
    ) -> None:  # fmt: skip
        """The torso step (:meth:`_turn_torso`) once, on each fit the retries kept (``kept``: scan, the
        reading it came from, its surface score in cm) that the check still doubts and that scores above
        ``CrossingConfig.reach_max_score_cm``: the scan read again the same way (the same part labels), the
        fit itself neither refined nor restarted, then its torso turned. A start taken replaces the fit
        (``results`` and ``exports`` in place, flagged as a refit); what was tried joins
        :attr:`FitResult.crossing` either way and the seconds are ``timings["torso"]``."""
        import roma

        rows, tries = [], []
        for i, read, score in kept:
            r = results[i]
            if not r.uncertain_reason or not score > self.crossing.reach_max_score_cm:
                continue
            betas, pose_aa, _ = exports[i]
            f64 = torch.float64
            start = {"local_rotmats": roma.rotvec_to_rotmat(torch.as_tensor(pose_aa, dtype=f64)),
                     "betas": torch.as_tensor(betas, dtype=f64),
                     "transl": torch.as_tensor(r.transl_m - items[i]["center"], dtype=f64)}  # fmt: skip
            rows.append(i)
            tries.append({**items[i], **read, "start_fit": start})
        if not tries:
            return
        t0 = time.perf_counter()
        res_t, exp_t = self._fit_batch(tries)
        seconds = (time.perf_counter() - t0) / len(tries)
        for i, r2, e2 in zip(rows, res_t, exp_t, strict=True):
            r, step = results[i], r2.crossing
            r.timings["torso"] = seconds
            r.timings["total"] += seconds
            if step is None:  # the pass's own check no longer doubts it: nothing tried
                continue
            rec = dict(r.crossing or {"score_cm": step["score_cm"], "tried_cm": {}, "taken": ""})
            rec["tried_cm"] = {**rec["tried_cm"], **step["tried_cm"]}
            rec["stopped"] = {**rec.get("stopped", {}), **step.get("stopped", {})}
            rec["first_doubt"] = rec.get("first_doubt") or step["first_doubt"]
            if step["taken"]:
                rec["taken"] = "+".join(t for t in (rec["taken"], step["taken"]) if t)
                r2.crossing, r2.retry, r2.timings = rec, r.retry, dict(r.timings)
                r2.start_hypothesis = r.start_hypothesis
                self._flag_refit(r2, r.uncertain_reason)
                results[i], exports[i] = r2, e2
            else:
                r.crossing = rec

    def _fit_batch(self, items: list[dict[str, Any]]) -> tuple[list[FitResult], list[tuple]]:
        """Fit a batch of :meth:`prepare` outputs without the Anny export; also returns each fit's
        ``(betas, pose_aa, vertices in metres)`` for it. Items holding ``start_fit`` (all of the batch or
        none; :meth:`_torso_once`) are read by the network as usual but keep that fit as it is: no second
        start, no refinement, only the torso step of :meth:`_crossings`."""
        from scipy.spatial import cKDTree

        if not items:
            return [], []
        t0 = time.perf_counter()
        net_in, ref_in, clouds = [], [], []  # clouds: every draw of every scan (net_in: the first ones)
        k = self.net_draws
        for it in items:
            rng = np.random.default_rng(self.seed)
            it["denoised"] = self._smooth_for_network(it)
            src = it["centred"]
            if it["denoised"]:  # on the points the noise was measured on (a dense scan: a subsample)
                sub = it.get("subsample")
                src = denoise(src if sub is None else src[sub])
            first = resample(src, self.net_points, rng)
            ref_in.append(resample(it["centred"], self.points, rng))
            if it.get("retry"):  # a retry: the same points refined, the network's draws its own
                rng = np.random.default_rng((self.seed, int(it["retry"])))
                first = resample(src, self.net_points, rng)
            net_in.append(first)
            clouds += [first] + [resample(src, self.net_points, rng) for _ in range(k - 1)]
        t1 = time.perf_counter()
        modes = self._scan_modes(items, ref_in)  # before the network: partial scans' torso shifts
        t_modes = time.perf_counter() - t1
        turns = self._turns(items, k)
        torso = np.repeat([bool(it.get("turn_torso")) for it in items], k)
        pred = self._network(clouds, turns, self._torso_shifts(modes, k), torso if torso.any() else None)
        probs_draws = pred["part_probs"].float().cpu().numpy()  # [B * k, n, K] (waits for a GPU)
        if k > 1:  # the first draw's outputs; pose, shape and translation the mean of all draws'
            mean = mean_prediction(pred, k)
            first = {n: v[::k] for n, v in pred.items() if torch.is_tensor(v) and len(v) == len(clouds)}
            pred = {**pred, **first, **mean}
        extra = self.body.num_betas - pred["betas"].shape[-1]
        if extra > 0:  # shape_betas: the components the network does not predict start at 0
            pred["betas"] = torch.nn.functional.pad(pred["betas"], (0, extra))
        trees = [cKDTree(p) for p in clouds]

        def point_probs(i: int, query: np.ndarray) -> np.ndarray:
            """Scan ``i``'s part probabilities at ``query``: those of the nearest point of each draw, averaged
            (summed in place: a scan of millions of points holds two such arrays at a time)."""
            out = probs_draws[i * k][trees[i * k].query(query)[1]]
            for d in range(1, k):
                out += probs_draws[i * k + d][trees[i * k + d].query(query)[1]]
            if k > 1:
                out /= k
            return out

        near = [trees[i * k].query(ref_in[i])[1] for i in range(len(items))]  # each point's first-draw point
        probs_ref = np.stack([point_probs(i, ref_in[i]) for i in range(len(items))])
        t_net = time.perf_counter() - t0 - t_modes
        init = {"local_rotmats": pred["local_rotmats"], "betas": pred["betas"], "transl": pred["transl"]}
        given = [it.get("start_fit") for it in items]  # fits to run the torso step on (:meth:`_torso_once`)
        fixed = given[0] is not None
        if any((g is None) == fixed for g in given):
            raise ValueError("a batch holds items with a given fit (start_fit) and items without")
        if fixed:  # that fit, neither refined nor started again: only its torso step follows
            init = {k: torch.stack([torch.as_tensor(g[k]) for g in given]).to(self.device) for k in init}
        t1 = time.perf_counter()
        if not fixed:
            self._place_partial(modes, net_in, pred, init)
        t_modes += time.perf_counter() - t1
        rows, second = [], None  # the full scans that also start from the second network, and its starts
        if self.refine and self.second is not None and not fixed:
            # (a retry read with the torso turned round: the first fit had the second start)
            rows = [i for i, m in enumerate(modes) if not m["partial"] and not items[i].get("turn_torso")]
        if rows:
            t1 = time.perf_counter()
            second = self._second_starts([net_in[i] for i in rows], [near[i] for i in rows],
                                         {k: pred[k][rows] for k in ("betas", "transl")},
                                         self._turns([items[i] for i in rows]))  # fmt: skip
            t_net += time.perf_counter() - t1
        t1 = time.perf_counter()
        dtype = self.body.v_template.dtype
        probs_fit = probs_ref  # the refinement's labels; what is reported stays the network's
        if self.refine and not fixed and self.hypotheses is not None and any(m["partial"] for m in modes):
            probs_fit = self._pick_starts(ref_in, probs_ref, init, modes)
        if self.refine and not fixed:
            visible = None
            if any(m["partial"] for m in modes):  # model -> scan only where each partial scan's camera sees
                from arteq.fit.partial import visibility_function

                views = [(m["camera"], m["view_dir"]) if m["partial"] else None for m in modes]
                incidence = body_tables(self.body, self.refine_config.m2s_vertices).incidence
                visible = visibility_function(self.body.faces, views, incidence)
            starts, probs_all, points_all = init, probs_fit, ref_in
            if rows:  # the second starts of the full scans refined in the same batch, after the others
                starts = {k: torch.cat([init[k], second["init"][k].to(init[k].dtype)]) for k in init}
                probs_all = np.concatenate([probs_fit, second["probs"]])
                points_all = ref_in + [ref_in[i] for i in rows]
                if visible is not None:
                    views = views + [None] * len(rows)
                    visible = visibility_function(self.body.faces, views, incidence)
            stop, stop_at, decided = None, (), {}
            if rows:  # the worse start of a scan stops early
                stop, stop_at, decided = self._start_stopper(ref_in, rows)
            out = refine(
                self.body,
                torch.as_tensor(np.stack(points_all), dtype=dtype, device=self.device),
                torch.as_tensor(probs_all, dtype=dtype, device=self.device),
                starts,
                self.refine_config,
                m2s_visible=visible,
                stop=stop,
                stop_at=stop_at,
            )
            if rows:  # the better of each full scan's two fits into its row
                probs_fit = self._keep_better(ref_in, rows, out, probs_fit, second["probs"], modes, decided)
            n = len(items)
            local, betas, transl = out.local_rotmats[:n], out.betas[:n], out.transl[:n]
            verts, joints, grot = out.vertices[:n], out.joints[:n], out.global_rotmats[:n]
        else:
            local, betas, transl = init["local_rotmats"], init["betas"], init["transl"]
            with torch.no_grad():
                o = self.body(betas=betas.to(dtype), pose=local.to(dtype), transl=transl.to(dtype))
            verts, joints, grot = o.vertices, o.joints, o.global_rotmats
        t_ref = time.perf_counter() - t1
        crossing: list[dict | None] = [None] * len(items)
        t_cross = [0.0] * len(items)
        checked: list[dict | None] = [None] * len(items)  # the check's values where the fit stays as checked
        # the network's points per part (the lost-hand step, the results)
        counts = [np.bincount(p.argmax(-1), minlength=probs_ref.shape[-1]) for p in probs_ref]
        unplaced: list[dict | None] = [None] * len(items)  # a hand-sized group no arm could be put on
        if self.refine and self.crossing is not None:
            fit = {"local_rotmats": local, "betas": betas, "transl": transl, "vertices": verts,
                   "joints": joints, "global_rotmats": grot}  # fmt: skip
            conditions = [it.get("conditions") for it in items]
            crossing, t_cross, checked = self._crossings(ref_in, probs_fit, modes, fit, conditions, fixed)
            if self.crossing.lost_hand and not fixed:
                self._lost_hands(ref_in, modes, fit, crossing, t_cross, checked, counts, unplaced)
            local, betas, transl = fit["local_rotmats"], fit["betas"], fit["transl"]
            verts, joints, grot = fit["vertices"], fit["joints"], fit["global_rotmats"]
        import roma

        pose_aa = roma.rotmat_to_rotvec(roma.special_procrustes(local.double())).cpu().numpy()
        verts, joints = verts.double().cpu().numpy(), joints.double().cpu().numpy()
        grot, betas, transl = (
            grot.double().cpu().numpy(),
            betas.double().cpu().numpy(),
            transl.double().cpu().numpy(),
        )
        per_scan_net, per_scan_ref = t_net / len(items), t_ref / len(items)
        results = []
        for i, it in enumerate(items):
            t2 = time.perf_counter()
            mode = modes[i]
            it["mode"] = mode  # for the clothing pass (a partial scan's camera)
            subset = self.subset
            if mode["partial"]:  # coverage of what the camera could see
                subset = subset[self._visible(verts[i], mode)[subset]]
            q = checked[i]
            if q is None:
                q = fit_quality(ref_in[i], verts[i], self.vertex_parts, subset, betas[i], probs_ref[i],
                                self.thresholds, it.get("conditions"))  # fmt: skip
            cond = it.get("conditions") or {}
            noise = cond.get("noise_m")
            q["noise_mm"] = float("nan") if noise is None else round(noise * 1000, 2)
            q["spacing_mm"] = round(cond.get("spacing_m", float("nan")) * 1000, 2)
            q["denoised"] = bool(it.get("denoised", False))
            if crossing[i] and crossing[i]["taken"] and crossing[i]["first_doubt"] and not q["flags"]:
                # a refit the check no longer doubts stays flagged: surface checks pass refits of wrong
                # vertices (experiments/fitting/crossing.md)
                q["flags"].append("refitted")
                q["first_doubt"] = crossing[i]["first_doubt"]
            if unplaced[i] is not None and self.crossing.lost_hand_flag:
                # a group off the fit by an arm whose hand the network did not see, that no placed arm
                # explained: the hand may lie elsewhere (experiments/fitting/lost_hand/README.md)
                q["flags"].append("hand_off_fit")
                q.update({f"hand_off_{k}": v for k, v in unplaced[i].items()})
            cleaned = it.get("clean")
            if cleaned is not None and "second_body" in cleaned.flags:
                q["flags"].append("second_body")
                q.update({f"second_body_{k}": v for k, v in cleaned.second_cluster.items()})
            s = it["scale"]
            keep = it["keep"]
            n_all = len(keep)
            lab = np.full(n_all, -1, dtype=np.int16)
            conf = np.zeros(n_all, dtype=np.float32)
            fit_lab = np.full(n_all, -1, dtype=np.int16)
            dist = np.full(n_all, np.inf, dtype=np.float32)
            probs_scan = point_probs(i, it["centred"])
            lab[keep] = probs_scan.argmax(-1)
            conf[keep] = probs_scan.max(-1)
            finite = it.get("finite", keep)
            d, vi = cKDTree(verts[i]).query(it.get("finite_centred", it["centred"]))
            fit_lab[finite] = self.vertex_parts[vi]
            dist[finite] = d / s
            status, message, reason = "ok", "", ""
            warnings = list(it["warnings"])
            if q["flags"]:
                if not self.check:
                    warnings.append(f"quality check failed: {describe_flags(q)}")
                elif verdict(q["flags"]) == "not_single_body":
                    status = "not_single_body"
                    hard = [f for f in q["flags"] if f in REFUSE_FLAGS]
                    message = f"{it['name']}: not a single body ({describe_flags(q, hard)})"
                else:
                    reason = describe_flags(q)
                    status = "refused" if self.strict else "uncertain"
                    what = "refused (--strict)" if self.strict else "written, check it"
                    message = f"{it['name']}: uncertain fit, {what} ({reason})"
            if warnings:
                message = (message + "; " if message else f"{it['name']}: ") + "; ".join(warnings)
            c = it["center"]
            results.append(
                FitResult(
                    name=it["name"],
                    status=status,
                    message=message,
                    units=it["units"],
                    scale_to_m=s,
                    vertices=((verts[i] + c) / s).astype(np.float32),
                    faces=self.faces,
                    joints=((joints[i] + c) / s).astype(np.float32),
                    betas=betas[i].astype(np.float32),
                    pose_aa=pose_aa[i].astype(np.float32),
                    global_rotmats=grot[i].astype(np.float32),
                    transl_m=(transl[i] + c).astype(np.float64),
                    point_labels=lab,
                    point_confidence=conf,
                    point_fit_labels=fit_lab,
                    point_distance=dist,
                    scan_points=((ref_in[i] + c) / s).astype(np.float32),
                    scan_labels=probs_ref[i].argmax(-1).astype(np.int16),
                    point_clutter=it.get("clutter"),
                    clean=cleaned,
                    clutter_points=_removed_points(it, c, s),
                    quality=q,
                    uncertain_reason=reason,
                    timings={
                        "clean": it.get("clean_seconds", 0.0),
                        "network": per_scan_net,
                        "scan_mode": t_modes / len(items),
                        "refine": per_scan_ref,
                        "check": time.perf_counter() - t2,
                        "crossing": t_cross[i],
                    },  # fmt: skip
                    body_model=str(getattr(self.body, "name", "")),
                    checkpoint=self.checkpoint_id,
                    refined=self.refine,
                    warnings=warnings,
                    scan_mode="partial" if mode["partial"] else "full",
                    scan_mode_reason=mode["reason"],
                    view_dir=mode["view_dir"],
                    one_sidedness=mode["score"],
                    start_hypothesis=mode.get("hypothesis") or mode.get("second_start"),
                    crossing=crossing[i],
                    part_points=counts[i],
                    parts_seen=counts[i] >= max(MIN_PART_POINTS, MIN_PART_SHARE * self.points),
                )
            )
        for r in results:
            t = r.timings
            t["total"] = t["clean"] + t["network"] + t["scan_mode"] + t["refine"] + t["check"] + t["crossing"]
        exports = [(betas[i], pose_aa[i], verts[i] + it["center"]) for i, it in enumerate(items)]
        return results, exports

    @torch.no_grad()
    def _second_starts(
        self, net_in: list[np.ndarray], near: list[np.ndarray], pred: dict[str, torch.Tensor],
        turns: np.ndarray | None = None,
    ) -> dict[str, Any]:  # fmt: skip
        """The second network's starts for the scans given (``pred``: this model's ``betas`` and ``transl``
        of those scans): its local rotations, this model's betas, the translation placed for that body with
        its part weights, and its part probabilities at the refinement's points (``near``: each one's
        network point). ``turns``: the network reads the clouds turned (:func:`turn_back`)."""
        from arteq.models.placement import estimate_translation

        x = torch.as_tensor(np.stack(net_in), dtype=torch.float32, device=self.device)
        if turns is None:
            other = self.second.net(x)
        else:
            turn = torch.as_tensor(turns, dtype=torch.float32, device=self.device)
            other = turn_back(self.second.net(x @ turn.transpose(-1, -2)), turn)
        local = other["local_rotmats"].float()
        betas = pred["betas"].float()
        posed = self.body(
            betas=betas.to(self.body.v_template.dtype), pose=local.to(self.body.v_template.dtype)
        )
        transl = estimate_translation(
            posed.vertices.float(), self.module.centroid_matrix, x, other["pool_weights"]
        )
        probs = other["part_probs"].float().cpu().numpy()
        return {
            "init": {"local_rotmats": local, "betas": betas, "transl": transl.to(pred["transl"].dtype)},
            "probs": np.stack([probs[i][near[i]] for i in range(len(net_in))]),
        }

    def _start_stopper(
        self, ref_in: list[np.ndarray], rows: list[int]
    ) -> tuple[Callable, tuple[int, ...], dict[int, dict[str, Any]]]:
        """For :func:`refine`'s ``stop``: the batch holds every scan (rows ``0..n-1``) and then the second
        starts of the scans ``rows`` (row ``n + j`` for ``rows[j]``). At the iterations of
        :data:`SECOND_START_STOPS` the start whose surface score exceeds the other's by the margin stops.
        Returns ``stop``, ``stop_at`` and the decisions it fills (scan -> the start kept, both scores, the
        iteration)."""
        from arteq.fit.crossing import surface_score

        n = len(ref_in)
        pairs = {i: n + j for j, i in enumerate(rows)}
        margin = {refine_iteration(self.refine_config, f): m for f, m in SECOND_START_STOPS}
        margin.pop(-1, None)
        decided: dict[int, dict[str, Any]] = {}

        def stop(it: int, alive: torch.Tensor, verts: torch.Tensor) -> torch.Tensor:
            where = {int(r): a for a, r in enumerate(alive)}
            out = torch.zeros(len(alive), dtype=torch.bool)
            for i, k in pairs.items():
                if i in decided or i not in where or k not in where:
                    continue
                own, alt = (
                    surface_score(ref_in[i], verts[where[r]].detach().double().cpu().numpy(), self.subset)
                    for r in (i, k)
                )
                if max(own, alt) > min(own, alt) * (1 + margin[it]) or margin[it] == 0:
                    take = alt < own
                    out[where[i if take else k]] = True
                    decided[i] = {"take": take, "own": own, "alt": alt, "iteration": it}
            return out

        return stop, tuple(sorted(margin)), decided

    def _keep_better(
        self, ref_in: list[np.ndarray], rows: list[int], out: Any, probs_fit: np.ndarray,
        probs_second: np.ndarray, modes: list[dict[str, Any]], decided: dict[int, dict[str, Any]],
    ) -> np.ndarray:  # fmt: skip
        """Per full scan ``rows[j]``, the refinement from the second start (``out``'s row ``len(ref_in) + j``,
        its part probabilities ``probs_second[j]``) replaces the network's (row ``rows[j]``) when its
        surface score is lower, at the end or where ``decided`` (:meth:`_start_stopper`) says the other
        stopped; ``modes`` record both scores and that iteration. Returns the part probabilities of the
        starts kept."""
        from arteq.fit.crossing import surface_score

        n = len(ref_in)
        verts = out.vertices.detach().double().cpu().numpy()
        probs_fit = probs_fit.copy()
        name = self.second_name
        for j, i in enumerate(rows):
            if i in decided:
                d = decided[i]
                take, own, alt, at = d["take"], d["own"], d["alt"], d["iteration"]
            else:
                own = surface_score(ref_in[i], verts[i], self.subset)
                alt = surface_score(ref_in[i], verts[n + j], self.subset)
                take, at = alt < own, out.iterations
            scores = {"network": round(own, 3), name: round(alt, 3)}
            modes[i]["second_start"] = {
                "picked": name if take else "network",
                "scores": scores,
                "iteration": at,
            }
            if take:
                for t in (
                    out.local_rotmats,
                    out.betas,
                    out.transl,
                    out.vertices,
                    out.joints,
                    out.global_rotmats,
                ):
                    t[i] = t[n + j]
                probs_fit[i] = probs_second[j]
        return probs_fit

    def _crossings(
        self,
        ref_in: list[np.ndarray],
        probs_ref: np.ndarray,
        modes: list[dict[str, Any]],
        fit: dict,
        conditions: list[dict | None] | None = None,
        torso_only: bool = False,
    ) -> tuple[list[dict | None], list[float], list[dict | None]]:
        """Crossed limbs (:mod:`arteq.fit.crossing`) for the full scans of a refined batch: which pairs each
        tries, the swaps' refinement, and ``fit``'s tensors replaced where a swap is kept; then the torso
        step (:meth:`_turn_torso`; left for :meth:`_torso_once` where ``CrossingConfig.torso_once`` defers
        it). ``torso_only``: the torso step alone (:meth:`_torso_once`'s pass). Returns per scan the record
        for :attr:`FitResult.crossing` (None: nothing tried), its seconds, and the check's values of the fit
        where it was not replaced (None elsewhere: checked again)."""
        t0 = time.perf_counter()
        n = len(ref_in)
        tries: list[list[str]] = [[] for _ in range(n)]
        extra: list[dict[str, np.ndarray]] = [{} for _ in range(n)]  # limbs placed on off-fit points
        doubtful = [""] * n
        checked: list[dict | None] = [None] * n
        joints = fit["joints"].detach().double().cpu().numpy()
        for i in range(n):
            if modes[i]["partial"]:
                continue
            q = fit_quality(
                ref_in[i], fit["vertices"][i].detach().double().cpu().numpy(), self.vertex_parts,
                self.subset, fit["betas"][i].detach().double().cpu().numpy(), probs_ref[i], self.thresholds,
                conditions[i] if conditions else None,
            )  # fmt: skip
            checked[i] = q
            if verdict(q["flags"]) == "not_single_body":
                continue
            doubtful[i] = describe_flags(q) if verdict(q["flags"]) == "uncertain" else ""
            if torso_only:
                continue
            tries[i] = pairs_to_try(joints[i], bool(doubtful[i]), self.crossing)
            if self.crossing.reach and doubtful[i] and "off_fit_limb" in q["flags"]:
                extra[i] = self._reach(ref_in[i], fit, i)
        torso = self.crossing.torso and (torso_only or not self._torso_deferred)
        if not any(tries) and not any(extra) and not (torso and any(doubtful)):
            return [None] * n, [0.0] * n, checked
        picked = [{"taken": ""} for _ in range(n)]
        if any(tries) or any(extra):
            picked = try_swaps(self.body, ref_in, fit, self.subset, tries, self.refine_config, self.crossing,
                               extra=extra)  # fmt: skip
        for k in fit:
            fit[k] = fit[k].detach().clone()
        records: list[dict | None] = [None] * n
        for i, p in enumerate(picked):
            if not tries[i] and not extra[i]:
                continue
            records[i] = {"score_cm": round(p["score"], 4), "tried_cm": {k: round(v, 4) for k, v in
                          p["tried"].items()}, "stopped": p.get("stopped", {}), "taken": p["taken"],
                          "first_doubt": doubtful[i]}  # fmt: skip
            if "polish_cm" in p:  # the swap taken, refined on (CrossingConfig.polish_iters)
                records[i]["polish_cm"] = round(p["polish_cm"], 4)
            if p["taken"]:
                checked[i] = None
                for k in fit:
                    fit[k][i] = p[k].to(fit[k].dtype)
        for _ in range(self.crossing.reach_rounds - 1):  # a limb placed: another may still be off
            again = [{} for _ in range(n)]
            for i, p in enumerate(picked):
                if p["taken"].startswith(REACH):
                    again[i] = self._reach(ref_in[i], fit, i)
            if not any(again):
                break
            picked = try_swaps(self.body, ref_in, fit, self.subset, [[] for _ in range(n)],
                               self.refine_config, self.crossing, extra=again)  # fmt: skip
            for i, p in enumerate(picked):
                if not again[i]:
                    p["taken"] = ""
                    continue
                rec = records[i]
                rec["tried_cm"].update({f"{k} (then)": round(v, 4) for k, v in p["tried"].items()})
                if p["taken"]:
                    rec["taken"] += "+" + p["taken"]
                    for k in fit:
                        fit[k][i] = p[k].to(fit[k].dtype)
        turned = self._turn_torso(ref_in, fit, doubtful if torso else [""] * n, records, checked)
        went = [bool(t or e or u) for t, e, u in zip(tries, extra, turned)]
        seconds = (time.perf_counter() - t0) / max(1, sum(went))
        return records, [seconds if w else 0.0 for w in went], checked

    def _turn_torso(
        self, ref_in: list[np.ndarray], fit: dict, doubtful: list[str], records: list[dict | None],
        checked: list[dict | None],
    ) -> list[bool]:  # fmt: skip
        """The doubted fits of ``fit`` lost as a whole (surface score above
        ``CrossingConfig.reach_max_score_cm``) refined again from their lower torso turned
        (:func:`arteq.fit.torso_turns.torso_starts`), ``CrossingConfig.torso_rounds`` rounds (after the
        first, a fit kept scoring below that gets its limbs placed instead: :meth:`_reach`); ``fit``'s rows,
        ``records`` (``tried_cm`` keys ``"<start> (torso R)"``, round R) and ``checked`` updated where a start
        is kept. Returns which scans tried."""
        import dataclasses
        import math

        from arteq.fit.crossing import surface_score

        n = len(ref_in)
        cfg = self.crossing
        tried = [False] * n
        if not cfg.torso:
            return tried
        rc = dataclasses.replace(cfg, iters=cfg.torso_iters, max_score_cm=math.inf)
        going = [bool(d) for d in doubtful]
        for rnd in range(cfg.torso_rounds):
            extra: list[dict[str, np.ndarray]] = [{} for _ in range(n)]
            for i in range(n):
                if not going[i]:
                    continue
                verts = fit["vertices"][i].detach().double().cpu().numpy()
                if surface_score(ref_in[i], verts, self.subset) > cfg.reach_max_score_cm:
                    extra[i] = torso_starts(fit["global_rotmats"][i].detach().double().cpu().numpy())
                elif rnd > 0:  # the torso kept has brought the fit in: a limb may still be off
                    extra[i] = self._reach(ref_in[i], fit, i)
            if not any(extra):
                break
            none = [[] for _ in range(n)]
            picked = try_swaps(self.body, ref_in, fit, self.subset, none, self.refine_config, rc, extra=extra)
            for i, p in enumerate(picked):
                going[i] = bool(extra[i] and p["taken"])
                if not extra[i]:
                    continue
                tried[i] = True
                if records[i] is None:
                    records[i] = {"score_cm": round(p["score"], 4), "tried_cm": {}, "stopped": {},
                                  "taken": "", "first_doubt": doubtful[i]}  # fmt: skip
                rec, tag = records[i], f" (torso {rnd + 1})"
                rec["tried_cm"].update({k + tag: round(v, 4) for k, v in p["tried"].items()})
                rec["stopped"].update({k + tag: v for k, v in p.get("stopped", {}).items()})
                if p["taken"]:
                    rec["taken"] += ("+" if rec["taken"] else "") + p["taken"] + tag
                    checked[i] = None
                    for k in fit:
                        fit[k][i] = p[k].to(fit[k].dtype)
        return tried

    def _lost_hands(
        self, ref_in: list[np.ndarray], modes: list[dict[str, Any]], fit: dict, records: list[dict | None],
        seconds: list[float], checked: list[dict | None], seen: list[np.ndarray], unplaced: list[dict | None],
    ) -> None:  # fmt: skip
        """:func:`arteq.fit.lost_hand.fit_lost_hand` on each full scan of ``fit`` (the crossed-limb step's
        tensors, updated in place where an arm is kept) that scores at most
        ``CrossingConfig.reach_max_score_cm`` (above it the fit is lost as a whole: the torso step's case);
        ``seen``: per scan, the network's points of each part. Its record under ``"lost_hand"`` of the scan's
        crossing record (``records``, created where there was none; ``"hand_<arm>"`` added to its
        ``taken``), its seconds added to ``seconds``, ``checked`` cleared where the fit changed; where arms
        were tried and none kept, the group's size and the arms tried in ``unplaced`` (the check's
        ``hand_off_fit``)."""
        from arteq.fit.lost_hand import fit_lost_hand

        for i in range(len(ref_in)):
            q = checked[i]
            if modes[i]["partial"] or (q is not None and verdict(q["flags"]) == "not_single_body"):
                continue
            t0 = time.perf_counter()
            row = {k: fit[k][i].detach().double().cpu().numpy() for k in fit}
            share = seen[i] / max(1, len(ref_in[i]))
            rec = fit_lost_hand(self.body, ref_in[i], row, self.vertex_parts, seen=share, subset=self.subset,
                                max_score_cm=self.crossing.reach_max_score_cm)  # fmt: skip
            if rec is None:
                continue
            if records[i] is None:
                doubt = describe_flags(q) if q is not None and verdict(q["flags"]) == "uncertain" else ""
                records[i] = {"score_cm": round(rec["score_cm"], 4), "tried_cm": {}, "stopped": {},
                              "taken": "", "first_doubt": doubt}  # fmt: skip
            records[i]["lost_hand"] = {k: v for k, v in rec.items() if k not in ("local_rotmats", "score_cm")}
            if not rec["arm"]:
                unplaced[i] = {
                    "points": int(rec["group"]),
                    "arms": " and ".join(a.replace("_", " ") for a in rec["tried"]),
                }
            if rec["arm"]:
                taken = records[i]["taken"]
                records[i]["taken"] = (taken + "+" if taken else "") + "hand_" + rec["arm"]
                local = fit["local_rotmats"]
                local[i] = torch.as_tensor(rec["local_rotmats"], dtype=local.dtype, device=local.device)
                with torch.no_grad():
                    o = self.body(betas=fit["betas"][i : i + 1], pose=local[i : i + 1],
                                  transl=fit["transl"][i : i + 1])  # fmt: skip
                fit["vertices"][i], fit["joints"][i], fit["global_rotmats"][i] = (
                    o.vertices[0].to(fit["vertices"].dtype), o.joints[0].to(fit["joints"].dtype),
                    o.global_rotmats[0].to(fit["global_rotmats"].dtype),
                )  # fmt: skip
                checked[i] = None
            seconds[i] += time.perf_counter() - t0

    def _reach(self, points: np.ndarray, fit: dict, i: int) -> dict[str, np.ndarray]:
        """:func:`arteq.fit.reach.reach_starts` of row ``i`` of ``fit`` (the check's off-fit distances); none
        for a fit whose surface score is above ``CrossingConfig.reach_max_score_cm``."""
        from arteq.fit.crossing import surface_score

        def row(k: str) -> np.ndarray:
            return fit[k][i].detach().double().cpu().numpy()

        if surface_score(points, row("vertices"), self.subset) > self.crossing.reach_max_score_cm:
            return {}
        return reach_starts(
            points, row("vertices"), row("joints"), row("local_rotmats"), row("global_rotmats"),
            self.vertex_parts, self.thresholds.off_fit_cm / 100, self.thresholds.off_link_cm / 100,
            self.crossing.reach_min_points,
        )  # fmt: skip

    def _smooth_for_network(self, item: dict[str, Any]) -> bool:
        """Whether a scan reaches the network smoothed: a full surface (no camera, not one-sided) noisier
        than ``denoise_above_mm`` (measured on full scans only: experiments/fitting/scan_defects.md)."""
        from arteq.fit.partial import PARTIAL_SCORE, one_sidedness

        noise = item.get("conditions", {}).get("noise_m")
        if self.denoise_above_mm is None or noise is None or noise * 1000 <= self.denoise_above_mm:
            return False
        if self.partial or item.get("viewpoint") is not None or self.view_dir is not None:
            return False
        if self.partial is None:
            score, _ = one_sidedness(resample(item["centred"], 4000, np.random.default_rng(self.seed)))
            return bool(score <= PARTIAL_SCORE)
        return True

    def _scan_modes(self, items: list[dict[str, Any]], ref_in: list[np.ndarray]) -> list[dict[str, Any]]:
        """Full or partial, and why, per scan, and a partial scan's camera direction (see the class
        docstring); from the points alone, before the network."""
        from arteq.fit.partial import PARTIAL_SCORE, facing_direction, one_sidedness

        modes = []
        for i, it in enumerate(items):
            score = estimate = None
            if self.partial is not False:  # on a fixed point count: the score depends on the density
                cloud = resample(it["centred"], 4000, np.random.default_rng(self.seed))
                score, estimate = one_sidedness(cloud)
                if score > PARTIAL_SCORE or self.partial:  # the direction refined from the normals
                    estimate = facing_direction(cloud, estimate)
            m = {"partial": True, "view_dir": None, "camera": None, "score": score}
            viewpoint = it.get("viewpoint")
            if self.partial is False:
                m.update(partial=False, reason="full (--no-partial)")
            elif viewpoint is not None:
                d = viewpoint - ref_in[i].mean(0)
                d = d / np.linalg.norm(d)
                m.update(camera=viewpoint, view_dir=d, reason="partial (the file's camera)")
            elif self.view_dir is not None:
                m.update(view_dir=self.view_dir, reason="partial (--view-dir)")
            elif self.partial:
                m.update(view_dir=estimate, reason="partial (--partial; camera direction estimated)")
            elif score > PARTIAL_SCORE:
                why = f"partial (detected: one-sidedness {score:.2f} > {PARTIAL_SCORE})"
                m.update(view_dir=estimate, reason=why)
            else:
                why = f"full (detected: one-sidedness {score:.2f} <= {PARTIAL_SCORE})"
                m.update(partial=False, reason=why)
            modes.append(m)
        return modes

    def _place_partial(
        self, modes: list[dict[str, Any]], net_in: list[np.ndarray], pred: dict[str, torch.Tensor],
        init: dict[str, torch.Tensor],
    ) -> None:  # fmt: skip
        """A partial scan's translation in ``init`` replaced by
        :func:`arteq.models.placement.align_translation`'s (the predicted body on the seen surface)."""
        from arteq.models.placement import align_translation

        rows = [i for i, m in enumerate(modes) if m["partial"]]
        if rows:
            dtype = self.body.v_template.dtype
            with torch.no_grad():  # the predicted body before translation
                betas, local = init["betas"][rows].to(dtype), init["local_rotmats"][rows].to(dtype)
                verts0 = self.body(betas=betas, pose=local).vertices
            x = torch.as_tensor(np.stack([net_in[i] for i in rows]), dtype=dtype, device=self.device)
            t = align_translation(verts0, self.body.part_labels, x, pred["part_probs"][rows],
                                  init["transl"][rows])  # fmt: skip
            init["transl"] = init["transl"].clone()
            init["transl"][rows] = t.to(init["transl"].dtype)

    def _pick_starts(
        self, ref_in: list[np.ndarray], probs_ref: np.ndarray, init: dict[str, torch.Tensor],
        modes: list[dict[str, Any]],
    ) -> np.ndarray:  # fmt: skip
        """Partial scans: the refinement's start picked from :func:`arteq.fit.partial.pick_starts`'s
        hypotheses (``init`` rows replaced, ``modes[i]["hypothesis"]`` set); returns the part
        probabilities (the picked start's own labelling where it is not the network's body). Full scans'
        rows are left as they are."""
        from arteq.fit.partial import pick_starts

        rows = [i for i, m in enumerate(modes) if m["partial"]]
        picked = pick_starts(
            self.body, [ref_in[i] for i in rows], [probs_ref[i] for i in rows],
            {k: init[k][rows] for k in ("local_rotmats", "betas", "transl")},
            [(modes[i]["camera"], modes[i]["view_dir"]) for i in rows],
            self.refine_config, self.hypotheses, self.subset,
        )  # fmt: skip
        probs_ref = probs_ref.copy()
        for k in ("local_rotmats", "betas", "transl"):
            init[k] = init[k].clone()
            init[k][rows] = picked["init"][k].to(device=init[k].device, dtype=init[k].dtype)
        for j, i in enumerate(rows):
            probs_ref[i] = picked["probs"][j]
            modes[i]["hypothesis"] = picked["info"][j]
        return probs_ref

    def _visible(self, vertices: np.ndarray, mode: dict[str, Any]) -> np.ndarray:
        """``[V]`` bool: the vertices of a fitted body (centred metres) its scan's camera sees."""
        from arteq.fit.partial import visibility_function

        visible = visibility_function(self.body.faces, [(mode["camera"], mode["view_dir"])])
        return visible(torch.as_tensor(vertices)[None])[0].cpu().numpy()

    def fit_points(self, points: np.ndarray, units: str = "m", name: str = "points") -> FitResult:
        """Fit one cloud ``[N, 3]`` (in ``units``); bad input gives a result with status ``error``."""
        try:
            item = self.prepare(points, units, name)
        except ScanError as exc:
            return FitResult(name=name, status="error", message=str(exc), units=units)
        return self.fit_prepared([item])[0]


def _removed_points(item: dict[str, Any], centre: np.ndarray, scale: float) -> np.ndarray | None:
    """Up to 5000 of the points clutter removal dropped, in the file's frame and units (for previews)."""
    cleaned = item.get("clean")
    if cleaned is None or cleaned.keep.all():
        return None
    gone = item["finite_centred"][~cleaned.keep]
    if len(gone) > 5000:
        gone = gone[np.random.default_rng(0).choice(len(gone), 5000, replace=False)]
    return ((gone + centre) / scale).astype(np.float32)


_FITTERS: dict[tuple, Fitter] = {}


def get_fitter(**kwargs: Any) -> Fitter:
    """A :class:`Fitter`, cached by its arguments (loading a checkpoint costs about a second)."""
    key = tuple(sorted((k, repr(v)) for k, v in kwargs.items()))
    if key not in _FITTERS:
        _FITTERS[key] = Fitter(**kwargs)
    return _FITTERS[key]


def fit_points(
    points: np.ndarray | torch.Tensor,
    units: str = "m",
    ckpt: str | Path | None = None,
    refine: bool = True,
    device: str = "auto",
    num_points: int = 5000,
    check: bool = True,
    name: str = "points",
    fitter: Fitter | None = None,
    clean: bool = True,
    strict: bool = False,
) -> FitResult:
    """Fit the body to one point cloud ``[N, 3]`` given in ``units`` (``m``, ``cm`` or ``mm``).

    Returns a :class:`FitResult` in the cloud's own frame and units; ``result.status`` is ``ok``,
    ``uncertain`` (a body, but the check doubts the fit: ``result.uncertain_reason`` says why),
    ``not_single_body`` (not one body: a sphere, two people; ``result.message`` says why), ``refused``
    (uncertain and ``strict``) or ``error`` (bad input: too few points, wrong units...). Pass
    ``fitter=`` to reuse a loaded model.
    """
    if isinstance(points, torch.Tensor):
        points = points.detach().cpu().numpy()
    f = fitter or get_fitter(
        ckpt=ckpt, device=device, refine=refine, points=num_points, check=check, clean=clean, strict=strict
    )
    return f.fit_points(points, units=units, name=name)
