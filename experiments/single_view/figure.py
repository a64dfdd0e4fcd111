"""The README's picture: one held-out single-view scan (a depth camera in front of the body) and its fit,
both from the front and from the side, drawn by the fitter's own preview (:mod:`arteq.fit.preview`).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/single_view/figure.py
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from run import scans  # noqa: E402


def main(index: int = 0, view: str = "test_view_front") -> Path:
    from arteq.fit.api import Fitter
    from arteq.fit.preview import render_preview

    torch.set_num_threads(1)
    fitter = Fitter(device="cpu", anny=False)
    d = scans(max(2, index + 1), fitter.body)[view]
    res = fitter.fit_points(d["points"][index].double().numpy(), name=f"{view} #{index}")
    with torch.no_grad():
        one = slice(index, index + 1)
        gt = fitter.body(betas=d["betas"][one], pose=d["pose"][one], transl=d["transl"][one]).vertices[0]
    v2v = float(np.linalg.norm(res.vertices - gt.numpy(), axis=1).mean() * 100)
    res.name = f"{view.replace('test_view_', '')} view"  # the preview's title: status, inliers, clutter
    out = render_preview(res, HERE / "single_view_fit.png", dpi=60)
    print(f"{out}: {res.name}, V2V {v2v:.1f} cm, {res.status}, {res.scan_mode_reason}")
    return out


if __name__ == "__main__":
    main()
