"""Preview PNG of a fit: the scan coloured by predicted part (removed clutter in grey) next to the
fitted mesh, two views.

Views are orthographic in the fitted body's own frame (front and left side, head up), whatever the
scan's orientation. Drawn with matplotlib as depth-sorted points (no 3D toolkit, fast) on a figure of
its own with the Agg canvas: the process's matplotlib backend is never switched.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def part_colours(k: int = 22) -> np.ndarray:
    """``[k, 4]`` RGBA part colours (tab20, then Set1), from matplotlib's colormap registry: nothing global
    is touched (``arteq.viz.data_grid`` switches the backend on import, so it is not imported here)."""
    from matplotlib import colormaps

    tab, extra = colormaps["tab20"], colormaps["Set1"]
    return np.asarray([tab(i) for i in range(min(k, 20))] + [extra(i) for i in range(k - 20)])


def render_preview(res, out: str | Path, dpi: int = 80) -> Path:
    """Write the preview of ``res`` (:class:`arteq.fit.FitResult`) to ``out`` (PNG)."""
    import torch
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from arteq.geometry.normals import vertex_normals

    s = res.scale_to_m
    r0 = np.asarray(res.global_rotmats[0], dtype=np.float64)
    pelvis = np.asarray(res.joints[0], dtype=np.float64) * s
    # body frame of the fit (SMPL / anny22 axes: x left, y up, z front), metres
    to_body = lambda x: (np.asarray(x, dtype=np.float64) * s - pelvis) @ r0  # noqa: E731
    pts, verts = to_body(res.scan_points), to_body(res.vertices)
    faces = torch.as_tensor(np.asarray(res.faces, dtype=np.int64))
    normals = vertex_normals(torch.from_numpy(verts)[None], faces)[0].numpy()
    cols = part_colours(22)
    labels = np.clip(np.asarray(res.scan_labels, dtype=np.int64), 0, 21)
    views = [("front", 0, 2, 1.0), ("side", 2, 0, -1.0)]  # name, horizontal axis, depth axis, sign
    # a Figure of its own with the Agg canvas: no pyplot, the caller's matplotlib backend stays as it was
    fig = Figure(figsize=(6.4, 6.6))
    FigureCanvasAgg(fig)
    axes = fig.subplots(2, 2)
    lim = np.abs(np.concatenate([pts, verts])).max(0) + 0.05
    clutter = getattr(res, "clutter_points", None)
    clutter = to_body(clutter) if clutter is not None and len(clutter) else None
    if clutter is not None:  # only what falls into the picture (floor under the feet, wall behind...)
        clutter = clutter[np.all(np.abs(clutter) <= lim + 0.3, axis=1)]
    for row, (view, h, depth, sign) in enumerate(views):
        if clutter is not None and len(clutter):
            ch = sign * clutter[:, h] if h == 2 else clutter[:, h]
            axes[row, 0].scatter(ch, clutter[:, 1], s=0.6, c="0.75", linewidths=0)
        order_p = np.argsort(sign * pts[:, depth])
        axes[row, 0].scatter(sign * pts[order_p, h] if h == 2 else pts[order_p, h], pts[order_p, 1],
                             s=1.0, c=cols[labels[order_p]], linewidths=0)  # fmt: skip
        order_v = np.argsort(sign * verts[:, depth])
        shade = np.clip(sign * normals[order_v, depth], 0, 1) * 0.7 + 0.25
        hv = sign * verts[order_v, h] if h == 2 else verts[order_v, h]
        axes[row, 1].scatter(hv, verts[order_v, 1], s=0.6, c=np.repeat(shade[:, None], 3, 1), linewidths=0)
        for col in range(2):
            ax = axes[row, col]
            ax.set_aspect("equal")
            ax.set_xlim(-max(lim[0], lim[2]), max(lim[0], lim[2]))
            ax.set_ylim(-lim[1], lim[1])
            ax.set_xticks([])
            ax.set_yticks([])
            ax.set_title(f"{'scan (predicted parts)' if col == 0 else 'fitted mesh'}, {view}", fontsize=8)
    q = res.quality
    removed = ""
    if getattr(res, "clean", None) is not None:
        n = sum(v for k, v in res.clean.counts.items() if k != "kept")
        removed = f"; {n} clutter points removed (grey)" if n else ""
    fig.suptitle(
        f"{res.name}: {res.status}; {q.get('inlier_frac', float('nan')):.0%} inliers, "
        f"rmse {q.get('rmse_in_cm', float('nan')):.2f} cm{removed}",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(out, dpi=dpi, format="png")
    return Path(out)
