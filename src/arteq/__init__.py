"""arteq: part-based SE(3)-equivariant human body fitting to point clouds (ArtEq, ICCV 2023)."""

__version__ = "0.1.0"

try:  # config resolvers for conf/ (omegaconf is a dependency; tolerate its absence for bare imports)
    from arteq.config import register_resolvers as _register_resolvers

    _register_resolvers()
except ImportError:  # pragma: no cover
    pass
