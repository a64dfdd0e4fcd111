"""Fit the body model to your own scans: ``arteq-fit INPUT... --out DIR`` and its Python API.

    from arteq.fit import fit_points, fit_files, Fitter
    result = fit_points(points)                  # [N, 3] metres -> FitResult
    summary = fit_files(["scans/"], "fits/")     # what the command does

Names are imported lazily so that ``arteq-fit --help`` starts without loading torch.
"""

from __future__ import annotations

from arteq._lazy import lazy_exports

__all__ = ["FitResult", "Fitter", "RunSummary", "fit_files", "fit_points", "get_fitter", "write_result"]

_WHERE = {
    "FitResult": "arteq.fit.api",
    "Fitter": "arteq.fit.api",
    "fit_points": "arteq.fit.api",
    "get_fitter": "arteq.fit.api",
    "RunSummary": "arteq.fit.files",
    "fit_files": "arteq.fit.files",
    "write_result": "arteq.fit.files",
}
__getattr__ = lazy_exports(__name__, _WHERE)
