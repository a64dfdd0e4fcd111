"""Non-uniform, noisy surface sampling of triangle meshes, with per-point part labels.

How the density is non-uniform: faces are drawn with probability proportional to
``area * density``, where ``density`` is a smooth random field over the surface,
``exp(contrast * f(x))`` with ``f`` a sum of random low-frequency cosines of position
(random Fourier features, wavelength ~0.6 m, a fresh field per sample). A field value is
taken at each face centroid. With ``contrast=1`` the density varies by a factor ~e^2-e^3
between the densest and sparsest regions of a body, smoothly, like a scanner that sees some
sides better than others. Each point gets fresh barycentric coordinates (uniform on its
triangle) and then isotropic Gaussian noise.

All functions are vectorised torch; randomness comes only from the ``generator`` argument.
"""

from __future__ import annotations

import math

import torch


def _check_mesh(vertices: torch.Tensor, faces: torch.Tensor) -> None:
    if vertices.ndim != 2 or vertices.shape[-1] != 3:
        raise ValueError(f"vertices must have shape [V, 3], got {tuple(vertices.shape)}")
    if faces.ndim != 2 or faces.shape[-1] != 3:
        raise ValueError(f"faces must have shape [F, 3], got {tuple(faces.shape)}")
    if faces.shape[0] == 0:
        raise ValueError("faces is empty: cannot sample a surface with no triangles")
    if not torch.isfinite(vertices).all():
        raise ValueError("vertices contain NaN or Inf")
    if faces.min() < 0 or faces.max() >= vertices.shape[0]:
        raise ValueError(f"faces index out of range for {vertices.shape[0]} vertices")


def face_areas(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Triangle areas.

    Args:
        vertices: ``[V, 3]``.
        faces: ``[F, 3]`` long.
    Returns:
        ``[F]`` areas (same dtype as vertices).
    """
    tri = vertices[faces]  # [F, 3, 3]
    return 0.5 * torch.linalg.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]).norm(dim=-1)


def smooth_density_field(
    positions: torch.Tensor,
    generator: torch.Generator,
    contrast: float = 1.0,
    wavelength: float = 0.6,
    num_waves: int = 8,
) -> torch.Tensor:
    """A random, smooth, positive density evaluated at ``positions``.

    ``density(x) = exp(contrast * f(x))``, ``f(x) = sqrt(2 / K) * sum_k cos(w_k . x + phi_k)`` with
    ``w_k ~ N(0, (2 pi / wavelength)^2 I / 3)`` (so ``|w_k| ~ 2 pi / wavelength``) and
    ``phi_k ~ U(0, 2 pi)`` (``f`` has unit variance).

    Args:
        positions: ``[P, 3]`` points (metres) where the field is evaluated.
        generator: source of the random field.
        contrast: log-density standard deviation; 0 gives a uniform density.
        wavelength: typical spatial period in metres.
        num_waves: number K of random cosines.
    Returns:
        ``[P]`` positive densities, normalised to mean 1.
    """
    if contrast < 0 or wavelength <= 0 or num_waves < 1:
        raise ValueError(
            f"need contrast >= 0, wavelength > 0, num_waves >= 1; got {contrast}, {wavelength}, {num_waves}"
        )
    dtype, device = positions.dtype, positions.device
    w = torch.randn(num_waves, 3, generator=generator, dtype=torch.float64) * (
        2 * math.pi / wavelength / math.sqrt(3)
    )
    phi = torch.rand(num_waves, generator=generator, dtype=torch.float64) * (2 * math.pi)
    w, phi = w.to(device=device, dtype=dtype), phi.to(device=device, dtype=dtype)
    f = torch.cos(positions @ w.T + phi).sum(-1) * math.sqrt(2.0 / num_waves)
    dens = torch.exp(contrast * f)
    return dens / dens.mean()


def sample_surface(
    vertices: torch.Tensor,
    faces: torch.Tensor,
    n: int,
    generator: torch.Generator,
    density: torch.Tensor | None = None,
    noise_std: float = 0.0,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Sample ``n`` noisy points on a triangle mesh with per-face density weighting.

    Faces are drawn (with replacement) with probability ``area * density``; each point gets fresh
    uniform barycentric coordinates on its face; then ``N(0, noise_std^2 I)`` noise is added.

    Args:
        vertices: ``[V, 3]`` float.
        faces: ``[F, 3]`` long.
        n: number of points (>= 1).
        generator: torch generator (CPU) that makes the draw reproducible.
        density: ``[F]`` non-negative per-face weights (``None``: uniform area sampling), e.g. from
            :func:`smooth_density_field` at face centroids.
        noise_std: standard deviation of the Gaussian noise, metres.
    Returns:
        ``points [n, 3]`` (vertices' dtype), ``face_idx [n]`` long, ``bary [n, 3]`` (sums to 1).
    """
    _check_mesh(vertices, faces)
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    if noise_std < 0 or not math.isfinite(noise_std):
        raise ValueError(f"noise_std must be finite and >= 0, got {noise_std}")
    weights = face_areas(vertices, faces).double()
    if density is not None:
        if density.shape != (faces.shape[0],):
            raise ValueError(f"density must have shape [F]={faces.shape[0]}, got {tuple(density.shape)}")
        if not torch.isfinite(density).all() or (density < 0).any():
            raise ValueError("density must be finite and non-negative")
        weights = weights * density.double().to(weights.device)
    if not weights.sum() > 0:
        raise ValueError("mesh has zero total (density-weighted) area")
    face_idx = torch.multinomial(weights.cpu(), n, replacement=True, generator=generator)
    uv = torch.rand(n, 2, generator=generator, dtype=torch.float64)
    su = uv[:, 0].sqrt()
    bary = torch.stack([1 - su, su * (1 - uv[:, 1]), su * uv[:, 1]], dim=-1)
    noise = torch.randn(n, 3, generator=generator, dtype=torch.float64) * noise_std
    face_idx = face_idx.to(vertices.device)
    bary_v = bary.to(device=vertices.device, dtype=vertices.dtype)
    tri = vertices[faces[face_idx]]  # [n, 3, 3]
    points = (bary_v.unsqueeze(-1) * tri).sum(1) + noise.to(device=vertices.device, dtype=vertices.dtype)
    return points, face_idx, bary_v


def interpolate_labels(
    weights: torch.Tensor, faces: torch.Tensor, face_idx: torch.Tensor, bary: torch.Tensor
) -> torch.Tensor:
    """Part label per sampled point: argmax of barycentrically interpolated skinning weights.

    Args:
        weights: ``[V, K]`` per-vertex skinning weights.
        faces: ``[F, 3]`` long.
        face_idx: ``[n]`` face of each point.
        bary: ``[n, 3]`` barycentric coordinates.
    Returns:
        ``[n]`` long labels in ``0..K-1``.
    """
    w = weights[faces[face_idx]]  # [n, 3, K]
    return (bary.to(w.dtype).unsqueeze(-1) * w).sum(1).argmax(-1)
