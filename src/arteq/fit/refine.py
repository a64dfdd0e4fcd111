"""Test-time refinement of a predicted body against its scan: robust, part-gated ICP (batched).

Start: a prediction (local rotations, betas, translation) and per-point part probabilities, e.g. the
ArtEq network's. Parameters per scan: a residual rotation ``delta_k`` per joint (``theta_k =
theta_k^start exp([delta_k])``, starting at 0), a translation offset and the betas. Objective per scan
(centimetres squared; scans are summed, points averaged within a scan, so scans stay independent); the
scan -> model term on at most ``points`` of each scan's points (farthest-point subset):

* scan -> model: each point against the posed vertex it is matched to, point-to-plane plus ``w_p2p``
  times point-to-point, through a Geman-McClure kernel ``rho(r^2) = s^2 r^2 / (s^2 + r^2)`` whose scale
  ``s`` shrinks geometrically from ``sigma_start`` to ``sigma_end`` (outliers lose their pull);
  during the first ``gate_frac`` of the iterations a point may only match vertices of its predicted
  parts (top ``top_parts`` parts with probability >= ``min_prob``; the most probable always), which
  keeps limbs out of the wrong local minima free nearest neighbours fall into; afterwards matches are
  free, at half weight when the matched part is not one of the point's predicted ones;
* model -> scan: a fixed farthest-point subset of vertices against the scan, point-to-point, the
  worst ``m2s_trim`` fraction dropped (holes), same kernel; for a partial scan (one camera's view,
  ``m2s_visible``) only the subset vertices the camera sees take part (recomputed at every re-match), so
  the unseen side is not pulled toward points that do not exist;
* priors: ``w_delta`` mean squared residual rotation (rad^2, anchors to the start; decays linearly to
  ``w_delta_end``), ``w_betas`` mean squared betas (units of sigma); betas beyond the first
  ``early_betas`` are frozen for the first third.

Two searches restart joints the local matches cannot bring back (:func:`swing_search`, :func:`twist_search`;
experiments/fitting/turn_search.md): at the end of the gated phase, an arm segment that sits away from its
points is swung about its joint to point where they are; at 75 % of the iterations, each hand is rolled
about its forearm to the turn that lies closest to the scan. A kept turn becomes its joint's start.

Adam with per-group learning rates and cosine decay. Correspondences: ``scipy.spatial.cKDTree`` on CPU
(one tree per part when gated), brute-force ``torch.cdist`` in chunks on GPU; scan -> model matches are
renewed every ``gate_reassoc_every`` iterations while gated and every ``reassoc_every`` after (between
renewals only the vertices the objective uses are posed), model -> scan matches at every iteration.
"""

from __future__ import annotations

import functools
import hashlib
import math
import time
import warnings
import weakref
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import numpy as np
import roma
import torch

from arteq.body.lbs import skin
from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS, PARENTS
from arteq.geometry.normals import vertex_normals
from arteq.geometry.pointops import fps_from_centroid
from arteq.geometry.rotations import rotation_between
from arteq.results import BodyFitResult


@dataclass
class RefineConfig:
    """Knobs of :func:`refine` (defaults measured in ``experiments/fitting/README.md``)."""

    iters: int = 60  # 40 before 2026-12-03 (experiments/fitting/converge.md)
    #: scan points the scan -> model term uses: a subset of each scan's when it has more (0: all); half of a
    #: 5000-point scan converges as well; 60 iterations on it made whole fits about 7 % slower than 40 on
    #: every point, every point at 60 would cost 40 % more refinement (converge.md)
    points: int = 2500
    #: how: ``fps`` (farthest points from the centroid's nearest: dense regions thinned, sparse ones kept
    #: whole) or ``random`` (a fixed random subset, which lost two fits of ~170 that every point kept)
    subset: str = "fps"
    sigma_start: float = 8.0  # cm
    sigma_end: float = 5.0  # cm; 1.0 before 2026-12-02 (experiments/fitting/README.md, section 1b)
    w_p2p: float = 0.1
    w_m2s: float = 1.0
    m2s_vertices: int = 2000
    m2s_trim: float = 0.15
    gate_frac: float = 0.4
    top_parts: int = 2
    min_prob: float = 0.2
    w_delta: float = 20.0
    w_delta_end: float = 2.0
    w_betas: float = 0.1  # 0.5 before 2026-12-03 (converge.md)
    early_betas: int = 2
    lr_rot: float = 0.02
    lr_transl: float = 0.01
    lr_betas: float = 0.1  # 0.05 before 2026-12-03
    reassoc_every: int = 2  # after the gated phase, re-match every this many iterations
    gate_reassoc_every: int = 2  # during the gated phase, re-match every this many iterations
    #: turn search (:func:`twist_search`): at this fraction of the iterations (< 0: never), each joint of
    #: ``twist_joints`` is tried turned about its parent segment's axis by ``twist_steps`` angles
    twist_at: float = 0.75
    twist_joints: str = "left_wrist,right_wrist"
    twist_steps: int = 12
    twist_min_gain: float = 0.15  # cm: a turn is kept when it lowers the part's score by this much
    twist_max_score: float = 2.5  # cm: and when the turned part's score is at most this (it fits there)
    #: swing search (:func:`swing_search`): at this fraction of the iterations (< 0: never), each branch of
    #: ``swing_joints`` scoring above ``swing_min_score`` (cm) is tried pointing in ``swing_dirs`` directions
    #: (measured in experiments/fitting/turn_search.md)
    swing_at: float = 0.4
    swing_joints: str = "left_shoulder,right_shoulder,left_elbow,right_elbow"
    swing_dirs: int = 162
    swing_min_score: float = 3.0
    swing_min_gain: float = 1.0  # cm: a swing is kept when it lowers the branch's score by this much
    swing_max_score: float = 3.0  # cm: and when the swung branch scores at most this
    backend: str = "auto"  # auto | kdtree | torch
    #: threads that share a batch's nearest-neighbour searches on CPU (0: torch's thread count)
    workers: int = 0

    def __post_init__(self) -> None:
        if self.subset not in ("random", "fps"):
            raise ValueError(f"subset must be random or fps, got {self.subset!r}")
        turn_joint_ids(self.twist_joints)  # a bad joint name fails here, not mid-fit
        for j in turn_joint_ids(self.swing_joints):
            if j not in PARENTS:
                raise ValueError(
                    f"swing_joints: {JOINT_NAMES[j]!r} ends a chain (a swing aims a joint's child)"
                )

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_strings(cls, items: list[str] | tuple[str, ...], **base) -> RefineConfig:
        """A config from ``KEY=VALUE`` strings (command lines: ``--set sigma_end=3``) over ``base``; each
        value is read as its field's type. An unknown key or an unreadable value is a ``ValueError``."""
        from arteq.config import dataclass_from_strings

        return dataclass_from_strings(cls, items, "refine", **base)


