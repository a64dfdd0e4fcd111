"""Probe: the network's prediction averaged over several random 500-point subsets of the same scan.

The network reads 500 points (its training size) drawn at random from a scan of thousands; two draws of the
same clean scan give bodies ~6 cm apart (experiments/fitting/clutter_spread.py, network alone). Averaging the
predictions of K draws (per joint: the chordal mean of the global rotations; betas and translation: the mean)
is a test-time average over the draw, not over orientation (section 2c of experiments/fitting/README.md).

    OMP_NUM_THREADS=1 python experiments/fitting/resample_average.py [--seed 0] [--k 1,2,4,8]

The user-scan suite's scans with a truth (``user_scans.people_scans(seed)``), the network alone (anny_scan):
V2V cm to the truth per group for K draws (the first K of 8), and the spread of two disjoint K-averages.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def main() -> None:
    import user_scans as us

    from arteq.fit import Fitter
    from arteq.fit.api import mean_prediction, resample

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--k", default="1,2,4,8")
    ap.add_argument("--rotate", action="store_true", help="draws turned, predictions turned back")
    a = ap.parse_args()
    ks = [int(x) for x in a.k.split(",")]
    draws = 2 * max(ks)
    torch.set_num_threads(1)
    f = Fitter(ckpt="anny_scan", device="cpu", anny=False)
    body = f.body
    rows = {}
    for s in us.people_scans(a.seed):
        if not s.truth:
            continue
        it = f.prepare(s.points, name=s.name)
        clouds = [resample(it["centred"], f.net_points, np.random.default_rng(d)) for d in range(draws)]
        turns = [np.eye(3)] * (1 if a.rotate else draws)
        if a.rotate:  # the first draw as it is, the others turned (a fixed seed per draw)
            gens = [torch.Generator().manual_seed(100 + d) for d in range(1, draws)]
            turns += [roma.random_rotmat(generator=g, dtype=torch.float64).numpy() for g in gens]
            clouds = [c @ q.T for c, q in zip(clouds, turns)]
        with torch.no_grad():
            pred = f._network(clouds)
            if a.rotate:  # back into the scan's frame: the root turned back, the translation about the pelvis
                q = torch.as_tensor(np.stack(turns), dtype=torch.float64)
                dt = body.v_template.dtype
                nb = body.num_betas - pred["betas"].shape[1]
                padded = torch.nn.functional.pad(pred["betas"], (0, max(0, nb))).to(dt)
                j0 = body(betas=padded).joints[:, 0].double()
                local = pred["local_rotmats"].double().clone()
                local[:, 0] = q.transpose(-1, -2) @ local[:, 0]
                t = (q.transpose(-1, -2) @ (j0 + pred["transl"].double())[..., None])[..., 0] - j0
                pred = {**pred, "local_rotmats": local.to(pred["local_rotmats"].dtype), "transl": t}
            out = []
            for k in ks:
                both = []
                for off in (0, max(ks)):
                    rows_k = {n: pred[n][off : off + k] for n in ("local_rotmats", "betas", "transl")}
                    p = mean_prediction(rows_k, k)
                    nb = body.num_betas - p["betas"].shape[1]
                    betas = torch.nn.functional.pad(p["betas"], (0, max(0, nb)))
                    dt = body.v_template.dtype
                    posed = body(betas=betas.to(dt), pose=p["local_rotmats"].to(dt), transl=p["transl"])
                    v = posed.vertices[0].double().numpy() + it["center"]
                    both.append(v)
                v2v = np.linalg.norm(both[0] - s.vertices, axis=1).mean() * 100
                spread = np.linalg.norm(both[0] - both[1], axis=1).mean() * 100
                out.append((v2v, spread))
        rows.setdefault(s.group, []).append(out)
        print(f"{s.group:10s} {s.name[:40]:40s} " + "  ".join(f"K{k}: {v:5.1f} ({sp:4.1f})"
              for k, (v, sp) in zip(ks, out)), flush=True)  # fmt: skip
    print("\ngroup: V2V to the truth mean (spread of two K-averages mean), cm")
    for g, r in rows.items():
        m = np.array(r).mean(0)
        print(
            f"{g:10s} n={len(r):2d} " + "  ".join(f"K{k}: {v:5.2f} ({sp:4.2f})" for k, (v, sp) in zip(ks, m))
        )


if __name__ == "__main__":
    main()
