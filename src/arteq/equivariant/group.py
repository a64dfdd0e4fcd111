"""The icosahedral rotation group (60 elements), its tables, neighbourhoods and kernel points.

Everything is built once, lazily, in float64 by closure from two generators (a 72 degree rotation
about the icosahedron vertex axis (0, 1, phi) and a 120 degree rotation about (1, 1, 1)); nothing is
read from a data file. The float64 tables are the source of truth; the public functions return
copies cast to the requested dtype / device.

Conventions
-----------
- ``rotations[0]`` is the identity.
- ``cayley[i, j]`` is the index of ``R_i @ R_j``; ``inverse[i]`` the index of ``R_i^T``.
- Left multiplication by element ``g`` sends element ``b`` to ``cayley[g, b]``; the permutation
  ``left_permutations()[g]`` is that map (it equals ``cayley[g]``).
- A feature field ``f[..., a, ...]`` over the group is *rotated* by element ``j`` as
  ``f'[a] = f[cayley[inverse[j], a]]`` (the value that was at ``b`` moves to ``cayley[j, b]``);
  see :func:`rotate_group_features`. This is what rotating an input point cloud by ``R_j`` does to
  the features of :class:`arteq.equivariant.EquivariantBackbone`.
- The group-conv neighbourhood ``H`` is the identity plus the twelve 72 degree rotations (the
  nearest elements to the identity); the index table is ``idx[g, k] = cayley[g, H[k]]`` (right
  multiplication), which commutes with left multiplication: ``idx[cayley[j, g], k] ==
  cayley[j, idx[g, k]]``.
"""

from __future__ import annotations

import math

import torch

from arteq.tensor_cache import tensor_cache

GROUP_SIZE = 60
KERNEL_KINDS = ("paper24", "ico13", "ico33")
_PHI = (1.0 + math.sqrt(5.0)) / 2.0


