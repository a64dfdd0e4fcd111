"""Curled fingers for the Anny-built bodies: one curl per hand on Anny's own finger bones and weights.

The 22-part bodies (``anny22``, ``anny_allages``) fold Anny's 30 finger bones into the hands: a fitted hand
is one rigid, flat part. Real hands are rarely flat, and a closed hand costs a fit 3-4 cm on the hands' 3192
vertices, a quarter of Anny's mesh (experiments/fitting/native_anny/README.md). :class:`HandCurl` bends
them back on the body's rest (T-pose) mesh, before its skinning:

* every finger's three bones (``finger1-1`` .. ``finger5-3`` of each hand, Anny's names) turn about the
  finger's own flexion axis (its direction crossed with the palm's normal) by ``curl * MAX_DEG``
  (:data:`MAX_DEG`: 90 deg per joint; the thumb half that), ``curl`` in [0, 1] per hand (0: Anny's flat
  hand, the body as it is);
* each vertex moves by Anny's own skinning weights of those bones (linear blend skinning in the rest frame);
  the palm, the metacarpals and the wrist do not move, and nothing else of the body;
* the bones' heads follow the body's shape: each a fixed convex combination of nearby rest vertices, fitted
  by non-negative least squares to Anny's own heads over shapes of the body's distribution (the held-out
  error is stored).

The data (``<body>_hands.npz`` beside the body's cached file) is built from ``anny`` on first use, like the
body itself (:func:`ensure_hands`); a body not built from Anny has none (:func:`hands_for` returns None).
"""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import numpy as np
import roma
import torch

#: curl 1 turns each finger joint this far (degrees; index .. little finger); the thumb's half of it
MAX_DEG = 90.0
THUMB_SCALE = 0.5
#: Anny's finger bones of one hand, in chain order: finger f (1 thumb .. 5 little), joints k = 1..3
FINGER_BONES = tuple(f"finger{f}-{k}" for f in range(1, 6) for k in range(1, 4))
SIDES = ("L", "R")  # the body's left hand (+x), then its right
#: shape samples the head regressor is fitted on, and held out to measure it
REGRESSOR_SAMPLES, HELD_OUT = 96, 32
CANDIDATES = 40  # nearest rest vertices of each head the regressor may use
FORMAT = 1


