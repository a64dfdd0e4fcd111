"""The check's ``off_fit_limb`` rule on recorded fits: which fits it would doubt at given thresholds.

    python experiments/fitting/off_fit_table.py experiments/fitting/off_fit/measure_*.json \
        --frac 0.012 0.02 0.03 --cm 15 20

Reads ``user_scans.py --json``, ``check_calibration.py --out`` and ``scan_defects.py --json`` records made with
the rule off (its values are recorded all the same) and counts, per threshold pair, the fits the rule would
newly doubt: those written ``ok`` today, split by whether they are good (V2V <= 3 cm) or not. A good fit
doubted is a false doubt (written, but flagged); a bad one caught is a false acceptance fewer.
"""

from __future__ import annotations

import argparse
import json


def load(path: str) -> list[dict]:
    out = []
    data = json.load(open(path))
    for r in data["records"] if isinstance(data, dict) else data:
        q = r.get("quality") or r  # check_calibration nests the check's values
        if q.get("off_group_frac") is None or r.get("v2v_cm") is None:
            continue
        name = r.get("name") or f"{r.get('body')}: {r.get('defect')}"
        out.append({"set": path.rsplit("/", 1)[-1].replace(".json", ""), "name": name, "status": r["status"],
                    "v2v": r["v2v_cm"], "frac": q["off_group_frac"], "cm": q["off_group_cm"]})  # fmt: skip
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("records", nargs="+")
    ap.add_argument("--frac", type=float, nargs="+", default=[0.012, 0.02, 0.03])
    ap.add_argument("--cm", type=float, nargs="+", default=[15.0, 20.0])
    args = ap.parse_args()
    rows = [r for p in args.records for r in load(p)]
    ok = [r for r in rows if r["status"] == "ok"]
    print(f"{len(rows)} written fits, {len(ok)} `ok` ({sum(r['v2v'] > 3 for r in ok)} of them above 3 cm V2V)\n")
    print("| share >= | extent >= cm | good `ok` fits doubted | bad `ok` fits caught | of the bad |")
    print("|---:|---:|---:|---:|---:|")
    for f in args.frac:
        for c in args.cm:
            hit = [r for r in ok if r["frac"] >= f and r["cm"] >= c]
            good, bad = [r for r in hit if r["v2v"] <= 3], [r for r in hit if r["v2v"] > 3]
            print(f"| {f:g} | {c:g} | {len(good)} | {len(bad)} | {sum(r['v2v'] > 3 for r in ok)} |")
    print("\n`ok` fits with the largest off-fit groups:\n")
    for r in sorted(ok, key=lambda r: -r["frac"])[:12]:
        print(f"- {r['set']}: {r['name']}: V2V {r['v2v']:.2f} cm, group {r['frac']:.3f} of the points, {r['cm']:.1f} cm")


if __name__ == "__main__":
    main()
