"""How far the refinement converges: the user-scan suite's children and adults fitted with other refinement
settings (issue 19's V2V, stature and waist goals).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/converge.py \
        --arm "old=iters=40,points=0,w_betas=0.5,lr_betas=0.05" --arm "all_points=points=0" --arm default \
        --out experiments/fitting/converge/arms.md --json experiments/fitting/converge/arms.json

Each ``--arm NAME[=KEY=VALUE,...]`` is :class:`arteq.fit.refine.RefineConfig` over its defaults; every
other setting is ``arteq-fit``'s (``Fitter`` defaults: second start, crossing search, check, Anny export).
The scans are ``user_scans.py``'s ``children`` and ``adults`` groups (seed 0: the same 20 scans). Per arm:
V2V, stature and waist error (the Anny export against the truth) over the scans every arm fits within 5 cm
(the two lost reach_up scans are the network's and every arm loses them), and the median fit seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))


def parse_arm(spec: str) -> tuple[str, list[str]]:
    name, _, rest = spec.partition("=")
    return name, [kv for kv in rest.split(",") if kv]


def main(argv: list[str] | None = None) -> None:
    import user_scans as us

    from arteq.fit import Fitter
    from arteq.fit.refine import RefineConfig

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arm", action="append", required=True, help="NAME[=KEY=VALUE,...] (RefineConfig)")
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--out", default=None, help="Markdown table")
    ap.add_argument("--json", default=None, help="every scan's record per arm")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    scans = [s for s in us.people_scans(0) if s.group in ("children", "adults")]
    records: dict[str, list[dict]] = {}
    settings: dict[str, list[str]] = {}
    for spec in a.arm:
        name, items = parse_arm(spec)
        cfg = RefineConfig.from_strings(items)
        settings[name] = items
        fitter = Fitter(ckpt=a.ckpt, device="cpu", points=5000, anny=True, refine_config=cfg)
        records[name] = []
        for s in scans:
            rec = us.fit_scan(fitter, s)
            records[name].append(rec)
            st = us._f(rec.get("stature_err_cm"), signed=True)
            wa = us._f(rec.get("waist_err_cm"), signed=True)
            print(f"{name:12s} {s.name[:44]:44s} {rec['status']:10s} V2V {us._f(rec.get('v2v_cm'))} "
                  f"stature {st} waist {wa} {us._f(rec.get('fit_s'))} s", flush=True)  # fmt: skip
    fitted = [all((r[i].get("v2v_cm") or 1e9) <= 5 for r in records.values()) for i in range(len(scans))]
    both = [i for i, f in enumerate(fitted) if f]
    lines = [
        f"{len(scans)} scans (user_scans.py children and adults, seed 0); the {len(both)} every arm fits "
        "within 5 cm are averaged. V2V cm mean / median; |stature| and |waist| error cm mean / worst "
        "(Anny export against the truth); fit seconds median (one thread, beside other jobs: compare "
        "within a run only).",
        "",
        "| arm | settings over the defaults | V2V | stature | waist | fit s |",
        "|---|---|---|---|---|---:|",
    ]
    for name, recs in records.items():
        sel = [recs[i] for i in both]
        v = np.array([r["v2v_cm"] for r in sel])
        st = np.abs([r["stature_err_cm"] for r in sel])
        wa = np.abs([r["waist_err_cm"] for r in sel])
        secs = np.median([r["fit_s"] for r in recs if r.get("fit_s") is not None])
        lines.append(f"| {name} | {', '.join(settings[name]) or '(defaults)'} | {v.mean():.2f} / "
                     f"{np.median(v):.2f} | {st.mean():.2f} / {st.max():.2f} | {wa.mean():.2f} / "
                     f"{wa.max():.2f} | {secs:.2f} |")  # fmt: skip
    lines += ["", "| scan | " + " | ".join(records) + " |", "|---|" + "---:|" * len(records)]
    for i, s in enumerate(scans):
        cells = " | ".join(us._f(r[i].get("v2v_cm")) for r in records.values())
        lines.append(f"| {s.name} | {cells} |")
    text = "\n".join(lines) + "\n"
    us.report(text, a.out)
    if a.json:
        Path(a.json).parent.mkdir(parents=True, exist_ok=True)
        out = {"settings": settings, "records": records}
        Path(a.json).write_text(json.dumps(out, indent=1, default=float))


if __name__ == "__main__":
    main()
