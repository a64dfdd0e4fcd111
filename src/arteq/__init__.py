"""arteq: part-based SE(3)-equivariant human body fitting to point clouds (ArtEq, ICCV 2023)."""

__version__ = "0.1.0"
