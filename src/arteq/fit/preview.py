"""Preview PNG of a fit: the scan coloured by predicted part (removed clutter in grey) next to the
fitted mesh, two views.

Views are orthographic in the fitted body's own frame (front and left side, head up), whatever the
scan's orientation. Drawn with matplotlib (Agg) as depth-sorted points: no 3D toolkit, fast.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np


def _normals(v: np.ndarray, f: np.ndarray) -> np.ndarray:
    fn = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    vn = np.zeros_like(v)
    for c in range(3):
        np.add.at(vn, f[:, c], fn)
    return vn / np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)


def render_preview(res, out: str | Path, dpi: int = 80) -> Path:
    """Write the preview of ``res`` (:class:`arteq.fit.FitResult`) to ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from arteq.viz.data_grid import part_colours

    s = res.scale_to_m
    r0 = np.asarray(res.global_rotmats[0], dtype=np.float64)
    pelvis = np.asarray(res.joints[0], dtype=np.float64) * s
    # body frame of the fit (SMPL / anny22 axes: x left, y up, z front), metres
    to_body = lambda x: (np.asarray(x, dtype=np.float64) * s - pelvis) @ r0  # noqa: E731
    pts, verts = to_body(res.scan_points), to_body(res.vertices)
    normals = _normals(verts, np.asarray(res.faces))
    cols = part_colours(22)
    labels = np.clip(np.asarray(res.scan_labels, dtype=np.int64), 0, 21)
    views = [("front", 0, 2, 1.0), ("side", 2, 0, -1.0)]  # name, horizontal axis, depth axis, sign
    fig, axes = plt.subplots(2, 2, figsize=(6.4, 6.6))
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
    plt.close(fig)
    return Path(out)
