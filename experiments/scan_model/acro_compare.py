"""Compare two ``acro_eval.py --fit --json`` runs of the same scans: totals, per template, the scans that
moved.

    python experiments/scan_model/acro_compare.py BEFORE.json AFTER.json [--moved-cm 0.5]
"""

from __future__ import annotations

import argparse
import json

import numpy as np


def rows(path: str) -> dict[tuple[str, int], dict]:
    data = json.loads(open(path).read())
    return {(r["template"], r["body"]): r for r in (data["rows"] if isinstance(data, dict) else data)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("before")
    ap.add_argument("after")
    ap.add_argument("--moved-cm", type=float, default=0.5)
    a = ap.parse_args()
    b, c = rows(a.before), rows(a.after)
    keys = [k for k in c if k in b]
    x = np.array([b[k]["v2v_cm"] for k in keys])
    y = np.array([c[k]["v2v_cm"] for k in keys])
    tx, ty = sum(b[k]["fit_s"] for k in keys), sum(c[k]["fit_s"] for k in keys)
    same = int((np.abs(x - y) < 0.005).sum())
    print(f"{len(keys)} scans: V2V mean {x.mean():.2f} -> {y.mean():.2f} cm, median {np.median(x):.2f} -> "
          f"{np.median(y):.2f}, worst {x.max():.2f} -> {y.max():.2f}, above 5 cm {(x > 5).sum()} -> "
          f"{(y > 5).sum()}; fit seconds {tx:.0f} -> {ty:.0f}; {same} unchanged")  # fmt: skip
    print("\n| template | V2V mean before | after | above 5 cm before | after |\n|---|---:|---:|---:|---:|")
    for t in dict.fromkeys(k[0] for k in keys):
        sel = [i for i, k in enumerate(keys) if k[0] == t]
        over = f"{(x[sel] > 5).sum()} | {(y[sel] > 5).sum()}"
        print(f"| {t} | {x[sel].mean():.2f} | {y[sel].mean():.2f} | {over} |")
    moved = [i for i in range(len(keys)) if abs(x[i] - y[i]) > a.moved_cm]
    print(f"\nMoved by more than {a.moved_cm} cm ({len(moved)}):\n")
    for i in moved:
        t, body = keys[i]
        how = (c[keys[i]].get("crossing") or {}).get("taken", "")
        print(f"- {t} body {body}: {x[i]:.2f} -> {y[i]:.2f}" + (f" (crossing: {how})" if how else ""))


if __name__ == "__main__":
    main()