#: The result of :func:`refine`: :class:`arteq.results.BodyFitResult` (``pose_aa`` is None), the type
#: :func:`arteq.optim_fit.fit_body` returns too.
RefineOutput = BodyFitResult


class BodyTables:
    """Per-body constants of the refinement, computed once (:func:`body_tables` caches them): the
    model -> scan vertex subset, the vertex-face incidence, and the joint regressor folded into the
    template and shape space (rest joints are linear in the betas)."""

    def __init__(self, body: torch.nn.Module, m2s_vertices: int):
        # evenly spread vertices: the FPS of arteq.geometry from the vertex nearest the centroid
        template = body.v_template.detach().double().cpu()[None]
        count = min(m2s_vertices, template.shape[1])
        self.m2s_subset = fps_from_centroid(template, count)[0].to(body.v_template.device)
        faces = body.faces
        f = faces.shape[0]
        rows = faces.reshape(-1)
        cols = torch.arange(f, device=faces.device).repeat_interleave(3)
        vals = torch.ones(3 * f, dtype=body.v_template.dtype, device=faces.device)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # "sparse CSR support is in beta"
            coo = torch.sparse_coo_tensor(
                torch.stack([rows, cols]), vals, (body.v_template.shape[0], f), check_invariants=True
            )
            self.incidence = coo.coalesce().to_sparse_csr()
        self.j_template = body.J_regressor @ body.v_template  # [K, 3]
        self.j_shapedirs = torch.einsum("kv,vcl->kcl", body.J_regressor, body.shapedirs)  # [K, 3, nb]
        self._template = template
        self._part_labels = body.part_labels.cpu()
        self._branches: dict[tuple[int, int], torch.Tensor] = {}

    def branch_subset(self, joint: int, count: int = 150) -> torch.Tensor:
        """``[<= count]`` evenly spread vertices (FPS) of ``joint``'s part and its descendants' (cached)."""
        key = (joint, count)
        if key not in self._branches:
            inside = torch.tensor(branch_parts(joint))
            vidx = torch.nonzero(torch.isin(self._part_labels, inside))[:, 0]
            pick = fps_from_centroid(self._template[:, vidx], min(count, len(vidx)))[0]
            self._branches[key] = vidx[pick].to(self.j_template.device)
        return self._branches[key]

    def branch_fraction(self, joint: int) -> float:
        """The share of the body's surface on ``joint``'s part and its descendants' (of the evenly spread
        model -> scan subset)."""
        labels = self._part_labels[self.m2s_subset.cpu()]
        return float(torch.isin(labels, torch.tensor(branch_parts(joint))).double().mean())


_TABLES: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def body_tables(body: torch.nn.Module, m2s_vertices: int = 2000) -> BodyTables:
    """Cached :class:`BodyTables` of ``body`` (recomputed if the device or subset size changed)."""
    t = _TABLES.get(body)
    if (
        t is None
        or len(t.m2s_subset) != min(m2s_vertices, body.v_template.shape[0])
        or (t.j_template.device != body.v_template.device)
    ):
        with torch.no_grad():
            t = BodyTables(body, m2s_vertices)
        _TABLES[body] = t
    return t


#: the last clouds' farthest-point subsets (:func:`fps_subsets`), by content
_FPS_SUBSETS: OrderedDict[bytes, torch.Tensor] = OrderedDict()
_FPS_SUBSETS_MAX = 64


def fps_subsets(points: torch.Tensor, count: int) -> torch.Tensor:
    """``[B, count]`` sorted indices of each cloud's farthest-point subset (:func:`fps_from_centroid`,
    float64).

    A cloud met before is not sampled again: the fitter refines the same points from a second start in
    the same batch, and again in its crossed-limb refits and retries (about 0.1 s per 5000-point scan
    each time on a CPU). Rows are keyed by their float64 bytes: the indices are those of a fresh run.
    """
    x = points.detach().double()
    tag = int(count).to_bytes(8, "little")
    keys = [hashlib.blake2b(row.cpu().numpy().tobytes(), digest_size=16).digest() + tag for row in x]
    first: dict[bytes, int] = {}  # each cloud not met before: its first row
    for i, k in enumerate(keys):
        if k not in _FPS_SUBSETS:
            first.setdefault(k, i)
    if first:
        rows = list(first.values())
        new = fps_from_centroid(x[rows], count).sort(dim=1).values.cpu()
        for k, idx in zip(first, new, strict=True):
            _FPS_SUBSETS[k] = idx
    for k in keys:
        _FPS_SUBSETS.move_to_end(k)
    while len(_FPS_SUBSETS) > max(_FPS_SUBSETS_MAX, len(keys)):
        _FPS_SUBSETS.popitem(last=False)
    return torch.stack([_FPS_SUBSETS[k] for k in keys]).to(points.device)


def subset_rows(body: torch.nn.Module, sel: torch.Tensor, nb: int) -> tuple[torch.Tensor, ...]:
    """The body's rows of the vertices ``sel [S]`` that :func:`skin_subset` uses (template, the first ``nb``
    shape directions, skinning weights): gathered once per set of vertices, not at every iteration."""
    return body.v_template[sel], body.shapedirs[sel, :, :nb], body.lbs_weights[sel]