def _axis_angle(axis: tuple[float, float, float], angle: float) -> torch.Tensor:
    """Rodrigues' formula in float64. axis: 3 floats (any length), angle: radians -> [3, 3]."""
    a = torch.tensor(axis, dtype=torch.float64)
    a = a / a.norm()
    k = torch.zeros(3, 3, dtype=torch.float64)
    k[0, 1], k[0, 2], k[1, 2] = -a[2], a[1], -a[0]
    k = k - k.T
    return torch.eye(3, dtype=torch.float64) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def _match(mats: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
    """Index in ``table [G,3,3]`` of each matrix in ``mats [...,3,3]``; asserts an exact match."""
    d = (mats.reshape(-1, 1, 9) - table.reshape(1, -1, 9)).abs().amax(-1)
    best, idx = d.min(-1)
    if float(best.max()) > 1e-9:
        raise RuntimeError("icosahedral group: a product left the group (numerical closure failed)")
    return idx.reshape(mats.shape[:-2])


@tensor_cache(maxsize=1)
def _tables() -> dict[str, torch.Tensor]:
    gens = [_axis_angle((0.0, 1.0, _PHI), 2 * math.pi / 5), _axis_angle((1.0, 1.0, 1.0), 2 * math.pi / 3)]
    elems = [torch.eye(3, dtype=torch.float64)]
    frontier = [elems[0]]
    while frontier:  # breadth-first closure: deterministic order, identity first
        new = []
        for m in frontier:
            for g in gens:
                p = m @ g
                if all(float((p - e).abs().max()) > 1e-9 for e in elems):
                    elems.append(p)
                    new.append(p)
        frontier = new
    rot = torch.stack(elems)
    if rot.shape[0] != GROUP_SIZE:
        raise RuntimeError(f"icosahedral group closure gave {rot.shape[0]} elements, expected 60")
    # snap entries to the exact float64 values implied by orthonormality (already ~1e-16 accurate)
    cayley = _match(rot[:, None] @ rot[None, :], rot)
    inverse = (cayley == 0).float().argmax(1)
    trace = rot.diagonal(dim1=-2, dim2=-1).sum(-1)
    angle = torch.arccos(((trace - 1) / 2).clamp(-1, 1))
    nbr = torch.cat(
        [torch.zeros(1, dtype=torch.long), torch.nonzero((angle - 2 * math.pi / 5).abs() < 1e-6)[:, 0]]
    )
    if nbr.numel() != 13:
        raise RuntimeError("icosahedral group: expected twelve 72-degree rotations")
    return {
        "rotations": rot,
        "cayley": cayley,
        "inverse": inverse,
        "angles": angle,
        "neighbourhood": nbr,
        "conv_index": cayley[:, nbr],
    }


def group_rotations(
    dtype: torch.dtype = torch.float32, device: torch.device | str | None = None
) -> torch.Tensor:
    """The 60 rotation matrices ``[60, 3, 3]`` (index 0 = identity), cast to ``dtype``/``device``."""
    return _tables()["rotations"].to(dtype=dtype, device=device)


def cayley_table(device: torch.device | str | None = None) -> torch.Tensor:
    """``C [60, 60]`` long, ``C[i, j]`` = index of ``R_i @ R_j``."""
    return _tables()["cayley"].clone().to(device)


def inverse_table(device: torch.device | str | None = None) -> torch.Tensor:
    """``inv [60]`` long, ``R_inv[i] = R_i^T``."""
    return _tables()["inverse"].clone().to(device)


def left_permutations(device: torch.device | str | None = None) -> torch.Tensor:
    """``P [60, 60]`` long: left multiplication by element ``g`` maps element ``b`` to ``P[g, b]``."""
    return cayley_table(device)


def rotation_angles(dtype: torch.dtype = torch.float64) -> torch.Tensor:
    """Rotation angle of each element in radians ``[60]``."""
    return _tables()["angles"].to(dtype)


def element_orders() -> torch.Tensor:
    """Order of each element ``[60]`` long (1, 2, 3 or 5)."""
    c = _tables()["cayley"]
    order = torch.zeros(GROUP_SIZE, dtype=torch.long)
    for g in range(GROUP_SIZE):
        p, n = g, 1
        while p != 0:
            p, n = int(c[p, g]), n + 1
        order[g] = n
    return order


def group_neighbourhood(device: torch.device | str | None = None) -> torch.Tensor:
    """``H [13]`` long: identity then the twelve 72 degree rotations (nearest to the identity)."""
    return _tables()["neighbourhood"].clone().to(device)


def group_conv_index(device: torch.device | str | None = None) -> torch.Tensor:
    """``idx [60, 13]`` long, ``idx[g, k] = cayley[g, H[k]]`` (right multiplication)."""
    return _tables()["conv_index"].clone().to(device)


def rotate_group_features(feats: torch.Tensor, element: int, dim: int = 2) -> torch.Tensor:
    """Apply group element ``element`` to a feature field over the group along ``dim``.

    ``out[..., a, ...] = feats[..., cayley[inverse[element], a], ...]``: the value at ``b`` moves to
    ``cayley[element, b]``. ``feats`` must have size 60 along ``dim``.
    """
    if feats.shape[dim] != GROUP_SIZE:
        raise ValueError(
            f"rotate_group_features: feats has size {feats.shape[dim]} along dim {dim}, expected 60"
        )
    t = _tables()
    perm = t["cayley"][t["inverse"][element]].to(feats.device)
    return feats.index_select(dim, perm)


def _fibonacci_sphere(n: int) -> torch.Tensor:
    """``n`` well-spread unit vectors ``[n, 3]`` (float64, golden-angle spiral)."""
    i = torch.arange(n, dtype=torch.float64) + 0.5
    z = 1.0 - 2.0 * i / n
    r = (1.0 - z * z).sqrt()
    theta = math.pi * (3.0 - math.sqrt(5.0)) * i
    return torch.stack([r * torch.cos(theta), r * torch.sin(theta), z], -1)


def _cyclic(v: list[tuple[float, float, float]]) -> list[tuple[float, float, float]]:
    return [p for x, y, z in v for p in ((x, y, z), (y, z, x), (z, x, y))]


@tensor_cache()
def _unit_kernel(kind: str) -> torch.Tensor:
    if kind == "paper24":
        pts = _fibonacci_sphere(23)
    elif kind in ("ico13", "ico33"):
        s = (1.0, -1.0)
        verts = _cyclic([(0.0, a, b * _PHI) for a in s for b in s])
        if kind == "ico33":
            ip = 1.0 / _PHI
            verts += [(a, b, c) for a in s for b in s for c in s]
            verts += _cyclic([(0.0, a * _PHI, b * ip) for a in s for b in s])
        pts = torch.tensor(verts, dtype=torch.float64)
        pts = pts / pts.norm(dim=-1, keepdim=True)
    else:
        raise ValueError(f"kernel_points: unknown kind {kind!r}; expected one of {KERNEL_KINDS}")
    return torch.cat([torch.zeros(1, 3, dtype=torch.float64), pts])


def kernel_points(
    kind: str = "paper24", radius: float = 1.0, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """Kernel points ``[J, 3]``: the centre, then ``J - 1`` points on a sphere of ``radius``.

    ``"paper24"``: centre + 23 Fibonacci-sphere points (J = 24, like the paper). ``"ico13"``: centre +
    the 12 icosahedron vertices (J = 13); ``"ico33"``: + the 20 face centres too (J = 33). The
    ``ico*`` sets are closed under the group (see :func:`kernel_permutation`).
    """
    if not radius > 0:
        raise ValueError(f"kernel_points: radius must be > 0, got {radius}")
    return (_unit_kernel(kind) * radius).to(dtype)


@tensor_cache()
def _kernel_perm(kind: str) -> torch.Tensor | None:
    k = _unit_kernel(kind)
    rk = torch.einsum("aij,nj->ani", _tables()["rotations"], k)  # [60, J, 3]
    d = (rk[:, :, None] - k[None, None]).norm(dim=-1)  # [60, J, J]
    best, idx = d.min(-1)
    if float(best.max()) > 1e-9:
        return None
    return idx


def kernel_permutation(kind: str) -> torch.Tensor | None:
    """``pi [60, J]`` long with ``R_a @ k_j == k_{pi[a, j]}``, or ``None`` if the set is not closed."""
    p = _kernel_perm(kind)
    return None if p is None else p.clone()


def rotated_kernel_points(
    kind: str = "paper24", radius: float = 1.0, dtype: torch.dtype = torch.float32
) -> torch.Tensor:
    """``R_a k_j`` for all elements and kernel points ``[60, J, 3]``."""
    k = kernel_points(kind, radius, torch.float64)
    return torch.einsum("aij,nj->ani", _tables()["rotations"], k).to(dtype)
