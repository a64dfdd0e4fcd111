"""Fits lost as a whole: starts with the lower torso turned in its own frame.

In the acrobatic poses that bend the whole body (a plough, a wheel, a backbend, a bow) the network reads the
pelvis and the lower spine upside down or turned round: on 16 such scans the pelvis's global rotation was
more than 90 degrees off the truth in 15 (median 148), mostly about the body's left-right axis (its pitch)
or its up axis, while the neck and the head were read right (median errors 23 and 16 degrees;
experiments/scan_model/spine/torso/README.md). The refinement does not turn a pelvis back by that much,
and the surface score of such a fit stays above 3 cm. Started
from the truth's torso, the same refinement halves these errors, and the surface score prefers it
(experiments/scan_model/spine/reach/README.md, section 1).

:func:`torso_starts` gives the starts: the global rotations of the pelvis alone, or of the pelvis and the
spine parts above it up to spine1, spine2 or spine3 (:data:`CHAINS`), turned in their own frame by each of
:data:`TURNS` (a quarter or a half turn about the left-right axis, a half turn about the up or the forward
axis), every other part keeping its global rotation (its local rotation rebuilt): 20 starts. The
crossed-limb step (:func:`arteq.fit.crossing.try_swaps`) refines them beside the fit refined again and keeps
one only when its surface score is clearly lower.
"""

from __future__ import annotations

import numpy as np
import torch

from arteq.body.skeleton import JOINT_NAMES, NUM_JOINTS, global_to_local
from arteq.geometry.rotations import euler_to_rotmat

_J = {n: i for i, n in enumerate(JOINT_NAMES)}
#: the parts turned together, from the pelvis up
CHAINS: dict[str, tuple[int, ...]] = {
    "pelvis": (_J["pelvis"],),
    "to_spine1": (_J["pelvis"], _J["spine1"]),
    "to_spine2": (_J["pelvis"], _J["spine1"], _J["spine2"]),
    "to_spine3": (_J["pelvis"], _J["spine1"], _J["spine2"], _J["spine3"]),
}
#: turns in a part's own frame (the rest pose's axes: x left-right, y up, z forward)
TURNS: dict[str, np.ndarray] = {
    name: euler_to_rotmat(torch.tensor(angles, dtype=torch.float64)).numpy()
    for name, angles in {
        "pitch90": (90.0, 0.0, 0.0),
        "pitch-90": (-90.0, 0.0, 0.0),
        "pitch180": (180.0, 0.0, 0.0),
        "turn180": (0.0, 180.0, 0.0),
        "roll180": (0.0, 0.0, 180.0),
    }.items()
}
#: the prefix of a torso start's name in the crossed-limb step's records (``torso_to_spine2_pitch180``)
PREFIX = "torso_"


def torso_starts(global_rot: np.ndarray) -> dict[str, np.ndarray]:
    """Local rotations ``[22, 3, 3]`` of every start of :data:`CHAINS` x :data:`TURNS` from a fit's global
    rotations ``global_rot [22, 3, 3]``, named ``torso_<chain>_<turn>``: the chain's parts turned in their own
    frame (``R -> R @ T``), every other part's global rotation as in the fit."""
    global_rot = np.asarray(global_rot, dtype=np.float64)
    if global_rot.shape != (NUM_JOINTS, 3, 3):
        shape = list(global_rot.shape)
        raise ValueError(f"torso_starts: global rotations must be [{NUM_JOINTS}, 3, 3], got {shape}")
    names, turned = [], []
    for chain, parts in CHAINS.items():
        for turn, t in TURNS.items():
            g = global_rot.copy()
            g[list(parts)] = g[list(parts)] @ t
            names.append(f"{PREFIX}{chain}_{turn}")
            turned.append(g)
    local = global_to_local(torch.as_tensor(np.stack(turned))).numpy()
    return dict(zip(names, local))
