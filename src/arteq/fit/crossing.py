"""Crossed limbs: refit with a left / right pair of limb segments swapped, keep it when it explains the scan
better.

The part-local network reads left and right from the torso's frame (:mod:`arteq.models.sides`): a point's
side is the side of the body's midplane it lies on. A limb that crosses the midplane (arms crossed
overhead, a forearm across the chest, a handstand's arms seen upside down) is then split between the two
sides, and the refinement, which starts from those labels, ends with the limbs uncrossed: the surface is
covered, the vertices are wrong (16-22 cm V2V on the user-scan suite's ``reach_up`` scans).

After the refinement, for a fit that the check doubts or whose two segments of a pair come close (within
:attr:`CrossingConfig.near_m`, where a crossing happens), each pair of :data:`PAIRS` is tried swapped:
both segments are turned about their joints to point at the other side's segment end (:func:`swap_start`,
the children follow), and the body is refined again from there without part gating (the network's sides
are what is in doubt). Whole limbs (:data:`CHAINS`: arms, legs) are tried where all their pairs are, or
where both limbs are raised and close (:func:`pairs_to_try`; arms crossed overhead fitted as parallel
arms). The fit itself is refined again the same way (``none``), so that every candidate has had the same
iterations; a swap that scores clearly above ``none`` after
:attr:`CrossingConfig.stop_at` of them stops there and is not taken (none such won later on the measured
sets). A swap is kept when its surface score (:func:`surface_score`, symmetric robust Chamfer in cm) is
lower than ``none``'s by :attr:`CrossingConfig.min_gain` (relative), else ``none`` is kept when it scores
lower than the fit; nothing changes for a fit that is lost altogether (score above
:attr:`CrossingConfig.max_score_cm`: every start is far off there and the score does not tell them
apart). Measured in experiments/fitting/crossing.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
import torch

from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS
from arteq.geometry.rotations import rotation_between

_J = {n: i for i, n in enumerate(JOINT_NAMES)}
#: name -> (left joint, right joint, left segment end, right segment end); the part that turns about the
#: joint is the segment (its children follow it).
PAIRS: dict[str, tuple[int, int, int, int]] = {
    "upper_arms": (_J["left_shoulder"], _J["right_shoulder"], _J["left_elbow"], _J["right_elbow"]),
    "forearms": (_J["left_elbow"], _J["right_elbow"], _J["left_wrist"], _J["right_wrist"]),
    "thighs": (_J["left_hip"], _J["right_hip"], _J["left_knee"], _J["right_knee"]),
    "shins": (_J["left_knee"], _J["right_knee"], _J["left_ankle"], _J["right_ankle"]),
}
#: whole limbs swapped at once: each pair of the chain in turn, every segment aimed at where the other side's
#: segment ended in the fit (a cartwheel's arms fitted crossed overhead need both upper arms and forearms
#: swapped: the upper arms alone leave the forearms pointing back across; experiments/fitting/crossing.md)
CHAINS: dict[str, tuple[str, ...]] = {"arms": ("upper_arms", "forearms"), "legs": ("thighs", "shins")}
#: every limb swapped at once, tried where both chains are: a body read with all four limbs on the wrong
#: side (a bow fitted with the left arm and leg where the right ones are) is not undone by one chain
ALL_LIMBS = "limbs"
SWAPS: dict[str, tuple[str, ...]] = {**CHAINS, ALL_LIMBS: CHAINS["arms"] + CHAINS["legs"]}


@dataclass
class CrossingConfig:
    """When and how swapped limb pairs are tried (values: experiments/fitting/crossing.md)."""

    #: a fit whose two segments of a pair pass within this distance (m) tries that pair
    near_m: float = 0.15
    #: a fit the check doubts (status uncertain) tries every pair
    doubtful_tries_all: bool = True
    #: refinement iterations from each swapped start (no gating)
    iters: int = 30
    #: a swap (or placed limb) taken is refined this many iterations more from where it ended, kept where it
    #: then scores lower (0: off). Since 2026-12-07: arms overhead read swapped had ended 1.3-2.1 cm V2V after
    #: the swap's 30 iterations, 0.9-1.9 after 60 more; experiments/fitting/polish/
    polish_iters: int = 60
    #: keep a swap whose score is lower than the fit's by this fraction
    min_gain: float = 0.03
    #: no swap for a fit scoring above this (cm): every start is far off there
    max_score_cm: float = 4.0
    #: at this iteration (< 0: never) a swap scoring above the fit refined again (``none``) by more than
    #: ``stop_margin`` (relative) stops and is not taken (experiments/fitting/stops.md)
    stop_at: int = 8
    stop_margin: float = 0.05
    #: also try the whole limbs of :data:`CHAINS`: where all their pairs are tried, or where both limbs
    #: are raised (each limb's end ``chain_raised_m`` beyond its root along the pelvis -> neck axis: arms
    #: overhead) and every pair of the chain comes within ``chain_near_m`` (0: only the former)
    chains: bool = True
    #: 0.3 until 2026-12-06: an adult's arms crossed overhead, fitted parallel 30.3 cm apart, stayed 21 cm off
    #: (experiments/fitting/crossing.md, last section)
    chain_near_m: float = 0.4
    chain_raised_m: float = 0.1
    #: also try all four limbs swapped at once (:data:`ALL_LIMBS`) where both chains are tried (off: on the
    #: lost acrobatic fits it starts nearer the truth, 39 -> 20 cm V2V on a bow, but refines to a worse
    #: surface score than the fit, so it is never kept; experiments/fitting/lost_fits.md)
    all_limbs: bool = False
    #: also try each limb placed on the largest group of scan points off the fit (:mod:`arteq.fit.reach`),
    #: for a fit the check doubts with such a group (``off_fit_limb``) of at least ``reach_min_points``; a
    #: limb taken, the fit tries again from there (``reach_rounds`` rounds in all: a second limb off). Only
    #: where the fit scores at most ``reach_max_score_cm``: above it the fit is lost as a whole, and the score
    #: took limbs placed wrong over it (a plough 17.6 -> 42.0 cm; experiments/scan_model/spine/reach/)
    reach: bool = True
    reach_min_points: int = 30
    reach_rounds: int = 2
    reach_max_score_cm: float = 3.0
    #: a fit the check doubts that scores above ``reach_max_score_cm`` (lost as a whole: a plough, a wheel, a
    #: bow read with the pelvis upside down) also tries its lower torso turned (:mod:`arteq.fit.torso_turns`),
    #: each start refined ``torso_iters`` iterations (a pelvis turned by a half turn is not refined back in
    #: 30), ``torso_rounds`` rounds: the next from the fit kept, its torso turned again while it scores above
    #: ``reach_max_score_cm``, else its limbs placed (``reach``); kept by the ``min_gain`` rule, whatever the
    #: fit's score (``max_score_cm`` does not apply); experiments/scan_model/spine/torso/
    torso: bool = True
    torso_iters: int = 60
    torso_rounds: int = 2
    #: with the fitter's retries on (``Fitter(retries=...)``, ``torso_retry``): the torso step is left out of
    #: the first fit and of every retry, and run once, on the fit the retries keep (where it is still doubted
    #: and scores above ``reach_max_score_cm``); off, every one of those fits runs it. On since 2026-12-07:
    #: 28-38 % less time on lost scans, the same accuracy within the fitter seeds' spread
    #: (experiments/scan_model/spine/torso/kept/)
    torso_once: bool = True
    #: after the steps above, a fit with a group of scan points off it (``LostHandConfig.min_points`` or more)
    #: tries each arm that reaches the group with its hand put there, the arm alone fitted on a local
    #: objective (:mod:`arteq.fit.lost_hand`): a fist near the knees that the network gave none of the
    #: hand's points. On since 2026-12-07 (experiments/fitting/lost_hand/README.md)
    lost_hand: bool = True
    #: where that step tried arms and kept none, the check flags the fit (``hand_off_fit``, uncertain: a
    #: doubted full scan is then retried); off, it is written as the other checks say
    lost_hand_flag: bool = True

    @classmethod
    def from_strings(cls, items: list[str] | tuple[str, ...], **base) -> CrossingConfig:
        """A config from ``KEY=VALUE`` strings over ``base`` (:func:`arteq.config.dataclass_from_strings`)."""
        from arteq.config import dataclass_from_strings

        return dataclass_from_strings(cls, items, "crossing", **base)


def swap_start(local: np.ndarray, global_rot: np.ndarray, joints: np.ndarray, pair: str) -> np.ndarray:
    """Local rotations ``[22, 3, 3]`` with ``pair``'s two segments each turned about its joint to point at
    the other side's segment end (``global_rot [22, 3, 3]``, ``joints [22, 3]`` of the posed fit); for a
    chain of :data:`CHAINS`, its pairs in turn, each segment (moved by the turns before) aimed at where the
    other side's segment ended in the fit."""
    from arteq.fit.refine import branch_parts

    pairs = SWAPS.get(pair, (pair,))
    g = np.array(global_rot, dtype=np.float64, copy=True)
    pos = np.array(joints, dtype=np.float64, copy=True)
    for p in pairs:
        lj, rj, le, re = PAIRS[p]
        for j, end, other in ((lj, le, re), (rj, re, le)):
            aim = rotation_between(
                torch.as_tensor(pos[end] - pos[j]), torch.as_tensor(joints[other] - pos[j])
            ).numpy()
            moved = branch_parts(j)  # the segment and what hangs from it turn rigidly about its joint
            g[moved] = aim @ g[moved]
            pos[moved] = pos[j] + (pos[moved] - pos[j]) @ aim.T
    out = np.array(local, dtype=np.float64, copy=True)
    for p in pairs:
        for j in PAIRS[p][:2]:
            out[j] = g[PARENTS[j]].T @ g[j]
    return out