class HandCurl(torch.nn.Module):
    """One curl per hand on a body's rest mesh (module docstring). Buffers: ``vert [M]`` and ``bone [M]``
    (0..29: hand * 15 + finger * 3 + joint), ``weight [M]`` the nonzero finger weights; ``reg_idx [30, K]``,
    ``reg_w [30, K]`` the heads' regressor; ``axes [10, 3]`` (hand * 5 + finger) unit flexion axes in the
    body's rest frame; ``max_rad [30]``."""

    def __init__(self, data: dict[str, np.ndarray], dtype: torch.dtype = torch.float32) -> None:
        super().__init__()
        for k in ("vert", "bone", "reg_idx"):
            self.register_buffer(k, torch.as_tensor(np.asarray(data[k]), dtype=torch.long), persistent=False)
        for k in ("weight", "reg_w", "axes", "max_rad"):
            self.register_buffer(k, torch.as_tensor(np.asarray(data[k])).to(dtype), persistent=False)
        self.num_vertices = int(data["num_vertices"])
        self.held_out_mm = float(data["held_out_mm"])
        #: vertices any finger weight moves: ``[Vh]`` sorted
        self.register_buffer("moved", torch.unique(self.vert), persistent=False)

    @classmethod
    def from_npz(cls, path: str | Path, dtype: torch.dtype = torch.float32) -> HandCurl:
        with np.load(path) as z:
            return cls({k: z[k] for k in z.files}, dtype)

    def heads(self, rest: torch.Tensor) -> torch.Tensor:
        """The finger bones' heads ``[B, 30, 3]`` of the rest vertices ``rest [B, V, 3]``."""
        return (rest[:, self.reg_idx] * self.reg_w.to(rest.dtype)[None, ..., None]).sum(2)

    def transforms(self, heads: torch.Tensor, curl: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Each finger bone's rest-frame transform for ``curl [B, 2]``: rotations ``[B, 30, 3, 3]`` and
        translations ``[B, 30, 3]`` (``x -> R x + t``), from the bones' rest ``heads [B, 30, 3]``."""
        b, dtype = heads.shape[0], heads.dtype
        # [B, 2]: one curl per hand; [B, 10]: one per finger (hand * 5 + finger)
        per_bone = curl.to(dtype).repeat_interleave(15 if curl.shape[1] == 2 else 3, dim=1)  # [B, 30]
        angle = per_bone * self.max_rad.to(dtype)
        axes = self.axes.to(dtype).repeat_interleave(3, dim=0)  # [30, 3]
        local = roma.rotvec_to_rotmat(axes * angle[..., None])  # [B, 30, 3, 3]
        local = local.reshape(b, 10, 3, 3, 3)  # [B, chain (hand * 5 + finger), joint, 3, 3]
        h = heads.reshape(b, 10, 3, 3)
        g = torch.eye(3, dtype=dtype, device=heads.device).expand(b, 10, 3, 3)
        moved_head = h[:, :, 0]
        rots, trans = [], []
        for k in range(3):  # the joints along every finger at once
            if k:
                moved_head = moved_head + (g @ (h[:, :, k] - h[:, :, k - 1])[..., None])[..., 0]
            g = g @ local[:, :, k]
            rots.append(g)
            trans.append(moved_head - (g @ h[:, :, k, :, None])[..., 0])
        return torch.stack(rots, 2).reshape(b, 30, 3, 3), torch.stack(trans, 2).reshape(b, 30, 3)

    def forward(self, rest: torch.Tensor, curl: torch.Tensor | None) -> torch.Tensor:
        """``rest [B, V, 3]`` with the fingers curled by ``curl [B, 2]`` (left, right hand), or ``[B, 10]``
        (each finger: hand * 5 + finger, thumb first); None: as is."""
        if curl is None:
            return rest
        if rest.shape[1] != self.num_vertices:
            raise ValueError(f"HandCurl: a body of {self.num_vertices} vertices, got {rest.shape[1]}")
        if curl.shape not in ((rest.shape[0], 2), (rest.shape[0], 10)):
            raise ValueError(f"HandCurl: curl must be [{rest.shape[0]}, 2] or [{rest.shape[0]}, 10], got "
                             f"{tuple(curl.shape)}")  # fmt: skip
        return self.deform(rest, self.heads(rest), curl, self.vert)

    def deform(
        self, x: torch.Tensor, heads: torch.Tensor, curl: torch.Tensor, rows: torch.Tensor,
        entries: torch.Tensor | None = None,
    ) -> torch.Tensor:  # fmt: skip
        """Rest vertices ``x [B, R, 3]`` curled; ``heads``: :meth:`heads` of the whole rest mesh. ``rows``:
        the row of ``x`` of each finger weight's vertex (:attr:`vert` when ``x`` is the whole rest mesh),
        or, with ``entries [M]`` (bool, which of the weights ``x`` holds), of those weights' vertices."""
        rot, trans = self.transforms(heads, curl)
        bone, weight = self.bone, self.weight
        if entries is not None:
            bone, weight = bone[entries], weight[entries]
        xv = x[:, rows]  # [B, M, 3]
        moved = (rot[:, bone] @ xv[..., None])[..., 0] + trans[:, bone]
        return x.index_add(1, rows, (moved - xv) * weight.to(x.dtype)[None, :, None])


# ----------------------------------------------------------------------------------------- building
def _nnls_convex(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Non-negative ``w`` with ``a @ w ~ b`` and ``sum(w) = 1`` (a heavily weighted row for the sum)."""
    from scipy.optimize import nnls

    big = 1e3 * max(1.0, float(np.abs(a).max()))
    w, _ = nnls(np.vstack([a, np.full((1, a.shape[1]), big)]), np.concatenate([b, [big]]))
    return w / w.sum()


def build_hands(body_name: str, out: str | Path, log=None) -> Path:
    """Build ``out`` (npz) for the Anny body ``body_name`` (needs ``anny``; seconds)."""
    import importlib

    from anny.skinning.skinning import dense_bone_weights

    from arteq.body import anny_rig
    from arteq.body.model import ANNY_BODIES

    spec = importlib.import_module(ANNY_BODIES[body_name]).spec()
    model = anny_rig.load_anny()
    bake = anny_rig.compute_bake(model)
    C = np.asarray(anny_rig.ANNY_TO_SMPL)
    idx = {b: i for i, b in enumerate(model.bone_labels)}
    bones = [idx[f"{name}.{s}"] for s in SIDES for name in FINGER_BONES]
    dense = dense_bone_weights(model.vertex_bone_weights, model.vertex_bone_indices, len(idx)).numpy()
    w = dense[:, bones]  # [V, 30]
    vert, bone = np.nonzero(w > 1e-6)
    # T-posed shapes of the body's distribution: vertices and all bone heads, SMPL axes, pelvis at the origin
    torch.manual_seed(7)
    sample = spec.make_sampler(model)
    verts, heads = [], []
    with torch.no_grad():
        for n in (64, REGRESSOR_SAMPLES + HELD_OUT - 64):
            _, phen, _ = sample(n)
            o = model(pose_parameters=anny_rig._bake_pose(model, bake, n), phenotype_kwargs=phen)
            v, h = o["vertices"].numpy() @ C.T, o["bone_poses"][..., :3, 3].numpy() @ C.T
            root = h[:, idx["root"] : idx["root"] + 1]
            verts.append(v - root)
            heads.append(h - root)
    V, H = np.concatenate(verts), np.concatenate(heads)
    fit, test = slice(0, REGRESSOR_SAMPLES), slice(REGRESSOR_SAMPLES, None)
    reg_idx = np.zeros((30, CANDIDATES), np.int64)
    reg_w = np.zeros((30, CANDIDATES))
    errs = []
    for i, b in enumerate(bones):
        mean_head = H[fit, b].mean(0)
        cand = np.argsort(np.linalg.norm(V[fit].mean(0) - mean_head, axis=1))[:CANDIDATES]
        a = V[fit][:, cand].transpose(0, 2, 1).reshape(-1, CANDIDATES)  # [N*3, K]
        reg_idx[i], reg_w[i] = cand, _nnls_convex(a, H[fit, b].reshape(-1))
        pred = (V[test][:, cand] * reg_w[i][None, :, None]).sum(1)
        errs.append(np.linalg.norm(pred - H[test, b], axis=1).max() * 1000)
    # flexion axes from Anny's rest pose (its A-pose, Anny axes), carried into the body's T-pose (SMPL axes)
    with torch.no_grad():
        rest_heads = model(pose_parameters={"root": torch.eye(4, dtype=torch.float64)[None]})["bone_poses"]
    rh = rest_heads[0, :, :3, 3].numpy()
    glob = anny_rig.baked_globals(model, bake).numpy()
    axes = np.zeros((10, 3))
    for hand, s in enumerate(SIDES):
        across = rh[idx[f"finger5-1.{s}"]] - rh[idx[f"finger2-1.{s}"]]
        along = rh[idx[f"finger3-1.{s}"]] - rh[idx[f"wrist.{s}"]]
        normal = np.cross(along, across)
        if normal @ -np.array([rh[idx[f"wrist.{s}"], 0], 0.0, 0.0]) < 0:  # the palm faces the body's midline
            normal = -normal
        for f in range(1, 6):
            d = rh[idx[f"finger{f}-2.{s}"]] - rh[idx[f"finger{f}-1.{s}"]]
            a = np.cross(d, normal)  # turns the finger's direction towards the palm
            a = C @ glob[idx[f"finger{f}-1.{s}"]] @ (a / np.linalg.norm(a))
            axes[hand * 5 + f - 1] = a / np.linalg.norm(a)
    max_rad = np.deg2rad(
        [MAX_DEG * (THUMB_SCALE if name.startswith("finger1-") else 1.0) for name in FINGER_BONES]
    )
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f"{out.name}.{os.getpid()}.tmp.npz")  # parallel builders each write their own
    np.savez(
        tmp, vert=vert, bone=bone, weight=w[vert, bone], reg_idx=reg_idx, reg_w=reg_w, axes=axes,
        max_rad=np.tile(max_rad, 2), num_vertices=np.int64(V.shape[1]), held_out_mm=np.float64(max(errs)),
        format=np.int64(FORMAT), meta=np.array(json.dumps({"body": body_name, "bones": FINGER_BONES})),
    )  # fmt: skip
    tmp.replace(out)
    if log is not None:
        log(
            f"hands of {body_name}: {len(np.unique(vert))} vertices, heads within {max(errs):.2f} mm "
            "(held out)"
        )
    return out


def hands_path(body_name: str) -> Path:
    from arteq.paths import cache_dir

    return cache_dir("body_models") / f"{body_name}_hands.npz"


def ensure_hands(body_name: str) -> Path:
    """The cached hands file of an Anny body, built (needs ``anny``) if absent."""
    path = hands_path(body_name)
    if path.is_file():
        with np.load(path) as z:
            if int(z["format"]) == FORMAT:
                return path
    try:
        import anny  # noqa: F401
    except ImportError as exc:
        raise RuntimeError(
            f"the finger curl of {body_name} is not cached at '{path}' and the `anny` package needed to "
            "build "
            "it is not installed: `pip install anny==0.6.2` (or copy the file from a machine that has it)"
        ) from exc
    print(f"arteq: building the finger curl of {body_name} into {path} (once; seconds) ...", file=sys.stderr)
    return build_hands(body_name, path)


def hands_for(body: torch.nn.Module) -> HandCurl | None:
    """The :class:`HandCurl` of an Anny-built body (built on first use), None for any other body."""
    from arteq.body.model import ANNY_BODIES

    name = getattr(body, "name", "")
    if name not in ANNY_BODIES:
        return None
    hc = HandCurl.from_npz(ensure_hands(name), dtype=body.v_template.dtype).to(body.v_template.device)
    if hc.num_vertices != body.num_vertices:
        return None
    return hc
