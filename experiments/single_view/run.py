"""Fit held-out simulated single-view scans with the shipped model: V2V, MPJPE, time per scan.

The scans are the cached view test sets of :mod:`arteq.data.single_view` (``data.view_splits``: the same
bodies, everyday poses, seen from the front, the side, the back and from above), and for reference the same
bodies' full-surface clouds (``test_view_full``: the full sampler on the same stream). Arms:

* ``network``: the network alone (``refine=False``), translation as the fitter places a scan of its mode;
* ``refine_full``: the refinement as for full scans (``partial=False``: model -> scan on every vertex);
* ``refine_partial``: the default fitter (scan mode detected; partial scans refined with the model -> scan
  term on the vertices the estimated camera sees).

Writes ``results/<arm>.json`` (per scan: split, V2V, MPJPE, seconds, mode, parts seen) and, with
``--table``, ``table.md`` from every results file present. Run from the repository root::

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python experiments/single_view/run.py --arm network --scans 16
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

HERE = Path(__file__).resolve().parent
SPLITS = ("test_view_full", "test_view_front", "test_view_side", "test_view_back", "test_view_top")
ARMS = {
    "network": {"refine": False},
    "refine_full": {"refine": True, "partial": False},
    "refine_partial": {"refine": True},
}


def scans(n: int, body) -> dict[str, dict[str, torch.Tensor]]:
    """``{split: stacked samples}``: ``n`` bodies per view (cached sets) and their full-surface clouds."""
    from arteq.data import BodyScanDataModule
    from arteq.data.dataset import BodyScanDataset
    from arteq.data.single_view import VIEW_SPLITS

    dm = BodyScanDataModule(body_model=body, num_points=5000, test_size=n, view_splits=list(VIEW_SPLITS))
    out = {}
    for split in VIEW_SPLITS:
        out[split] = dm.fixed_set(split).tensors
    # the same bodies (stream "test_view"), sampled on their whole surface
    src = dm.make_dataset("test_view_front").source
    full = BodyScanDataset(src, body, "test_view", n, seed=dm.seed, augment=dm.eval_augment, **dm.sampling)
    items = [full[i] for i in range(n)]
    out["test_view_full"] = {k: torch.stack([it[k] for it in items]) for k in items[0]}
    return out


def run_arm(arm: str, n: int, threads: int, ckpt: str | None = None) -> list[dict]:
    from arteq.fit.api import Fitter

    torch.set_num_threads(threads)
    fitter = Fitter(ckpt=ckpt, device="cpu", anny=False, **ARMS[arm])
    body = fitter.body
    data = scans(n, body)
    rows = []
    for split in SPLITS:
        d = data[split]
        for i in range(n):
            pts = d["points"][i].double().numpy()
            t0 = time.perf_counter()
            res = fitter.fit_points(pts, name=f"{split}_{i}")
            wall = time.perf_counter() - t0
            with torch.no_grad():
                one = slice(i, i + 1)
                gt = body(betas=d["betas"][one], pose=d["pose"][one], transl=d["transl"][one])
            v2v = float(np.linalg.norm(res.vertices - gt.vertices[0].numpy(), axis=1).mean() * 100)
            mpjpe = float(np.linalg.norm(res.joints - gt.joints[0].numpy(), axis=1).mean() * 100)
            labelled = res.point_labels >= 0  # clutter removal may drop flying pixels
            acc = float((res.point_labels[labelled] == d["labels"][i].numpy()[labelled]).mean() * 100)
            rows.append({
                "split": split, "index": i, "v2v_cm": v2v, "mpjpe_cm": mpjpe, "part_acc": acc,
                "seconds": wall,
                "status": res.status, "scan_mode": res.scan_mode, "reason": res.scan_mode_reason,
                "parts_seen": int(res.parts_seen.sum()) if res.parts_seen is not None else None,
                "one_sidedness": res.one_sidedness,
            })  # fmt: skip
            msg = f"V2V {v2v:.1f} cm, MPJPE {mpjpe:.1f} cm, parts {acc:.0f} %, {wall:.2f} s, {res.scan_mode}"
            print(f"{arm} {split} {i}: {msg}")
    return rows


def table(folder: Path) -> str:
    lines = [
        "| arm | scans | " + " | ".join(s.replace("test_view_", "") for s in SPLITS) + " |",
        "|---|---|" + "---|" * len(SPLITS),
    ]
    for arm in ARMS:
        path = folder / f"{arm}.json"
        if not path.is_file():
            continue
        res = json.loads(path.read_text())
        rows = res["rows"]
        cells = []
        for s in SPLITS:
            r = [x for x in rows if x["split"] == s]
            if not r:
                cells.append("–")
                continue
            v = np.array([x["v2v_cm"] for x in r])
            j = np.array([x["mpjpe_cm"] for x in r])
            t = np.median([x["seconds"] for x in r])
            part = np.mean([x["scan_mode"] == "partial" for x in r]) * 100
            acc = np.mean([x.get("part_acc", np.nan) for x in r])
            cells.append(
                f"{v.mean():.1f} / {np.median(v):.1f} / {j.mean():.1f} / {acc:.0f} % / {t:.2f} s / "
                f"{part:.0f} %"
            )
        lines.append(f"| {arm} | {len(rows) // len(SPLITS)} per view | " + " | ".join(cells) + " |")
    note = (
        "\nEach cell: V2V mean / median (cm, all vertices), MPJPE mean (cm, 22 joints), the network's part "
        "accuracy on the scan's points, median seconds per scan (wall clock of `Fitter.fit_points`), "
        "share of scans fitted in partial mode."
    )
    return "\n".join(lines) + "\n" + note + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", choices=sorted(ARMS), action="append", default=[])
    ap.add_argument("--scans", type=int, default=16, help="scans per view")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--ckpt", default=None, help="checkpoint or shipped model name (default: anny22)")
    ap.add_argument("--out", default=str(HERE / "results"), help="folder of the results files")
    ap.add_argument("--table", action="store_true", help="write table.md from the results present")
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for arm in args.arm:
        rows = run_arm(arm, args.scans, args.threads, args.ckpt)
        meta = {"arm": arm, "scans_per_view": args.scans, "threads": args.threads, "fitter": ARMS[arm],
                "ckpt": args.ckpt or "anny22"}  # fmt: skip
        (out / f"{arm}.json").write_text(json.dumps({**meta, "rows": rows}, indent=1))
    if args.table:
        text = table(out)
        (out.parent / "table.md" if out == HERE / "results" else out / "table.md").write_text(text)
        print(text)


if __name__ == "__main__":
    main()
