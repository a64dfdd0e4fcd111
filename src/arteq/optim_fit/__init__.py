"""Fitting by optimisation: the paper's optimisation baseline (Chamfer + priors from a standard start, or
from ArtEq's prediction) and its test-set evaluation (``python -m arteq.optim_fit.evaluate``).

Not the scan-fitting product: ``arteq-fit`` and its refinement / quality check live in :mod:`arteq.fit`.
"""

from arteq.optim_fit.chamfer import OptimFitResult, chamfer_terms, fit_body, root_candidates

__all__ = ["OptimFitResult", "chamfer_terms", "fit_body", "root_candidates"]
