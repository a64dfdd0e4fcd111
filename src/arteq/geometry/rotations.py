"""Rotation helpers: Euler angles, Haar-uniform random rotations (float64 by default), geodesic angles, the
smallest rotation between two directions."""

from __future__ import annotations

import roma
import torch

__all__ = ["euler_to_rotmat", "geodesic_deg", "random_rotmat", "rotation_between"]


def euler_to_rotmat(angles_deg: torch.Tensor) -> torch.Tensor:
    """Intrinsic XYZ Euler angles in degrees ``[..., 3]`` -> ``Rx(a) Ry(b) Rz(c)`` ``[..., 3, 3]``."""
    r = torch.deg2rad(angles_deg)
    ca, cb, cc = torch.cos(r).unbind(-1)
    sa, sb, sc = torch.sin(r).unbind(-1)
    rows = [
        cb * cc, -cb * sc, sb,
        sa * sb * cc + ca * sc, -sa * sb * sc + ca * cc, -sa * cb,
        -ca * sb * cc + sa * sc, ca * sb * sc + sa * cc, ca * cb,
    ]  # fmt: skip
    return torch.stack(rows, -1).reshape(*angles_deg.shape[:-1], 3, 3)


def random_rotmat(n: int, generator: torch.Generator, dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """``n`` Haar-uniform rotations ``[n, 3, 3]`` (normalised Gaussian quaternions)."""
    q = torch.randn(n, 4, generator=generator, dtype=dtype)
    q = q / q.norm(dim=-1, keepdim=True)
    return roma.unitquat_to_rotmat(q)


def geodesic_deg(r1: torch.Tensor, r2: torch.Tensor) -> torch.Tensor:
    """Angle (degrees) of ``r1^T r2`` for ``[..., 3, 3]`` rotations."""
    cos = ((r1.transpose(-1, -2) @ r2).diagonal(dim1=-2, dim2=-1).sum(-1) - 1) / 2
    return torch.rad2deg(torch.acos(cos.clamp(-1.0, 1.0)))


def rotation_between(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The smallest rotations ``[..., 3, 3]`` taking directions ``a [..., 3]`` to directions ``b [..., 3]``
    (broadcast; opposite directions: a half turn about an axis normal to ``a``)."""
    a, b = torch.broadcast_tensors(a / a.norm(dim=-1, keepdim=True), b / b.norm(dim=-1, keepdim=True))
    axis = torch.linalg.cross(a, b)
    sin, cos = axis.norm(dim=-1, keepdim=True), (a * b).sum(-1, keepdim=True)
    helper = torch.nn.functional.one_hot(a.abs().argmin(-1), 3).to(a.dtype)
    opposite = (sin < 1e-9) & (cos < 0)
    axis = torch.where(opposite, torch.linalg.cross(a, helper), axis)
    angle = torch.atan2(sin, cos)
    return roma.rotvec_to_rotmat(axis / axis.norm(dim=-1, keepdim=True).clamp_min(1e-12) * angle)
