"""Two people in one depth camera's view, given as bare points (no camera position): does the fitter still
refuse them (``not_single_body``)? Two bodies of the all-ages body (random shapes, standing, facing the
camera) side by side ``--gaps`` metres apart (between their nearest vertices, across the camera's view),
seen from the front, 2.5 m away, by the simulator of :mod:`arteq.data.single_view` (5000 points). Run from
the repository root::

    OMP_NUM_THREADS=1 python experiments/single_view/two_people_probe.py --pairs 4
"""

from __future__ import annotations

import argparse

import numpy as np
import torch


def scene(body, gap: float, seed: int) -> np.ndarray:
    from arteq.data.single_view import SingleViewConfig, single_view_scan

    g = torch.Generator().manual_seed(seed)
    betas = torch.randn(2, body.num_betas, generator=g, dtype=body.v_template.dtype) * 0.8
    pose = torch.eye(3, dtype=betas.dtype).expand(2, 22, 3, 3).contiguous()
    with torch.no_grad():
        out = body(betas=betas, pose=pose)
    a, b = out.vertices[0].double(), out.vertices[1].double()
    shift = a[:, 0].max() - b[:, 0].min() + gap  # b to the left of a (along x), ``gap`` apart
    b = b + torch.tensor([shift, 0.0, 0.0], dtype=b.dtype)
    verts = torch.cat([a, b])
    faces = torch.cat([body.faces, body.faces + len(a)])
    weights = torch.cat([body.lbs_weights, body.lbs_weights]).double()
    pelvis = 0.5 * (out.joints[0, 0].double() + out.joints[1, 0].double() + torch.tensor([shift, 0, 0]))
    cfg = SingleViewConfig(distance_m=(2.5, 2.5))
    scan = single_view_scan(
        verts, faces, weights, pelvis, torch.eye(3, dtype=torch.float64), 5000, g, cfg, "front"
    )
    return scan["points"].numpy()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pairs", type=int, default=4, help="pairs of bodies per gap")
    ap.add_argument("--gaps", type=float, nargs="*", default=[0.05, 0.15, 0.3, 0.6])
    ap.add_argument("--ckpt", default="anny_scan")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from arteq.fit.api import Fitter

    fitter = Fitter(ckpt=args.ckpt, device="cpu", anny=False)
    body = fitter.module.body
    for gap in args.gaps:
        for k in range(args.pairs):
            res = fitter.fit_points(scene(body, gap, seed=k), name=f"gap{gap:g}_{k}")
            print(
                f"gap {gap:.2f} m, pair {k}: {res.status} ({res.message or res.uncertain_reason})"[:220],
                flush=True,
            )


if __name__ == "__main__":
    main()