def segment_gap(joints: np.ndarray, pair: str, samples: int = 21) -> float:
    """Closest distance (m) between ``pair``'s left and right segments (joint to segment end)."""
    lj, rj, le, re = PAIRS[pair]
    t = np.linspace(0.0, 1.0, samples)[:, None]
    a = joints[lj] + t * (joints[le] - joints[lj])
    b = joints[rj] + t * (joints[re] - joints[rj])
    return float(np.linalg.norm(a[:, None] - b[None], axis=-1).min())


def surface_score(
    points: np.ndarray, vertices: np.ndarray, subset: np.ndarray, cap_m: float = 0.05, trim: float = 0.15
) -> float:
    """Symmetric robust Chamfer (cm): the mean capped distance of the points to the vertices, plus that of
    the ``subset`` vertices to the points with the worst ``trim`` dropped (holes)."""
    from scipy.spatial import cKDTree

    d1 = np.minimum(cKDTree(vertices).query(points)[0], cap_m).mean()
    d2 = np.sort(np.minimum(cKDTree(points).query(vertices[subset])[0], cap_m))
    d2 = d2[: max(1, int(round((1 - trim) * len(d2))))].mean()
    return float((d1 + d2) * 100)


def pairs_to_try(joints: np.ndarray, doubtful: bool, config: CrossingConfig | None = None) -> list[str]:
    """The pairs a fit tries: all when the check doubts it (and the config says so), else those whose
    segments come within ``near_m``."""
    cfg = config or CrossingConfig()
    if doubtful and cfg.doubtful_tries_all:
        pairs = list(PAIRS)
    else:
        pairs = [p for p in PAIRS if segment_gap(joints, p) < cfg.near_m]
    if cfg.chains:  # a whole limb where every pair of it is tried, or raised limbs that come close
        pairs += [
            c for c, parts in CHAINS.items() if all(p in pairs for p in parts) or _near_raised(joints, c, cfg)
        ]
        if cfg.all_limbs and all(c in pairs for c in CHAINS):
            pairs.append(ALL_LIMBS)
    return pairs


