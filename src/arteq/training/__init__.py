"""Training: the LightningModule (:class:`ArtEqModule`), losses and metrics.

Names are imported lazily, so that ``arteq.training.losses`` or ``.metrics`` do not load Lightning.
"""

from __future__ import annotations

from arteq._lazy import lazy_exports

__all__ = ["ArtEqModule", "BodyFitMetrics", "arteq_losses"]

_WHERE = {
    "ArtEqModule": "arteq.training.module",
    "BodyFitMetrics": "arteq.training.metrics",
    "arteq_losses": "arteq.training.losses",
}
__getattr__ = lazy_exports(__name__, _WHERE)
