"""Optimisation-based body fitting (the paper's optimisation baselines and ArtEq + refinement)."""

from arteq.fitting.fit import FitResult, chamfer_terms, fit_body, root_candidates

__all__ = ["FitResult", "chamfer_terms", "fit_body", "root_candidates"]
