"""Fit held-out simulated single-view scans with the shipped model: V2V, MPJPE, time per scan.

The scans are the cached view test sets of :mod:`arteq.data.single_view` (``data.view_splits``: the same
bodies, everyday poses, seen from the front, the side, the back and from above), and for reference the same
bodies' full-surface clouds (``test_view_full``: the full sampler on the same stream). Arms:

* ``network``: the network alone (``refine=False``), translation as the fitter places a scan of its mode;
* ``refine_full``: the refinement as for full scans (``partial=False``: model -> scan on every vertex);
* ``refine_partial_single``: as before the start hypotheses (``hypotheses=False``): partial scans refined
  from the network's start only;
* ``refine_partial_scored``: the network's start and the untwisted one both refined briefly, the one the
  partial objective and free-space share score best kept (``HypothesisConfig(keep_network=True)``);
* ``refine_partial_turned``: as ``refine_partial_scored`` plus the untwisted start turned 180 degrees
  about the body's up axis (``turns_deg=(0, 180)``);
* ``refine_partial``: the default fitter (scan mode detected; partial scans refined with the model -> scan
  term on the vertices the estimated camera sees, from the start picked among
  :func:`arteq.fit.partial.start_hypotheses`: the network's and, where parts of it are turned the wrong way
  round, the untwisted one).

Writes ``results/<arm>.json`` (per scan: split, V2V, also on the true vertices the camera saw and on the rest,
MPJPE, seconds, mode, parts seen) and, with
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
SPLITS = ("test_view_full", "test_view_front", "test_view_side", "test_view_back", "test_view_top", "test_view_near")
ARMS = {
    "network": {"refine": False},
    "refine_full": {"refine": True, "partial": False},
    "refine_partial_single": {"refine": True, "hypotheses": False},
    "refine_partial_scored": {"refine": True, "hypotheses": {"keep_network": True}},
    "refine_partial_turned": {"refine": True, "hypotheses": {"keep_network": True, "turns_deg": (0, 180)}},
    "refine_partial": {"refine": True},
}


class HypothesisLog:
    """Records every start hypothesis a fit scored (its refined vertices and score), to compare the pick with
    the best of the hypotheses by the ground truth (patches :func:`arteq.fit.partial.hypothesis_score`)."""

    def __init__(self):
        import arteq.fit.partial as partial

        self.calls: list[tuple[np.ndarray, np.ndarray, dict]] = []
        orig = partial.hypothesis_score

        def logged(vertices, points, *args, **kwargs):
            out = orig(vertices, points, *args, **kwargs)
            self.calls.append((vertices, points, out))
            return out

        partial.hypothesis_score = logged

    def take(self, gt_vertices: np.ndarray, scan_points: np.ndarray) -> list[dict] | None:
        """V2V (cm) of each hypothesis of the last fit against ``gt_vertices`` (scan frame, metres)."""
        calls, self.calls = self.calls, []
        if not calls:
            return None
        out = []
        for verts, pts, score in calls:
            centre = scan_points.mean(0) - pts.mean(0)  # the fitted points are the centred ones, moved back
            v2v = float(np.linalg.norm(verts + centre - gt_vertices, axis=1).mean() * 100)
            out.append(
                {
                    "v2v_cm": v2v,
                    "score": score["score"],
                    "free": score["free"],
                    "s2m": score["s2m"],
                    "m2s": score["m2s"],
                }
            )
        return out


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


def swapped_errors(body, res, betas, pose, gt) -> dict:
    """V2V (cm) of the fit with the truth's shape put in (``v2v_true_shape_cm``) and with the truth's pose put
    in (``v2v_true_pose_cm``), each placed by the fit's root joint: which of the two the error comes from."""
    import roma

    fit_pose = roma.rotvec_to_rotmat(torch.as_tensor(res.pose_aa, dtype=betas.dtype))[None]
    fit_betas = torch.as_tensor(res.betas, dtype=betas.dtype)[None]
    out = {}
    with torch.no_grad():
        for key, b, p in (("v2v_true_shape_cm", betas, fit_pose), ("v2v_true_pose_cm", fit_betas, pose)):
            o = body(betas=b, pose=p, transl=torch.zeros(1, 3, dtype=betas.dtype))
            shift = res.joints[0] - o.joints[0, 0].numpy()  # the fit's root joint
            v = o.vertices[0].numpy() + shift
            out[key] = float(np.linalg.norm(v - gt.vertices[0].numpy(), axis=1).mean() * 100)
    return out