def _near_raised(joints: np.ndarray, chain: str, cfg: CrossingConfig) -> bool:
    """Both limbs of ``chain`` raised (the end ``chain_raised_m`` beyond the root along pelvis -> neck) and
    every pair of it within ``chain_near_m``: arms overhead, where a crossing reads as parallel arms."""
    parts = CHAINS[chain]
    up = joints[_J["neck"]] - joints[_J["pelvis"]]
    up = up / max(float(np.linalg.norm(up)), 1e-9)
    lj, rj = PAIRS[parts[0]][:2]
    le, re = PAIRS[parts[-1]][2:]
    if min(float((joints[le] - joints[lj]) @ up), float((joints[re] - joints[rj]) @ up)) < cfg.chain_raised_m:
        return False
    return max(segment_gap(joints, p) for p in parts) < cfg.chain_near_m


def try_swaps(
    body: torch.nn.Module,
    points: list[np.ndarray],
    fit: dict[str, torch.Tensor],
    subset: np.ndarray,
    tries: list[list[str]],
    refine_config,
    config: CrossingConfig | None = None,
    keep_all: bool = False,
    extra: list[dict[str, np.ndarray]] | None = None,
) -> list[dict]:
    """Refine every swapped start of ``tries`` (one batch) and pick, per scan, the swap to keep.

    Args:
        points: per scan ``[N, 3]`` (metres, the refinement's frame).
        fit: the refined fits, ``local_rotmats [B, 22, 3, 3]``, ``global_rotmats``, ``joints [B, 22, 3]``,
            ``vertices [B, V, 3]``, ``betas [B, nb]``, ``transl [B, 3]``.
        tries: per scan, the pairs to try (empty: none).
        extra: per scan, more starts to try beside the swaps: name -> local rotations ``[22, 3, 3]`` (e.g.
            :func:`arteq.fit.reach.reach_starts`), picked as the swaps are.
        refine_config: the fitter's :class:`arteq.fit.refine.RefineConfig` (iterations, gating and the
            kernel's start replaced by the crossing's).
    Returns:
        per scan ``{"tried": {pair or "none": score}, "score": the fit's score, "taken": the pair, "none"
        (the fit refined again) or "" (the fit kept), and unless "" "local_rotmats", "betas", "transl",
        "vertices", "joints", "global_rotmats" (tensors of one scan)}``; ``"stopped": {pair: iteration}``
        for the swaps that stopped at :attr:`CrossingConfig.stop_at` (their score there); with ``keep_all``
        also ``"all_vertices": {pair or "none": [V, 3]}`` and ``"all_local": {pair or "none": [22, 3, 3]}``
        of every start tried (for studies).
    """
    from arteq.fit.refine import refine

    cfg = config or CrossingConfig()
    dtype, device = body.v_template.dtype, body.v_template.device
    out = []
    rows = []  # (scan, pair or "none")
    starts = []
    for i, pairs in enumerate(tries):
        verts = fit["vertices"][i].detach().double().cpu().numpy()
        score = surface_score(points[i], verts, subset)
        out.append({"tried": {}, "score": score, "taken": ""})
        more = extra[i] if extra else {}
        if not (pairs or more) or score > cfg.max_score_cm:
            continue
        local = fit["local_rotmats"][i].detach().double().cpu().numpy()
        grot = fit["global_rotmats"][i].detach().double().cpu().numpy()
        joints = fit["joints"][i].detach().double().cpu().numpy()
        rows.append((i, "none"))
        starts.append(local)
        for pair in pairs:
            rows.append((i, pair))
            starts.append(swap_start(local, grot, joints, pair))
        for name, start in more.items():
            rows.append((i, name))
            starts.append(np.asarray(start, dtype=np.float64))
    if not rows:
        return out
    idx = [i for i, _ in rows]
    # from a refined fit: no part gating, no swing search (the fit had it), the kernel at its final width
    rc = dataclasses.replace(
        refine_config, iters=cfg.iters, gate_frac=0.0, top_parts=NUM_JOINTS, swing_at=-1.0
    )
    rc.sigma_start = rc.sigma_end
    pts = torch.as_tensor(np.stack([points[i] for i in idx]), dtype=dtype, device=device)
    init = {
        "local_rotmats": torch.as_tensor(np.stack(starts), dtype=dtype, device=device),
        "betas": fit["betas"][idx].detach().to(device=device, dtype=dtype),
        "transl": fit["transl"][idx].detach().to(device=device, dtype=dtype),
    }
    probs = torch.ones(len(rows), pts.shape[1], NUM_JOINTS, dtype=dtype, device=device)  # no part gating
    stopped: dict[int, float] = {}  # row -> its score where it stopped

    def stop(it: int, alive: torch.Tensor, verts: torch.Tensor) -> torch.Tensor:
        where = {int(r): a for a, r in enumerate(alive)}
        score = {
            r: surface_score(points[rows[r][0]], verts[a].detach().double().cpu().numpy(), subset)
            for r, a in where.items()
        }
        out_rows = torch.zeros(len(alive), dtype=torch.bool)
        for r, a in where.items():
            i, pair = rows[r]
            base = rows.index((i, "none"))
            if pair != "none" and base in score and score[r] > score[base] * (1 + cfg.stop_margin):
                out_rows[a] = True
                stopped[r] = score[r]
        return out_rows

    res = refine(body, pts, probs, init, rc, stop=stop, stop_at=(cfg.stop_at,) if cfg.stop_at >= 0 else ())
    row_of: dict[tuple[int, str], int] = {}
    for r, (i, pair) in enumerate(rows):
        if r in stopped:
            out[i].setdefault("stopped", {})[pair] = cfg.stop_at
            out[i]["tried"][pair] = stopped[r]
        else:
            out[i]["tried"][pair] = surface_score(
                points[i], res.vertices[r].detach().double().cpu().numpy(), subset
            )
        row_of[(i, pair)] = r
        if keep_all:
            out[i].setdefault("all_vertices", {})[pair] = res.vertices[r].detach()
            out[i].setdefault("all_local", {})[pair] = res.local_rotmats[r].detach()
    for i, rec in enumerate(out):
        if "none" not in rec["tried"]:
            continue
        base = rec["tried"]["none"]
        lost = rec.get("stopped", {})
        swaps = {
            p: v
            for p, v in rec["tried"].items()
            if p != "none" and p not in lost and v < (1 - cfg.min_gain) * base
        }
        if swaps:
            pick = min(swaps, key=swaps.get)
        elif base < rec["score"]:
            pick = "none"
        else:
            continue
        rec["taken"] = pick
        _take(rec, res, row_of[(i, pick)])
    if cfg.polish_iters > 0:
        _polish(body, points, subset, out, dataclasses.replace(rc, iters=cfg.polish_iters))
    return out