def skin_subset(
    body: torch.nn.Module,
    tables: BodyTables,
    sel: torch.Tensor,
    betas,
    rotmats,
    transl,
    rows: tuple[torch.Tensor, ...] | None = None,
) -> torch.Tensor:
    """Posed vertices ``sel [S]`` only (differentiable): ``[B, S, 3]``, the same as
    ``body(betas, rotmats, transl).vertices[:, sel]`` for a body without pose correctives. ``rows``:
    :func:`subset_rows` of ``sel`` when the caller keeps them."""
    nb = betas.shape[1]
    template, shapedirs, weights = rows if rows is not None else subset_rows(body, sel, nb)
    v_shaped = template + torch.einsum("bl,vcl->bvc", betas, shapedirs)
    rest_joints = tables.j_template + torch.einsum("bl,kcl->bkc", betas, tables.j_shapedirs[..., :nb])
    verts, _, _ = skin(v_shaped, rest_joints, rotmats, weights, transl=transl)
    return verts


def geman_mcclure(r2: torch.Tensor, sigma: float) -> torch.Tensor:
    """``s^2 r^2 / (s^2 + r^2)`` of squared residuals ``r2`` (like ``r2`` near 0, at most ``s^2``)."""
    s2 = sigma * sigma
    return s2 * r2 / (s2 + r2)


def allowed_parts(probs: torch.Tensor, top: int = 2, min_prob: float = 0.2) -> torch.Tensor:
    """``[B, N, K]`` bool: the ``top`` most probable parts of each point with probability >= ``min_prob``
    (the most probable always)."""
    k = min(top, probs.shape[-1])
    val, idx = probs.topk(k, dim=-1)
    keep = val >= min_prob
    keep[..., 0] = True
    out = torch.zeros_like(probs, dtype=torch.bool)
    out.scatter_(-1, idx, keep)
    return out


