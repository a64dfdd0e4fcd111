"""Mixed precision: the parts of the pipeline that must run in float32 (or float64) under autocast.

Lightning's ``trainer.precision=bf16-mixed`` / ``16-mixed`` runs every step under ``torch.autocast``:
matrix products come out in bfloat16 / float16 (about 3 significant digits). That is fine for the
network's feature maps, not for quantities that are read off precisely or feed a decomposition: the
weighted chordal mean of the group rotations and its SVD projection, the softmax statistics of the pose
head's group weights, relative rotations between parts, the body model (LBS), the placement, losses and
metrics. Those run inside :func:`full_precision` on inputs raised with :func:`upcast`. (Neighbour search,
FPS and instance-norm statistics inside the backbone are kept in full precision by the backbone itself.)
"""

from __future__ import annotations

from contextlib import AbstractContextManager

import torch


def upcast(t: torch.Tensor) -> torch.Tensor:
    """``t`` in float32 if it is a lower-precision float (float64 and integer tensors are kept)."""
    if t.is_floating_point() and t.dtype not in (torch.float32, torch.float64):
        return t.float()
    return t


def full_precision(t: torch.Tensor | torch.device | str) -> AbstractContextManager:
    """Autocast switched off for the device type of ``t`` (a tensor, device or device-type string)."""
    if isinstance(t, torch.Tensor):
        device_type = t.device.type
    else:
        device_type = torch.device(t).type
    return torch.autocast(device_type=device_type, enabled=False)
