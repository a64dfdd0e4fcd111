"""Probe: when can a refinement's losing starts stop early? Records every start's surface score during the
refinement, and every start's final V2V, for the two places where ``arteq-fit`` refines several starts of
one scan and keeps one by that score:

* ``second``: a full scan's two starts (the network's and the second start's, ``Fitter(second_start=)``);
  the one with the lower final score is kept (experiments/fitting/second_start.md);
* ``crossing``: the crossed-limb step's starts (the fit refined again, ``none``, and each swapped pair;
  ``arteq.fit.crossing.try_swaps``).

    OMP_NUM_THREADS=1 python experiments/fitting/stop_probe.py record KIND SET OUT.json
    python experiments/fitting/stop_probe.py KIND OUT.json [OUT.json ...]    # the stopping rules' table

``KIND``: ``second`` or ``crossing``. ``SET``: ``users``, the bodies of the user-scan suite
(``user_scans.people_scans``), or ``seed0`` / ``seed1``, the bodies of the check's labelled set
(``check_calibration.labelled_set``). Every scan goes through ``Fitter.fit_points`` with ``arteq-fit``'s
defaults, the rule probed off (``second``: ``SECOND_START_STOPS = ()``; ``crossing``:
``CrossingConfig.stop_at = -1``), so every start runs to the end. Since a batch's scans are refined
independently, a rule that stops a start at iteration ``k`` changes a fit only where the stopped start would
have been kept: the table counts those scans and what the kept start's V2V would have been instead.
"""

from __future__ import annotations

import itertools
import json
import sys
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

#: iterations whose scores are recorded (the second start's refinement has 40, the crossing's 30)
RECORD = {"second": (4, 8, 12, 16, 20, 24, 28, 32, 36), "crossing": (2, 4, 6, 8, 10, 12, 14, 16, 20, 24)}


def bodies(which: str):
    if which.startswith("seed"):
        from check_calibration import labelled_set

        for it in labelled_set(int(which[4:])):
            if it.get("vertices") is not None:
                yield it["group"], it["name"], it["points"], it["vertices"]
    else:
        from user_scans import people_scans

        for s in people_scans(0):
            if s.vertices is not None:
                yield s.group, s.name, s.points, s.vertices


def record(kind: str, which: str, out: str) -> None:
    import arteq.fit.api as api
    import arteq.fit.refine as refine_mod
    from arteq.fit.crossing import CrossingConfig, surface_score

    torch.set_num_threads(1)
    if kind == "second":
        api.SECOND_START_STOPS = ()
    state: dict = {}
    keep = {"second": api.refine, "crossing": refine_mod.refine}[kind]

    def refine(body, points, probs, init, config=None, callback=None, **kw):
        if not state.get("armed"):
            return keep(body, points, probs, init, config, callback, **kw)
        state["armed"] = False
        pts = points.detach().double().cpu().numpy()
        scores = {}

        def cb(it, verts):
            if it in RECORD[kind]:
                v = verts.detach().double().cpu().numpy()
                scores[it] = [surface_score(pts[b], v[b], state["subset"]) for b in range(len(v))]

        res = keep(body, points, probs, init, config, cb, **kw)
        state["scores"], state["final"] = scores, res.vertices.detach().double().cpu().numpy()
        state["final_score"] = [surface_score(p, v, state["subset"]) for p, v in zip(pts, state["final"])]
        return res

    fit_prepared, try_swaps = api.Fitter.fit_prepared, api.try_swaps

    def fit_prepared_rec(self, items):
        state.update(center=items[0]["center"], subset=self.subset, armed=kind == "second")
        return fit_prepared(self, items)

    def try_swaps_rec(body, points, fit, subset, tries, *a, **k):
        state.update(armed=True, fit_verts=fit["vertices"].detach().double().cpu().numpy())
        res = try_swaps(body, points, fit, subset, tries, *a, **k)
        state.update(armed=False, swaps=res)
        return res

    api.Fitter.fit_prepared, api.try_swaps = fit_prepared_rec, try_swaps_rec
    if kind == "second":
        api.refine = refine
    else:
        refine_mod.refine = refine
    fitter = api.Fitter(device="cpu", anny=False, crossing=CrossingConfig(stop_at=-1))
    records = []
    for group, name, points, truth in bodies(which):
        for k in ("scores", "final", "swaps"):
            state.pop(k, None)
        r = fitter.fit_points(points, name=name)
        rec = {"group": group, "name": name, "status": r.status}
        if r.vertices is not None:
            rec["v2v"] = float(np.linalg.norm(r.vertices - truth, axis=1).mean() * 100)

        def v2v(v, truth=truth):
            return float(np.linalg.norm(v + state["center"] - truth, axis=1).mean() * 100)

        if kind == "second" and "final" in state and len(state["final"]) == 2:  # network, second start
            rec.update(rows=["network", "second"], final_score=state["final_score"],
                       v2v_rows=[v2v(v) for v in state["final"]])  # fmt: skip
        elif kind == "crossing" and state.get("swaps") and state["swaps"][0]["tried"]:
            sw = state["swaps"][0]
            rec.update(rows=list(sw["tried"]), final_score=[sw["tried"][p] for p in sw["tried"]],
                       fit_score=sw["score"], v2v_fit=v2v(state["fit_verts"][0]),
                       v2v_rows=[v2v(v) for v in state["final"]])  # fmt: skip
        if "rows" in rec:
            rec["scores"] = {str(k): v for k, v in state["scores"].items()}
        records.append(rec)
        print(json.dumps({k: rec[k] for k in ("group", "name", "status") if k in rec}), flush=True)
        Path(out).write_text(json.dumps({"kind": kind, "set": which, "records": records}, indent=0))