@functools.cache
def _thread_pool(threads: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(threads, thread_name_prefix="arteq-match")


class _KDTreeMatcher:
    """Nearest-vertex matches with scipy's cKDTree (CPU). ``workers`` threads share a batch's scans (cKDTree
    releases the GIL while it builds and searches); every scan's matches are the same either way."""

    def __init__(
        self, points: torch.Tensor, allowed: torch.Tensor, part_labels: torch.Tensor, workers: int,
        scan: torch.Tensor | None = None,
    ):  # fmt: skip
        """``points [B, N, 3]`` are matched to the model (``allowed [B, N, K]``); the model is matched to
        ``scan [B, M, 3]`` (default: ``points``), e.g. the whole scan when ``points`` is a subset of it."""
        from scipy.spatial import cKDTree

        self.cKDTree = cKDTree
        self.workers = workers
        self.points = points.detach().cpu().double().numpy()
        self.scan_trees = [
            cKDTree(p) for p in (self.points if scan is None else scan.detach().cpu().double().numpy())
        ]
        labels = part_labels.cpu().numpy()
        k = allowed.shape[-1]
        self.part_vidx = [np.nonzero(labels == j)[0] for j in range(k)]
        al = allowed.cpu().numpy()
        self.allowed_idx = [[np.nonzero(al[b, :, j])[0] for j in range(k)] for b in range(al.shape[0])]

    def rows(self, keep: np.ndarray) -> _KDTreeMatcher:
        """The matcher of the scans ``keep [B]`` (bool) only (its trees shared)."""
        out = object.__new__(_KDTreeMatcher)
        out.cKDTree, out.workers, out.part_vidx = self.cKDTree, self.workers, self.part_vidx
        out.points = self.points[keep]
        out.scan_trees = [t for t, k in zip(self.scan_trees, keep) if k]
        out.allowed_idx = [a for a, k in zip(self.allowed_idx, keep) if k]
        return out

    def _tree(self, vertices: np.ndarray):
        """A tree over posed vertices, rebuilt at every match: the sliding-midpoint build without the
        median splits is faster to build and as fast to search here (the same nearest vertices)."""
        return self.cKDTree(vertices, leafsize=24, balanced_tree=False)

    def _gated(self, v: np.ndarray, i: int) -> np.ndarray:
        """Scan ``i``'s points matched to the nearest vertex of ``v [V, 3]`` among their allowed parts."""
        n = self.points.shape[1]
        out = np.zeros(n, dtype=np.int64)
        best = np.full(n, np.inf)
        for j, vidx in enumerate(self.part_vidx):
            pidx = self.allowed_idx[i][j]
            if len(pidx) == 0 or len(vidx) == 0:
                continue
            d, nn = self._tree(v[vidx]).query(self.points[i, pidx])
            upd = d < best[pidx]
            best[pidx[upd]] = d[upd]
            out[pidx[upd]] = vidx[nn[upd]]
        return out

    def _each(self, f: Callable[[int], np.ndarray], n: int) -> np.ndarray:
        """``f`` of every scan ``0..n-1``, stacked (on the thread pool when there is one)."""
        if self.workers > 1 and n > 1:
            return np.stack(list(_thread_pool(self.workers).map(f, range(n))))
        return np.stack([f(i) for i in range(n)])

    def scan_to_model(self, verts: torch.Tensor, gated: bool) -> torch.Tensor:
        v = verts.detach().cpu().double().numpy()

        def one(i: int) -> np.ndarray:
            return self._gated(v[i], i) if gated else self._tree(v[i]).query(self.points[i])[1]

        return torch.from_numpy(self._each(one, len(v))).to(verts.device)

    def model_to_scan(self, verts: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        """Each of ``verts [B, S, 3]``'s nearest scan point; ``rows [B, S]`` (bool, optional): only those
        vertices are matched (the others get index 0: a caller that masks them, as a partial scan's
        visibility does, never reads it)."""
        v = verts.detach().cpu().double().numpy()
        if rows is None:
            idx = self._each(lambda i: self.scan_trees[i].query(v[i])[1], len(v))
            return torch.from_numpy(idx).to(verts.device)
        use = rows.cpu().numpy()

        def one(i: int) -> np.ndarray:
            out = np.zeros(v.shape[1], dtype=np.int64)
            out[use[i]] = self.scan_trees[i].query(v[i][use[i]])[1]
            return out

        return torch.from_numpy(self._each(one, len(v))).to(verts.device)

    def scan_distance(self, i: int, query: torch.Tensor) -> torch.Tensor:
        """Distance of each of ``query [M, 3]`` to scan ``i``'s nearest point."""
        d = self.scan_trees[i].query(query.detach().cpu().double().numpy(), workers=self.workers)[0]
        return torch.from_numpy(d).to(query.device)


class _TorchMatcher:
    """Nearest-vertex matches by brute force (``torch.cdist`` in chunks): for GPUs."""

    def __init__(
        self, points: torch.Tensor, allowed: torch.Tensor, part_labels: torch.Tensor, chunk: int = 2048,
        scan: torch.Tensor | None = None,
    ):  # fmt: skip
        """As :class:`_KDTreeMatcher`."""
        self.points = points.detach()
        self.scan = self.points if scan is None else scan.detach()
        self.allowed_v = [allowed[i][:, part_labels] for i in range(points.shape[0])]  # [N, V] bool
        self.chunk = chunk

    def rows(self, keep: np.ndarray) -> _TorchMatcher:
        """The matcher of the scans ``keep [B]`` (bool) only."""
        out = object.__new__(_TorchMatcher)
        out.chunk = self.chunk
        rows = torch.as_tensor(keep, device=self.points.device)
        out.points, out.scan = self.points[rows], self.scan[rows]
        out.allowed_v = [a for a, k in zip(self.allowed_v, keep) if k]
        return out

    def _nearest(self, a: torch.Tensor, b: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
        out = []
        for s in range(0, a.shape[0], self.chunk):
            d = torch.cdist(a[s : s + self.chunk], b)
            if mask is not None:
                d = d.masked_fill(~mask[s : s + self.chunk], float("inf"))
            out.append(d.argmin(dim=1))
        return torch.cat(out)

    def scan_to_model(self, verts: torch.Tensor, gated: bool) -> torch.Tensor:
        v = verts.detach().to(self.points.dtype)
        return torch.stack(
            [
                self._nearest(self.points[i], v[i], self.allowed_v[i] if gated else None)
                for i in range(v.shape[0])
            ]
        )

    def model_to_scan(self, verts: torch.Tensor, rows: torch.Tensor | None = None) -> torch.Tensor:
        """As :meth:`_KDTreeMatcher.model_to_scan` (every vertex is matched: ``rows`` saves nothing here)."""
        v = verts.detach().to(self.points.dtype)
        return torch.stack([self._nearest(v[i], self.scan[i], None) for i in range(v.shape[0])])

    def scan_distance(self, i: int, query: torch.Tensor) -> torch.Tensor:
        """Distance of each of ``query [M, 3]`` to scan ``i``'s nearest point."""
        q = query.detach().to(self.points.dtype)
        return torch.cat([torch.cdist(q[s : s + self.chunk], self.scan[i]).amin(1)
                          for s in range(0, q.shape[0], self.chunk)])  # fmt: skip


def visible_trimmed_mean(
    values: torch.Tensor, d2: torch.Tensor, visible: torch.Tensor, trim: float
) -> torch.Tensor:
    """``[B]``: per row, the mean of ``values [B, S]`` over the ``visible`` entries, the ``trim`` fraction of
    them with the largest ``d2`` dropped (at least one kept; 0 for a row with none visible)."""
    order = d2.masked_fill(~visible, float("inf")).sort(dim=1).values
    keep = ((1 - trim) * visible.sum(1)).round().clamp_min(1).long()
    use = visible & (d2 <= order.gather(1, (keep - 1)[:, None]))
    return (values * use).sum(-1) / use.sum(-1).clamp_min(1)


def _gather(x: torch.Tensor, idx: torch.Tensor) -> torch.Tensor:
    """``x [B, M, C]``, ``idx [B, N]`` -> ``[B, N, C]``."""
    return torch.gather(x, 1, idx[..., None].expand(-1, -1, x.shape[-1]))


def turn_joint_ids(names: str) -> list[int]:
    """Joint indices of a comma-separated list of joint names (``""``: none); an unknown name is an error."""
    out = []
    for name in (n.strip() for n in names.split(",")):
        if not name:
            continue
        if name not in JOINT_NAMES or PARENTS[JOINT_NAMES.index(name)] < 0:
            raise ValueError(
                f"turn search joints: {name!r} is not a non-root joint ({', '.join(JOINT_NAMES[1:])})"
            )
        out.append(JOINT_NAMES.index(name))
    return out


def twist_search(
    vertices: torch.Tensor,
    joints: torch.Tensor,
    subsets: dict[int, torch.Tensor],
    scan_distance: Callable[[int, torch.Tensor], torch.Tensor],
    steps: int = 12,
    min_gain_cm: float = 0.15,
    max_score_cm: float = 2.5,
    cap_cm: float = 5.0,
) -> torch.Tensor:
    """Turns about the parent segments' axes that bring parts onto the scan: ``[B, K, 3, 3]`` (world frame,
    identity where nothing is kept).

    For each joint ``j`` of ``subsets`` (joint -> vertex indices of its part and its descendants'), the
    branch is turned rigidly about the axis from ``j``'s parent joint through ``j`` (a hand about the
    forearm, a foot about the shin: the joint stays where it is) by ``steps`` equal angles, and scored by
    its vertices' mean distance to the scan (``scan_distance(scan, points)``, capped at ``cap_cm``). The
    best turn is kept when it scores ``min_gain_cm`` below the unturned branch and at most ``max_score_cm``
    (a branch that is not where its points are, is not fixed by turning it: a turn then only finds some
    other points to cover). Why: a hand's roll about the forearm is what the network gets least right and
    what the refinement's local matches cannot undo (half a turn away, a flat hand fits the scan's hand
    points about as well).
    """
    b = vertices.shape[0]
    eye = torch.eye(3, dtype=vertices.dtype, device=vertices.device)
    turns = eye.expand(b, NUM_JOINTS, 3, 3).clone()
    angles = torch.arange(steps, dtype=vertices.dtype, device=vertices.device) * (2 * math.pi / steps)
    for j, sub in subsets.items():
        axis = joints[:, j] - joints[:, PARENTS[j]]
        axis = axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        for i in range(b):
            rots = roma.rotvec_to_rotmat(angles[:, None] * axis[i])  # [steps, 3, 3]
            local = vertices[i, sub] - joints[i, j]
            cand = torch.einsum("sab,vb->sva", rots, local) + joints[i, j]
            d = scan_distance(i, cand.reshape(-1, 3)).reshape(steps, -1)
            score = (d * 100).clamp_max(cap_cm).mean(-1)
            best = int(score.argmin())
            if best != 0 and score[0] - score[best] >= min_gain_cm and score[best] <= max_score_cm:
                turns[i, j] = rots[best]
    return turns


def sphere_directions(count: int) -> np.ndarray:
    """``[count, 3]`` unit vectors spread evenly over the sphere (a Fibonacci lattice)."""
    i = np.arange(count) + 0.5
    z = 1 - 2 * i / count
    r = np.sqrt(np.clip(1 - z * z, 0, None))
    phi = np.pi * (1 + 5**0.5) * i
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def branch_parts(joint: int) -> list[int]:
    """``joint`` and its descendants (the parts that move with it)."""
    inside = [joint]
    for k in range(NUM_JOINTS):  # parents precede children
        if PARENTS[k] in inside:
            inside.append(k)
    return inside


def _swing_scores(
    cands: np.ndarray, own: np.ndarray, d_rest: np.ndarray, carried: float, cap_cm: float
) -> np.ndarray:
    """:func:`swing_search`'s score (cm) of each candidate placement ``cands [D, S, 3]`` of a branch: the
    mean capped distance of its vertices to the points it is responsible for (``own [M, 3]``; not to the
    whole scan, where a limb folded onto the body would find points too), plus the capped distance of each
    of those points to it or to the rest of the body (``d_rest [M]``, cm), summed over the ``carried``
    points the branch should carry. ``[D]``."""
    if not len(own):
        return np.full(len(cands), cap_cm)
    weight = 1.0
    if len(own) > 256:  # an even subset stands for them all
        pick = np.linspace(0, len(own) - 1, 256).round().astype(int)
        weight, own, d_rest = len(own) / 256, own[pick], d_rest[pick]
    c = torch.as_tensor(cands, dtype=torch.float32)
    o = torch.as_tensor(own, dtype=torch.float32)
    d = torch.cat(
        [torch.cdist(c[k : k + 32], o.expand(len(c[k : k + 32]), -1, -1)) for k in range(0, len(c), 32)]
    )
    near_own = (d.amin(2) * 100).clamp_max(cap_cm).mean(1).double()  # [D]; d: [D, S, M] metres
    to_branch = (d.amin(1).double() * 100).clamp_max(cap_cm)
    explained = torch.minimum(to_branch, torch.as_tensor(d_rest).clamp_max(cap_cm)).sum(1)
    return (near_own + weight * explained / max(1.0, carried)).numpy()


def swing_search(
    points: list[np.ndarray],
    vertices: np.ndarray,
    joints: np.ndarray,
    part_labels: np.ndarray,
    subsets: dict[int, np.ndarray],
    fractions: dict[int, float],
    dirs: int = 162,
    min_score_cm: float = 3.0,
    min_gain_cm: float = 1.0,
    max_score_cm: float = 3.0,
    explained_cm: float = 3.0,
    cap_cm: float = 5.0,
    workers: int = 1,
) -> np.ndarray:
    """Swings about joints that put lost limbs where their points are: ``[B, K, 3, 3]`` world-frame turns
    (identity where nothing is kept).

    A limb the network points the wrong way (a forearm hanging where the scan's is raised) sits in empty
    space: the refinement's kernel gives far points no pull and its trimmed model -> scan term drops the
    limb, so nothing moves it back. Per scan, each branch of ``subsets`` (joint -> evenly spread vertex
    indices of the joint's part and its descendants) is scored against the points it is responsible for
    (:func:`_swing_scores`, cm: those nearest one of its vertices, and those within its reach that no vertex
    explains within ``explained_cm``). A branch scoring above ``min_score_cm`` is swung rigidly about its
    joint to point at each of ``dirs`` directions (then finer, around the best); the best swing is kept
    when it scores ``min_gain_cm`` below the branch as it is and at most ``max_score_cm``. Branches are
    tried worst first; one that moves stops its ancestors and descendants from being tried in the same
    search. ``workers`` threads share the scans.
    """
    from scipy.spatial import cKDTree

    b = vertices.shape[0]
    grid = sphere_directions(dirs)
    child = {j: next(k for k in range(NUM_JOINTS) if PARENTS[k] == j) for j in subsets}
    branch = {j: np.isin(part_labels, branch_parts(j)) for j in subsets}

    def one(i: int) -> np.ndarray:
        turns = np.tile(np.eye(3), (NUM_JOINTS, 1, 1))
        pts, verts = points[i], vertices[i]
        d_fit, nearest = cKDTree(verts).query(pts)
        loose = d_fit * 100 > explained_cm
        todo = []
        for j, sub in subsets.items():
            pivot = joints[i, j]
            reach = np.linalg.norm(verts[branch[j]] - pivot, axis=1).max() + explained_cm / 100
            own = pts[(loose & (np.linalg.norm(pts - pivot, axis=1) <= reach)) | branch[j][nearest]]
            d_rest = cKDTree(verts[~branch[j]][::3]).query(own)[0] * 100 if len(own) else np.zeros(0)
            carried = len(pts) * fractions[j]
            current = float(_swing_scores(verts[sub][None], own, d_rest, carried, cap_cm)[0])
            todo.append((current, j, own, d_rest, carried))
        blocked: set[int] = set()
        for current, j, own, d_rest, carried in sorted(todo, key=lambda t: -t[0]):
            if current <= min_score_cm or j in blocked:
                continue
            pivot = joints[i, j]
            aim = joints[i, child[j]] - pivot
            local = verts[subsets[j]] - pivot
            best, best_rot, best_dir = current, None, None
            for step in (None, 8.0, 4.0, 2.0):  # the grid, then finer around its best
                if step is None:
                    directions = grid
                else:
                    u = np.cross(best_dir, np.eye(3)[np.argmin(np.abs(best_dir))])
                    u /= np.linalg.norm(u)
                    tilt = np.stack([u, -u, np.cross(best_dir, u), -np.cross(best_dir, u)]) * np.radians(step)
                    directions = roma.rotvec_to_rotmat(torch.as_tensor(tilt)).numpy() @ best_dir
                rots = rotation_between(torch.as_tensor(aim), torch.as_tensor(directions)).numpy()
                cands = np.einsum("dab,sb->dsa", rots, local) + pivot
                scores = _swing_scores(cands, own, d_rest, carried, cap_cm)
                k = int(scores.argmin())
                if scores[k] < best:
                    best, best_rot, best_dir = float(scores[k]), rots[k], directions[k]
                if best_dir is None:
                    break
            if best_rot is not None and current - best >= min_gain_cm and best <= max_score_cm:
                turns[j] = best_rot
                blocked.update(k for k in subsets if k in branch_parts(j) or j in branch_parts(k))
        return turns

    if b == 0:
        return np.zeros((0, NUM_JOINTS, 3, 3))
    if workers > 1 and b > 1:
        return np.stack(list(_thread_pool(workers).map(one, range(b))))
    return np.stack([one(i) for i in range(b)])


def refine_iteration(cfg: RefineConfig, fraction: float) -> int:
    """The iteration at ``fraction`` of :func:`refine`'s, moved down to one where the scan -> model matches
    are renewed (so a search or a ``stop`` there leaves the other scans' fits as they were); -1 for a
    negative fraction or one past the end."""
    iters = max(0, int(cfg.iters))
    if fraction < 0:
        return -1
    gate_iters = int(round(cfg.gate_frac * iters))
    when = int(round(fraction * iters))
    if when >= gate_iters:
        when -= (when - gate_iters) % max(1, cfg.reassoc_every)
    elif when > 0:
        when -= when % max(1, cfg.gate_reassoc_every)
    return when if 0 <= when < iters else -1


def _rows_of_params(
    opt: torch.optim.Optimizer, params: tuple[torch.Tensor, ...], keep: torch.Tensor
) -> list[torch.Tensor]:
    """``params``' rows ``keep`` as new leaves that replace them in ``opt`` (one per param group, in order),
    with their Adam moments carried over."""
    out = []
    for group, p in zip(opt.param_groups, params):
        q = p.detach()[keep].clone().requires_grad_(True)
        state = opt.state.pop(p, {})
        opt.state[q] = {
            k: (v[keep].clone() if torch.is_tensor(v) and v.dim() > 0 else v) for k, v in state.items()
        }
        group["params"] = [q]
        out.append(q)
    return out


def _rows_visible(
    m2s_visible: Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor], alive: torch.Tensor, total: int
) -> Callable[[torch.Tensor, torch.Tensor | None], torch.Tensor]:
    """``m2s_visible`` of a batch of ``total`` rows for the rows ``alive`` only (the others get the first
    row's vertices and normals: their answers are not used)."""

    def rows(x: torch.Tensor | None) -> torch.Tensor | None:
        if x is None:
            return None
        full = x[:1].expand(total, -1, -1).clone()
        full[alive.to(x.device)] = x
        return full

    def visible(verts: torch.Tensor, normals: torch.Tensor | None) -> torch.Tensor:
        return m2s_visible(rows(verts), rows(normals))[alive.to(verts.device)]

    return visible


def refine(
    body: torch.nn.Module,
    points: torch.Tensor,
    part_probs: torch.Tensor,
    init: dict[str, torch.Tensor],
    config: RefineConfig | None = None,
    callback: Callable[[int, torch.Tensor], None] | None = None,
    m2s_subset: torch.Tensor | None = None,
    m2s_visible: Callable[[torch.Tensor], torch.Tensor] | None = None,
    stop: Callable[[int, torch.Tensor, torch.Tensor], torch.Tensor] | None = None,
    stop_at: tuple[int, ...] = (),
    offset: torch.Tensor | None = None,
) -> RefineOutput:
    """Refine ``init`` against ``points`` (see module docstring).

    Args:
        body: :class:`arteq.body.BodyModel` (buffers ``faces``, ``part_labels``, ``v_template``).
        points: ``[B, N, 3]`` metres (centred clouds are best for float32 precision).
        part_probs: ``[B, N, K]`` part probabilities (or one-hot labels) of the points.
        init: ``local_rotmats [B,22,3,3]``, ``betas [B,nb]``, ``transl [B,3]``.
        config: :class:`RefineConfig`.
        callback: called as ``callback(iteration, vertices [B,V,3])`` before each step (for studies; after a
            ``stop``, the rows still refined).
        m2s_subset: ``[S]`` vertex indices for the model -> scan term (default: farthest points).
        m2s_visible: for partial scans, a function of the posed vertices ``[B, V, 3]`` and their unit
            normals (``[B, V, 3]``, the ones the re-match computed, or ``None``: compute them) giving
            ``[B, V]`` bool, the vertices each scan's camera sees (e.g.
            :func:`arteq.fit.partial.visibility_function`): the model -> scan term then uses only those of
            the subset. ``None``: every subset vertex.
        stop: at each iteration of ``stop_at``, called as ``stop(iteration, rows [A], vertices [A, V, 3])``
            with the batch indices of the scans still refined and their posed vertices; returns ``[A]`` bool,
            the scans to stop refining there (e.g. the worse of two starts of one scan). A stopped scan's
            result is its fit at that iteration; the others' are those of a run without ``stop`` when
            ``stop_at`` holds only re-matching iterations (:func:`refine_iteration`).
        stop_at: iterations at which ``stop`` is called.
        offset: ``[V]`` metres: the surface fitted to the scan is the body's pushed out along its vertex
            normals by this much (clothing over the skin, :mod:`arteq.fit.clothing`); the result is the
            body itself. ``None``: the body's own surface.
    Returns:
        :class:`RefineOutput`.
    """
    cfg = config or RefineConfig()
    t0 = time.perf_counter()
    if offset is not None:
        offset = offset.to(device=body.v_template.device, dtype=body.v_template.dtype)
        if offset.shape != body.v_template.shape[:1] or not torch.isfinite(offset).all():
            raise ValueError(f"refine: offset must be [{body.v_template.shape[0]}] finite metres, got "
                             f"{tuple(offset.shape)}")  # fmt: skip
    if points.ndim != 3 or points.shape[-1] != 3:
        raise ValueError(f"refine: points must be [B, N, 3], got {tuple(points.shape)}")
    b, n, _ = points.shape
    dtype, device = body.v_template.dtype, body.v_template.device
    points = points.to(device=device, dtype=dtype)
    probs = part_probs.to(device=device, dtype=dtype)
    if probs.shape[:2] != (b, n):
        raise ValueError(f"refine: part_probs must be [{b}, {n}, K], got {tuple(probs.shape)}")
    scan = points  # the model -> scan term and the searches see every point
    if 0 < cfg.points < n:  # the same subset for every call: results do not depend on batching
        if cfg.subset == "fps":
            keep = fps_subsets(points, cfg.points)  # [B, points]
            points, probs = _gather(points, keep), _gather(probs, keep)
        else:
            keep = torch.randperm(n, generator=torch.Generator().manual_seed(0))[: cfg.points].sort().values
            points, probs = points[:, keep.to(device)], probs[:, keep.to(device)]
        n = cfg.points
    start_rot = init["local_rotmats"].detach().to(device=device, dtype=dtype)
    betas = init["betas"].detach().to(device=device, dtype=dtype).clone()
    transl0 = init["transl"].detach().to(device=device, dtype=dtype)
    nb = betas.shape[1]

    allowed = allowed_parts(probs, cfg.top_parts, cfg.min_prob)
    backend = cfg.backend
    if backend == "auto":
        backend = "torch" if device.type == "cuda" else "kdtree"
    workers = cfg.workers if cfg.workers > 0 else torch.get_num_threads()
    if backend == "kdtree":
        matcher = _KDTreeMatcher(points, allowed, body.part_labels, workers, scan=scan)
    elif backend == "torch":
        matcher = _TorchMatcher(points, allowed, body.part_labels, scan=scan)
    else:
        raise ValueError(f"refine: backend must be auto, kdtree or torch, got {cfg.backend!r}")
    tables = body_tables(body, cfg.m2s_vertices)
    if m2s_subset is None:
        m2s_subset = tables.m2s_subset
    m2s_subset = m2s_subset.to(device)
    faces = body.faces
    part_labels = body.part_labels
    partial = body.posedirs.shape[0] == 0  # skin only the vertices the objective uses

    delta = torch.zeros(b, NUM_JOINTS, 3, dtype=dtype, device=device, requires_grad=True)
    dt = torch.zeros(b, 3, dtype=dtype, device=device, requires_grad=True)
    betas.requires_grad_(True)
    opt = torch.optim.Adam(
        [
            {"params": [delta], "lr": cfg.lr_rot},
            {"params": [dt], "lr": cfg.lr_transl},
            {"params": [betas], "lr": cfg.lr_betas},
        ]
    )
    base_lr = [g["lr"] for g in opt.param_groups]
    iters = max(0, int(cfg.iters))
    gate_iters = int(round(cfg.gate_frac * iters))
    early_mask = torch.zeros(nb, dtype=dtype, device=device)
    early_mask[: cfg.early_betas] = 1
    keep_m2s = max(1, int(round((1 - cfg.m2s_trim) * len(m2s_subset))))
    searches: dict[int, list[tuple[str, list[int]]]] = {}  # iteration -> [(kind, joints)]
    for kind, at, names in (
        ("swing", cfg.swing_at, cfg.swing_joints),
        ("twist", cfg.twist_at, cfg.twist_joints),
    ):
        ids = turn_joint_ids(names)
        when = refine_iteration(cfg, at) if ids else -1  # on an iteration that matches again anyway
        if when >= 0:
            searches.setdefault(when, []).append((kind, ids))
    history: list[dict[str, float]] = []
    idx = normals = w = visible = sel = inv = push_match = push_sub = None
    alive = torch.arange(b)  # the batch rows still refined (``stop``)
    stopped: dict[int, tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = {}  # row -> rot, betas, transl
    visible_of = m2s_visible

    def pose_of(d: torch.Tensor) -> torch.Tensor:
        return start_rot @ roma.rotvec_to_rotmat(d)

    @torch.no_grad()
    def turned_start(start: torch.Tensor, kind: str, ids: list[int]) -> torch.Tensor:
        """:func:`swing_search` or :func:`twist_search` on the current fit; a kept turn becomes its joint's
        start (and the prior's anchor), with that joint's residual and Adam moments reset to 0."""
        rot = pose_of(delta)
        posed = body(betas=betas, pose=rot, transl=transl0 + dt)
        if kind == "twist":
            subsets = {j: tables.branch_subset(j) for j in ids}
            turns = twist_search(posed.vertices, posed.joints, subsets, matcher.scan_distance,
                                 cfg.twist_steps, cfg.twist_min_gain, cfg.twist_max_score)  # fmt: skip
        else:
            pts = [p.cpu().double().numpy() for p in scan]
            turns = swing_search(
                pts, posed.vertices.cpu().double().numpy(), posed.joints.cpu().double().numpy(),
                part_labels.cpu().numpy(), {j: tables.branch_subset(j).cpu().numpy() for j in ids},
                {j: tables.branch_fraction(j) for j in ids}, cfg.swing_dirs, cfg.swing_min_score,
                cfg.swing_min_gain, cfg.swing_max_score, workers=workers,
            )  # fmt: skip
            turns = torch.as_tensor(turns, dtype=dtype, device=device)
        changed = (turns - torch.eye(3, dtype=dtype, device=device)).abs().amax((-1, -2)) > 0
        if not changed.any():
            return start
        par = posed.global_rotmats[:, [max(p, 0) for p in PARENTS]]
        turned = par.transpose(-1, -2) @ turns @ par @ rot  # local rotation of the turned global one
        delta[changed] = 0
        for moment in ("exp_avg", "exp_avg_sq"):
            if moment in opt.state.get(delta, {}):
                opt.state[delta][moment][changed] = 0
        return torch.where(changed[..., None, None], turned, start)

    for it in range(iters):
        frac = it / max(1, iters - 1)
        sigma = cfg.sigma_start * (cfg.sigma_end / cfg.sigma_start) ** frac
        w_delta = cfg.w_delta + (cfg.w_delta_end - cfg.w_delta) * frac
        for g, lr in zip(opt.param_groups, base_lr):
            g["lr"] = lr * (0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * frac)))
        for kind, ids in searches.get(it, []):
            start_rot = turned_start(start_rot, kind, ids)
        rot = pose_of(delta)
        gated = it < gate_iters
        every = cfg.gate_reassoc_every if gated else cfg.reassoc_every
        rematch = idx is None or (it - (0 if gated else gate_iters)) % max(1, every) == 0
        stopping = stop is not None and it in stop_at and len(alive) > 1
        if rematch or callback is not None or stopping:
            with torch.no_grad():
                vd = body(betas=betas, pose=rot, transl=transl0 + dt).vertices
            if callback is not None:
                callback(it, vd)
        if stopping:
            out_rows = torch.as_tensor(stop(it, alive.clone(), vd), dtype=torch.bool).cpu()
            if out_rows.any() and not out_rows.all():
                for a in torch.nonzero(out_rows)[:, 0].tolist():
                    stopped[int(alive[a])] = (rot[a].detach(), betas[a].detach(), (transl0 + dt)[a].detach())
                keep = ~out_rows
                kd = keep.to(device)
                alive = alive[keep]
                b = len(alive)
                points, scan, allowed = points[kd], scan[kd], allowed[kd]
                matcher = matcher.rows(keep.numpy())
                start_rot, transl0, vd = start_rot[kd], transl0[kd], vd[kd]
                delta, dt, betas = _rows_of_params(opt, (delta, dt, betas), kd)
                rot = pose_of(delta)
                if idx is not None:
                    idx, normals, w = idx[kd], normals[kd], w[kd]
                    if offset is not None:
                        push_match, push_sub = push_match[kd], push_sub[kd]
                    if visible is not None:
                        visible = visible[kd]
                    if partial:
                        sel, inv = torch.unique(torch.cat([idx.reshape(-1), m2s_subset]), return_inverse=True)
                        sel_rows = subset_rows(body, sel, nb)
                if m2s_visible is not None:
                    visible_of = _rows_visible(m2s_visible, alive, len(stopped) + len(alive))
        if rematch:
            with torch.no_grad():
                vn = vertex_normals(vd, faces, tables.incidence if partial else None)
                if offset is not None:  # the clothed surface: matched, and its normals' pushes kept
                    push = vn * offset[:, None]
                    vd = vd + push
                    push_sub = push[:, m2s_subset]
                idx = matcher.scan_to_model(vd, gated)
                normals = _gather(vn, idx)
                if offset is not None:
                    push_match = _gather(push, idx)
                if gated:
                    w = torch.ones(b, n, dtype=dtype, device=device)
                else:
                    ok = torch.gather(allowed, 2, part_labels[idx][..., None])[..., 0]
                    w = torch.where(ok, 1.0, 0.5).to(dtype)
                if visible_of is not None:  # the normals of the matched surface, when it is the posed one
                    visible = visible_of(vd, vn if offset is None else None).to(device)[:, m2s_subset]
                if partial:  # the vertices the objective uses: the matched ones and the subset
                    sel, inv = torch.unique(torch.cat([idx.reshape(-1), m2s_subset]), return_inverse=True)
                    sel_rows = subset_rows(body, sel, nb)
        if partial:
            vs = skin_subset(body, tables, sel, betas, rot, transl0 + dt, sel_rows)
            v_match = _gather(vs, inv[: b * n].view(b, n))
            v_sub = vs[:, inv[b * n :]]
        else:
            verts = body(betas=betas, pose=rot, transl=transl0 + dt).vertices
            v_match, v_sub = _gather(verts, idx), verts[:, m2s_subset]
        if offset is not None:
            v_match, v_sub = v_match + push_match, v_sub + push_sub
        sub_idx = matcher.model_to_scan(v_sub, visible)  # a partial scan: its visible vertices only
        diff = (points - v_match) * 100.0
        r2 = (diff * normals).sum(-1).square() + cfg.w_p2p * diff.square().sum(-1)
        s2m = (w * geman_mcclure(r2, sigma)).sum(-1) / w.sum(-1)
        d2 = ((v_sub - _gather(scan, sub_idx)) * 100.0).square().sum(-1)
        if visible is None:
            kept = torch.topk(d2.detach(), keep_m2s, dim=1, largest=False).indices
            m2s = geman_mcclure(torch.gather(d2, 1, kept), sigma).mean(-1)
        else:
            m2s = visible_trimmed_mean(geman_mcclure(d2, sigma), d2.detach(), visible, cfg.m2s_trim)
        prior = w_delta * delta.square().sum(-1).mean(-1) + cfg.w_betas * betas.square().mean(-1)
        loss_b = s2m + cfg.w_m2s * m2s + prior
        opt.zero_grad(set_to_none=True)
        loss_b.sum().backward()
        if it < iters // 3 and betas.grad is not None:
            betas.grad.mul_(early_mask)
        opt.step()
        history.append(
            {
                "iter": it,
                "loss": float(loss_b.detach().mean()),
                "s2m": float(s2m.detach().mean()),
                "m2s": float(m2s.detach().mean()),
                "sigma": sigma,
            }
        )
        if not math.isfinite(history[-1]["loss"]):
            raise FloatingPointError(f"refine: objective became {history[-1]['loss']} at iteration {it}")

    with torch.no_grad():
        rot, betas, transl = pose_of(delta), betas.detach(), (transl0 + dt).detach()
        if stopped:  # every row back in its place
            order = torch.argsort(torch.cat([alive, torch.tensor(sorted(stopped))]))
            rows = [stopped[r] for r in sorted(stopped)]
            rot, betas, transl = (
                torch.cat([x, torch.stack([r[k] for r in rows])])[order.to(device)]
                for k, x in enumerate((rot, betas, transl))
            )
        out = body(betas=betas, pose=rot, transl=transl)
    return RefineOutput(
        local_rotmats=rot.detach(),
        betas=betas,
        transl=transl,
        vertices=out.vertices.detach(),
        joints=out.joints.detach(),
        global_rotmats=out.global_rotmats.detach(),
        history=history,
        iterations=iters,
        seconds=time.perf_counter() - t0,
    )