def run_arm(
    arm: str,
    n: int,
    threads: int,
    ckpt: str | None = None,
    splits=None,
    refine_set=(),
    net_draws: int | None = None,
) -> list:
    from scipy.spatial import cKDTree

    from arteq.fit.api import Fitter
    from arteq.fit.refine import RefineConfig

    torch.set_num_threads(threads)
    from arteq.fit.partial import HypothesisConfig

    kw = dict(ARMS[arm])
    if isinstance(kw.get("hypotheses"), dict):
        kw["hypotheses"] = HypothesisConfig(**kw["hypotheses"])
    if refine_set:  # --set KEY=VALUE: RefineConfig fields
        kw["refine_config"] = RefineConfig.from_strings(refine_set)
    fitter = Fitter(ckpt=ckpt, device="cpu", anny=False, net_draws=net_draws, **kw)
    log = HypothesisLog()
    # the scans and their truth on the network's body (the cached view sets); the fit's body may hold more
    # shape components (Fitter's shape_betas: 32 for anny_allages), the truth's betas padded for it
    body = fitter.module.body
    data = scans(n, body)
    rows = []
    for split in [s for s in SPLITS if not splits or s.replace("test_view_", "") in splits]:
        d = data[split]
        for i in range(n):
            pts = d["points"][i].double().numpy()
            t0 = time.perf_counter()
            res = fitter.fit_points(pts, name=f"{split}_{i}")
            wall = time.perf_counter() - t0
            with torch.no_grad():
                one = slice(i, i + 1)
                gt = body(betas=d["betas"][one], pose=d["pose"][one], transl=d["transl"][one])
            if res.vertices is None:  # refused: no fit to measure
                row = {"split": split, "index": i, "status": res.status, "seconds": wall, "v2v_cm": None}
                rows.append(row)
                print(f"{arm} {split} {i}: {res.status} ({res.message}), {wall:.2f} s")
                continue
            err = np.linalg.norm(res.vertices - gt.vertices[0].numpy(), axis=1) * 100
            v2v = float(err.mean())
            # the true vertices the camera saw (a scan point within 2 cm) and the rest (hidden side, holes)
            seen = cKDTree(pts).query(gt.vertices[0].double().numpy())[0] < 0.02
            true_betas = torch.nn.functional.pad(d["betas"][one], (0, fitter.body.num_betas - body.num_betas))
            swap = swapped_errors(fitter.body, res, true_betas, d["pose"][one], gt)
            mpjpe = float(np.linalg.norm(res.joints - gt.joints[0].numpy(), axis=1).mean() * 100)
            hyps = log.take(gt.vertices[0].double().numpy(), res.scan_points.astype(np.float64))
            labelled = res.point_labels >= 0  # clutter removal may drop flying pixels
            acc = float((res.point_labels[labelled] == d["labels"][i].numpy()[labelled]).mean() * 100)
            rows.append({
                "split": split, "index": i, "v2v_cm": v2v, "mpjpe_cm": mpjpe, "part_acc": acc,
                "v2v_seen_cm": float(err[seen].mean()) if seen.any() else None,
                "v2v_unseen_cm": float(err[~seen].mean()) if (~seen).any() else None,
                "seen_frac": float(seen.mean()),
                **swap,
                "seconds": wall,
                "status": res.status, "scan_mode": res.scan_mode, "reason": res.scan_mode_reason,
                "parts_seen": int(res.parts_seen.sum()) if res.parts_seen is not None else None,
                "one_sidedness": res.one_sidedness,
                "start": res.start_hypothesis, "hypotheses": hyps,
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
            refused = sum(x["v2v_cm"] is None for x in r)
            r = [x for x in r if x["v2v_cm"] is not None]
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
                f"{part:.0f} %" + (f" / {refused} refused" if refused else "")
            )
        per_view = len(rows) // len({x["split"] for x in rows})
        lines.append(f"| {arm} | {per_view} per view | " + " | ".join(cells) + " |")
    note = (
        "\nEach cell: V2V mean / median (cm, all vertices), MPJPE mean (cm, 22 joints), the network's part "
        "accuracy on the scan's points, median seconds per scan (wall clock of `Fitter.fit_points`), "
        "share of scans fitted in partial mode."
    )
    return "\n".join(lines) + "\n" + note + "\n" + seen_table(folder) + picks(folder)


def seen_table(folder: Path) -> str:
    """V2V on the true vertices the camera saw (a scan point within 2 cm) and on the rest, per arm and view
    (results files that record it)."""
    lines = []
    for arm in ARMS:
        path = folder / f"{arm}.json"
        if not path.is_file():
            continue
        rows = [x for x in json.loads(path.read_text())["rows"] if x.get("v2v_seen_cm") is not None]
        cells = []
        for s in SPLITS:
            r = [x for x in rows if x["split"] == s and x.get("v2v_unseen_cm") is not None]
            if not r:
                cells.append("–")
                continue
            seen = np.mean([x["v2v_seen_cm"] for x in r])
            unseen = np.mean([x["v2v_unseen_cm"] for x in r])
            cell = f"{seen:.1f} / {unseen:.1f} / {np.mean([x['seen_frac'] for x in r]) * 100:.0f} %"
            if all("v2v_true_pose_cm" in x for x in r):
                shape = np.mean([x["v2v_true_shape_cm"] for x in r])
                pose = np.mean([x["v2v_true_pose_cm"] for x in r])
                cell += f" / {shape:.1f} / {pose:.1f}"
            cells.append(cell)
        if rows:
            lines.append(f"| {arm} | " + " | ".join(cells) + " |")
    if not lines:
        return ""
    head = (
        "\nV2V (cm, mean) on the true vertices the camera saw (a scan point within 2 cm) / on the rest (the "
        "hidden side and holes) / share of vertices seen; where recorded, the fit's V2V with the truth's "
        "shape put in / with the truth's pose put in (each placed by the fit's root joint):\n\n"
        "| arm | " + " | ".join(s.replace("test_view_", "") for s in SPLITS) + " |\n"
        "|---|" + "---|" * len(SPLITS) + "\n"
    )
    return head + "\n".join(lines) + "\n"


def picks(folder: Path, arm: str = "refine_partial_scored") -> str:
    """How the start hypotheses were picked (``arm``'s results): per view, scans with more than one start,
    the starts picked, and whether the pick is the start whose brief refinement is nearest the truth."""
    path = folder / f"{arm}.json"
    if not path.is_file():
        return ""
    rows = [r for r in json.loads(path.read_text())["rows"] if r.get("start")]
    if not rows:
        return ""
    lines = [
        f"\nStart hypotheses ({arm}): scans with more than one start, what was picked, picks that are the"
        " start nearest the truth after the brief refinement, and the V2V (cm, mean) after the brief"
        " refinement of the picked start and of the best one (oracle):\n",
        "| view | scans with starts to pick | picked (network / untwisted / turned) | right picks |"
        " brief V2V picked / oracle |",
        "|---|---:|---|---:|---|",
    ]
    for s in SPLITS:
        every = [x for x in rows if x["split"] == s]
        r = [x for x in every if x.get("hypotheses")]
        if not r:
            continue
        names = [x["start"]["picked"] for x in r]
        pick, best = [], []
        for x in r:
            h = x["hypotheses"]
            pick.append(h[int(np.argmin([a["score"] for a in h]))]["v2v_cm"])
            best.append(min(a["v2v_cm"] for a in h))
        right = int(np.isclose(pick, best).sum())
        turned = sum(n.startswith("turned") for n in names)
        count = f"{names.count('network')} / {names.count('untwisted')} / {turned}"
        view = s.replace("test_view_", "")
        lines.append(f"| {view} | {len(r)} of {len(every)} | {count} | {right} of {len(r)} | "
                     f"{np.mean(pick):.1f} / {np.mean(best):.1f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", choices=sorted(ARMS), action="append", default=[])
    ap.add_argument("--scans", type=int, default=16, help="scans per view")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--ckpt", default=None, help="checkpoint or shipped model name (default: anny22)")
    ap.add_argument("--out", default=str(HERE / "results"), help="folder of the results files")
    ap.add_argument("--table", action="store_true", help="write table.md from the results present")
    ap.add_argument("--splits", nargs="*", default=None, help="only these views (full front side back top)")
    ap.add_argument("--set", nargs="*", default=[], metavar="KEY=VALUE", help="RefineConfig fields")
    ap.add_argument(
        "--net-draws", type=int, default=None, help="Fitter(net_draws=...) (default: the Fitter's)"
    )
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for arm in args.arm:
        rows = run_arm(arm, args.scans, args.threads, args.ckpt, args.splits, args.set, args.net_draws)
        meta = {"arm": arm, "scans_per_view": args.scans, "threads": args.threads, "fitter": ARMS[arm],
                "ckpt": args.ckpt or "anny22", "refine_set": args.set,
                "net_draws": args.net_draws}  # fmt: skip
        (out / f"{arm}.json").write_text(json.dumps({**meta, "rows": rows}, indent=1))
    if args.table:
        text = table(out)
        (out.parent / "table.md" if out == HERE / "results" else out / "table.md").write_text(text)
        print(text)


if __name__ == "__main__":
    main()
