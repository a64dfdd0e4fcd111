"""Compare two runs of the same scans (records written by user_scans.py --json or check_calibration.py --out):
per scan V2V and status before / after, the scans that changed, and the totals.

    python experiments/fitting/compare_records.py BEFORE.json AFTER.json [--label-before X --label-after Y]
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def load(path: str) -> dict[tuple[str, str], dict]:
    return {(r["group"], r["name"]): r for r in json.loads(open(path).read())["records"]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--label-before", default="before")
    ap.add_argument("--label-after", default="after")
    ap.add_argument("--usable-cm", type=float, default=3.0)
    a = ap.parse_args()
    b, c = load(a.before), load(a.after)
    keys = [k for k in c if k in b]
    print(f"| group | scan | V2V cm, {a.label_before} | V2V cm, {a.label_after} | status | fit s |")
    print("|---|---|---:|---:|---|---:|")
    v_b, v_a = [], []
    for k in keys:
        x, y = b[k], c[k]
        vb, va = x.get("v2v_cm"), y.get("v2v_cm")
        if vb is not None and va is not None:
            v_b.append(vb)
            v_a.append(va)
        changed = x["status"] != y["status"] or (vb is not None and va is not None and abs(va - vb) > 0.05)
        if changed:
            sec = y.get("fit_s", y.get("seconds"))
            fb, fa = ("-" if v is None else f"{v:.2f}" for v in (vb, va))
            print(f"| {k[0]} | {k[1]} | {fb} | {fa} | {x['status']} -> {y['status']} "
                  f"| {'' if sec is None else f'{sec:.2f}'} |")  # fmt: skip
    v_b, v_a = np.array(v_b), np.array(v_a)
    u = a.usable_cm
    print(f"\n{len(keys)} scans, {len(v_b)} bodies: V2V mean {v_b.mean():.2f} -> {v_a.mean():.2f} cm, median "
          f"{np.median(v_b):.2f} -> {np.median(v_a):.2f}; usable (<= {u:g} cm) {int((v_b <= u).sum())} -> "
          f"{int((v_a <= u).sum())}; worse by > 0.5 cm: {int((v_a > v_b + 0.5).sum())}, better by > 0.5 cm: "
          f"{int((v_a < v_b - 0.5).sum())}")  # fmt: skip


if __name__ == "__main__":
    main()
