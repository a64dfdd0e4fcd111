"""Probe: the part-local network's sides (arteq.models.sides) read from two frames at inference, legs from
the pelvis's predicted rotation and points, arms from the upper spine's (spine3), instead of the chordal mean
of the four torso parts; the shipped anny_scan unchanged otherwise, the default fitter. Per body of the user
suite (both seeds): V2V, part accuracy of the network's labels, and pair accuracy (left / right counted as
one), the label of a scan point being its nearest true vertex's part (within 3 cm).

    OMP_NUM_THREADS=1 python experiments/fitting/sides_probe.py base > experiments/fitting/sides/probe_base.log
    OMP_NUM_THREADS=1 python experiments/fitting/sides_probe.py spine3 > experiments/fitting/sides/probe_two_frames.log
"""

import sys
from pathlib import Path

import numpy as np
import roma
import torch
import torch.nn.functional as F
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from user_scans import people_scans  # noqa: E402

from arteq.body.skeleton import JOINT_NAMES  # noqa: E402
from arteq.fit import Fitter  # noqa: E402
from arteq.models import arteq_net  # noqa: E402
from arteq.models import sides as S  # noqa: E402
from arteq.models.precision import full_precision, upcast  # noqa: E402

J = {n: i for i, n in enumerate(JOINT_NAMES)}
LEGS = [J[n] for n in JOINT_NAMES if n.startswith("left_") and n[5:] in ("hip", "knee", "ankle", "foot")]
ARMS = [
    J[n] for n in JOINT_NAMES if n.startswith("left_") and n[5:] in ("collar", "shoulder", "elbow", "wrist")
]
MODE = sys.argv[1]
UPPER = {"spine3": ("spine3",), "spine23": ("spine2", "spine3")}.get(MODE, ("spine3",))


def frame(pts, w_all, rots, parts):
    idx = [S.TORSO_PARTS.index(J[p]) for p in parts]
    w = w_all[..., [J[p] for p in parts]].sum(-1, keepdim=True)
    c = ((w * pts).sum(1) + 1e-6 * pts.mean(1)) / (w.sum(1) + 1e-6)
    r = roma.special_procrustes(rots[:, idx].sum(1).double())
    return c, (r @ torch.tensor(S.LEFT_AXIS, dtype=r.dtype)).to(pts.dtype)


def patched(self, seg_logits, points, weights, torso):
    with full_precision(points):
        pts = upcast(points).detach()
        w = weights.detach()
        torso = torso.detach()
        logp = F.log_softmax(upcast(seg_logits), dim=-1)
        out = logp.clone()
        for group, parts in ((LEGS, ("pelvis",)), (ARMS, UPPER)):
            c, left = frame(pts, w, torso, parts)
            x = ((pts - c[:, None]) * left[:, None]).sum(-1).to(logp.dtype) / self.side_scale
            rights = [S.RIGHT_PARTS[S.LEFT_PARTS.index(k)] for k in group]
            pair = torch.logaddexp(logp[..., group], logp[..., rights])
            out[..., group] = pair + F.logsigmoid(x)[..., None]
            out[..., rights] = pair + F.logsigmoid(-x)[..., None]
        return out


if MODE == "labels":  # the pose from the trained torso frame; the labels the fitter uses from two frames
    _orig_resolve, _orig_forward = arteq_net.ArtEqNet._resolve_sides, arteq_net.ArtEqNet.forward
    _seen = {}

    def keep_args(self, seg_logits, points, weights, torso):
        _seen["args"] = (seg_logits, points, weights, torso)
        return _orig_resolve(self, seg_logits, points, weights, torso)

    def forward(self, points, *args, **kwargs):
        _seen.clear()
        out = _orig_forward(self, points, *args, **kwargs)
        if "args" in _seen and kwargs.get("gt_labels") is None:
            seg = patched(self, *_seen["args"])
            out = {**out, "seg_logits": seg, "part_probs": seg.exp()}
        return out

    arteq_net.ArtEqNet._resolve_sides = keep_args
    arteq_net.ArtEqNet.forward = forward
elif MODE != "base":
    arteq_net.ArtEqNet._resolve_sides = patched
torch.set_num_threads(1)
f = Fitter(ckpt="anny_scan", device="cpu", anny=False)
lab = f.body.part_labels.numpy()
pair = np.arange(22)
for i, n in enumerate(JOINT_NAMES):
    if n.startswith("right_"):
        pair[i] = J["left_" + n[6:]]
tot = []
for seed in (0, 1):
    for s in people_scans(seed):
        if s.vertices is None or s.group == "clutter":
            continue
        r = f.fit_points(s.points, name=s.name)
        if r.vertices is None:
            continue
        d, nn = cKDTree(s.vertices).query(np.asarray(s.points, dtype=np.float64))
        ok = (r.point_labels >= 0) & (d < 0.03)
        t = lab[nn][ok]
        p = r.point_labels[ok]
        acc = (t == p).mean() * 100
        pacc = (pair[t] == pair[p]).mean() * 100
        v2v = np.linalg.norm(r.vertices - s.vertices, axis=1).mean() * 100
        tot.append((s.group, acc, v2v))
        print(
            f"{MODE} seed {seed} {s.group:10s} {s.name:42s} V2V {v2v:5.1f} part acc {acc:5.1f} pair acc {pacc:5.1f}",
            flush=True,
        )
for g in ("acrobatic", "children", "adults"):
    a = [x for x in tot if x[0] == g]
    print(
        MODE, g, "part acc", round(np.mean([x[1] for x in a]), 1), "V2V", round(np.mean([x[2] for x in a]), 2)
    )