def _polish(body: torch.nn.Module, points: list[np.ndarray], subset: np.ndarray, out: list[dict], rc) -> None:
    """The swaps (and placed limbs) :func:`try_swaps` took, refined ``rc.iters`` more iterations from where
    they ended (``rc``: its config without gating); kept where their surface score is lower
    (``out[i]["polish_cm"]``: the score after, whether kept or not)."""
    from arteq.fit.refine import refine

    idx = [i for i, rec in enumerate(out) if rec["taken"] not in ("", "none")]
    if not idx:
        return
    dtype, device = body.v_template.dtype, body.v_template.device
    pts = torch.as_tensor(np.stack([points[i] for i in idx]), dtype=dtype, device=device)
    init = {k: torch.stack([out[i][k].detach() for i in idx]).to(device=device, dtype=dtype)
            for k in ("local_rotmats", "betas", "transl")}  # fmt: skip
    probs = torch.ones(len(idx), pts.shape[1], NUM_JOINTS, dtype=dtype, device=device)
    res = refine(body, pts, probs, init, rc)
    for r, i in enumerate(idx):
        rec = out[i]
        after = surface_score(points[i], res.vertices[r].detach().double().cpu().numpy(), subset)
        rec["polish_cm"] = after
        if after < rec["tried"][rec["taken"]]:
            _take(rec, res, r)


def _take(rec: dict, res, r: int) -> None:
    """``rec`` (one scan's record of :func:`try_swaps`) takes row ``r`` of the refinement output ``res``."""
    for k in ("local_rotmats", "betas", "transl", "vertices", "joints", "global_rotmats"):
        rec[k] = getattr(res, k)[r]
