"""Networks: ArtEq (:class:`ArtEqNet`), its heads, the PointNet++ baseline and the registry by name.

Names are imported lazily: ``arteq.models.registry`` (names of architectures) loads no network.
"""

from __future__ import annotations

from arteq._lazy import lazy_exports

__all__ = ["ARCHITECTURES", "ArtEqNet", "PointNet2Regressor", "build_net", "display_name"]

_WHERE = {
    "ArtEqNet": "arteq.models.arteq_net",
    "PointNet2Regressor": "arteq.models.baselines",
    "ARCHITECTURES": "arteq.models.registry",
    "build_net": "arteq.models.registry",
    "display_name": "arteq.models.registry",
}
__getattr__ = lazy_exports(__name__, _WHERE)