def _second_outcome(r: dict, rule) -> tuple[int, int]:
    """(start kept, iterations of the stopped start or 40) under ``rule`` [(iteration, margin)]."""
    full = int(r["final_score"][1] < r["final_score"][0])
    for k, m in rule:
        s = r["scores"][str(k)]
        if max(s) > min(s) * (1 + m) or m == 0:
            return int(np.argmin(s)), k
    return full, 40


def _crossing_pick(r: dict, alive: set, min_gain: float = 0.03) -> str:
    """``try_swaps``' pick among the starts ``alive`` (their final scores)."""
    fs = dict(zip(r["rows"], r["final_score"]))
    swaps = {p: v for p, v in fs.items() if p != "none" and p in alive and v < (1 - min_gain) * fs["none"]}
    if swaps:
        return min(swaps, key=swaps.get)
    return "none" if fs["none"] < r["fit_score"] else ""


def table_second(records: list[dict]) -> list[str]:
    lines = ["| rule (iteration: margin) | cost | picks changed | V2V change cm |",
             "|---|---:|---:|---|"]  # fmt: skip
    rules = [[(k, m)] for k in (8, 16, 24) for m in (0.0, 0.05, 0.1)]
    rules += [[(8, 0.1), (16, 0.02)], [(8, 0.1), (16, 0.02), (24, 0.0)], [(8, 0.1), (12, 0.05), (24, 0.0)],
              [(4, 0.15), (8, 0.1), (16, 0.02), (24, 0.0)]]  # fmt: skip
    for rule in rules:
        cost, changed = 0, []
        for r in records:
            kept, at = _second_outcome(r, rule)
            full = int(r["final_score"][1] < r["final_score"][0])
            cost += 40 + at
            if kept != full:
                changed.append(f"{r['name']} {r['v2v_rows'][kept] - r['v2v_rows'][full]:+.2f}")
        text = ", ".join(f"{k}: {m:.0%}" for k, m in rule)
        lines.append(f"| {text} | {cost / (80 * len(records)):.2f} | {len(changed)} | {'; '.join(changed)} |")
    return lines


def table_crossing(records: list[dict]) -> list[str]:
    lines = ["| swaps stop at (iteration: margin over none) | cost | picks changed | V2V change cm |",
             "|---|---:|---:|---|"]  # fmt: skip
    for k, m in itertools.product((2, 4, 6, 8, 10, 12), (0.0, 0.05, 0.1)):
        cost = full_cost = 0
        changed = []
        for r in records:
            s = dict(zip(r["rows"], r["scores"][str(k)]))
            alive = {p for p in r["rows"] if p == "none" or s[p] <= s["none"] * (1 + m)}
            cost += 30 * len(alive) + k * (len(r["rows"]) - len(alive))
            full_cost += 30 * len(r["rows"])
            a, b = _crossing_pick(r, set(r["rows"])), _crossing_pick(r, alive)
            if a != b:
                va = r["v2v_fit"] if a == "" else r["v2v_rows"][r["rows"].index(a)]
                vb = r["v2v_fit"] if b == "" else r["v2v_rows"][r["rows"].index(b)]
                changed.append(f"{r['name']} {a or 'fit'} -> {b or 'fit'} {vb - va:+.2f}")
        lines.append(f"| {k}: {m:.0%} | {cost / full_cost:.2f} | {len(changed)} | {'; '.join(changed)} |")
    return lines


def main() -> None:
    if len(sys.argv) >= 5 and sys.argv[1] == "record":
        record(sys.argv[2], sys.argv[3], sys.argv[4])
        return
    if len(sys.argv) < 3 or sys.argv[1] not in ("second", "crossing"):
        raise SystemExit(__doc__)
    for f in sys.argv[2:]:
        d = json.loads(Path(f).read_text())
        recs = [r for r in d["records"] if "rows" in r]
        print(f"\n{f}: {d['set']}, {len(recs)} scans with several starts\n")
        print("\n".join((table_second if sys.argv[1] == "second" else table_crossing)(recs)))


if __name__ == "__main__":
    main()
