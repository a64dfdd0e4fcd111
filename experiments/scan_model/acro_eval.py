"""Acrobatic templates on many bodies: the network's part labels and the fit, per template.

The user-scan suite (experiments/fitting/user_scans.py) puts each of its 12 acrobatic templates on one body
per seed, so one lost scan moves its group's mean by centimetres. Here every template is scanned on
``--bodies`` bodies (anny's age-aware sampler, ages 4-80, seeds 9100+; not the suite's), each with its own
5-degree jitter, any orientation, 5000 points, 5 mm noise (user_scans.surface_scan), and fitted by
``arteq.fit.Fitter``:

- network only (``refine=False``, no clean-up, check, second start or crossed-limb step): part accuracy
  of the labels the fitter's network gives the scan's points (truth: the part of the true mesh's vertex
  nearest each point, before noise) and V2V (mean vertex distance to the true mesh, cm);
- the torso's reading: the angle between the chordal means of the network's and the true global rotations of
  the pelvis and the three spine parts (the frame ``arteq.models.sides`` reads left and right in); above
  90 degrees the torso is read turned round, and every limb's side with it;
- with ``--fit``: the whole fitter with ``arteq-fit``'s defaults: V2V and status.

``--set acrobatic`` (default): the suite's 12 templates (check_calibration.ACROBATIC). ``--set bends``:
:data:`BENDS`, six poses that bend the whole spine (yoga and gymnastics), written for this script after the
``athletic_spine`` training source (2026-12-07) and used for nothing else: a held-out check of that source
that its design did not see.

    OMP_NUM_THREADS=1 python experiments/scan_model/acro_eval.py --ckpt CKPT [--bodies 8] [--fit] \
        [--retries K] [--crossing KEY=VALUE ...] [--fit-seed S] [--json OUT.json] [--templates bow,pike]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "fitting"))

from check_calibration import ACROBATIC  # noqa: E402
from user_scans import People, pose_from_template, random_rotation, surface_scan  # noqa: E402

#: Whole-spine bends (intrinsic XYZ degrees as check_calibration.ACROBATIC: spine x < 0 extends, z bends
#: sideways; hip x < 0 flexes; knee x > 0 flexes; shoulder z > 0 raises, y > 0 takes the arm back; a left
#: joint without its right twin is mirrored; the shoulders default to the arms down).
BENDS: dict[str, dict[str, tuple[float, float, float]]] = {
    "camel": {"left_knee": (90, 0, 0), "left_hip": (15, 0, 5), "spine1": (-30, 0, 0), "spine2": (-25, 0, 0),
              "spine3": (-25, 0, 0), "neck": (-40, 0, 0), "left_shoulder": (0, 40, -60)},
    "cobra": {"left_hip": (10, 0, 5), "spine1": (-30, 0, 0), "spine2": (-25, 0, 0), "spine3": (-20, 0, 0),
              "neck": (-30, 0, 0), "left_shoulder": (0, -20, -70), "left_elbow": (0, -20, 0)},
    "plough": {"left_hip": (-145, 0, 5), "spine1": (40, 0, 0), "spine2": (35, 0, 0), "spine3": (30, 0, 0),
               "neck": (30, 0, 0)},
    "seated_fold": {"left_hip": (-120, 0, 5), "spine1": (40, 0, 0), "spine2": (35, 0, 0),
                    "spine3": (25, 0, 0), "neck": (25, 0, 0), "left_shoulder": (0, -90, -10)},
    "side_bend": {"spine1": (0, 0, 22), "spine2": (0, 0, 18), "spine3": (0, 0, 18), "neck": (0, 0, 20),
                  "left_shoulder": (0, 0, 160), "right_shoulder": (0, 0, -65)},
    "wheel": {"left_hip": (40, 0, 10), "left_knee": (90, 0, 0), "spine1": (-35, 0, 0), "spine2": (-30, 0, 0),
              "spine3": (-30, 0, 0), "neck": (-50, 0, 0), "left_shoulder": (0, 0, 170)},
}  # fmt: skip
SETS = {"acrobatic": ACROBATIC, "bends": BENDS}


def make_scans(bodies: int, templates: dict, seed: int = 9100) -> list[dict]:
    people = People()
    part_of = people.body.part_labels.numpy()
    rng = np.random.default_rng(seed)
    phens = people.sample(bodies, (4.0, 80.0), seed)
    persons = [people.person(p) for p in phens]
    scans = []
    for name, template in templates.items():
        for b, person in enumerate(persons):
            pose = pose_from_template(template, rng)
            rot, off = random_rotation(rng), rng.uniform(-2, 2, 3)
            v, _ = people.posed(person, pose, rot, off)
            with torch.no_grad():
                grot = (
                    rot @ people.body(betas=person["betas"][None], pose=pose[None]).global_rotmats[0].numpy()
                )
            clean = surface_scan(v, people.faces, 5000, rng, noise=0.0)
            nearest = cKDTree(v).query(clean)[1]
            pts = clean + rng.normal(0.0, 0.005, clean.shape)
            scans.append({"template": name, "body": b, "age": float(person["age_years"]), "points": pts,
                          "vertices": v, "labels": part_of[nearest], "grot": grot})  # fmt: skip
    return scans


def torso_error_deg(pred: np.ndarray, true: np.ndarray) -> float:
    """Angle (degrees) between the chordal means of two sets of global rotations ``[22, 3, 3]`` over the
    pelvis and the spine (:data:`arteq.models.sides.TORSO_PARTS`)."""
    import roma

    from arteq.models.sides import TORSO_PARTS

    idx = list(TORSO_PARTS)
    a = roma.special_procrustes(torch.as_tensor(pred[idx], dtype=torch.float64).sum(0))
    b = roma.special_procrustes(torch.as_tensor(true[idx], dtype=torch.float64).sum(0))
    return math.degrees(float(roma.rotmat_geodesic_distance(a, b)))


def evaluate(
    ckpt: str,
    scans: list[dict],
    fit: bool,
    threads: int,
    retries: int | None = None,
    crossing: tuple = (),
    fit_seed: int = 0,
) -> list[dict]:
    from arteq.fit import Fitter

    torch.set_num_threads(threads)
    net = Fitter(ckpt, refine=False, check=False, clean=False, second_start=False, crossing=False, anny=False)
    from arteq.fit.crossing import CrossingConfig

    cross = CrossingConfig.from_strings(list(crossing)) if crossing else True
    full = Fitter(ckpt, anny=False, retries=retries, crossing=cross, seed=fit_seed) if fit else None
    rows = []
    for s in scans:
        r = net.fit_points(s["points"])
        row = {
            "template": s["template"],
            "body": s["body"],
            "age": s["age"],
            "acc": float((r.point_labels == s["labels"]).mean()),
            "net_v2v_cm": float(np.linalg.norm(r.vertices - s["vertices"], axis=1).mean() * 100),
            "torso_err_deg": torso_error_deg(r.global_rotmats, s["grot"]),
        }
        if full is not None:
            t = time.perf_counter()
            f = full.fit_points(s["points"])
            row["fit_s"] = time.perf_counter() - t
            row["status"] = f.status
            if f.crossing:  # the crossed-limb step: the fit's score before it and what it took
                row["crossing"] = {"score_cm": f.crossing["score_cm"], "taken": f.crossing["taken"]}
            if f.retry:
                row["retry"] = {"scores_cm": f.retry["scores_cm"], "picked": f.retry["picked"]}
            row["v2v_cm"] = (
                float(np.linalg.norm(f.vertices - s["vertices"], axis=1).mean() * 100)
                if f.vertices is not None else float("nan")
            )  # fmt: skip
        rows.append(row)
    return rows


def summary(rows: list[dict]) -> str:
    fitted = "v2v_cm" in rows[0]
    head = "| template | n | part acc % | network V2V cm | torso read turned round (> 90 deg) |"
    out = [head + (" fit V2V cm mean / median / worst | > 5 cm |" if fitted else "")]
    out.append("|---|---:|---:|---:|---:|" + ("---|---:|" if fitted else ""))
    names = list(dict.fromkeys(r["template"] for r in rows)) + ["all"]
    for name in names:
        sel = [r for r in rows if name == "all" or r["template"] == name]
        line = f"| {name} | {len(sel)} | {100 * np.mean([r['acc'] for r in sel]):.1f} | "
        line += f"{np.mean([r['net_v2v_cm'] for r in sel]):.2f} | "
        line += f"{sum(r['torso_err_deg'] > 90 for r in sel)} |"
        if fitted:
            v = np.array([r["v2v_cm"] for r in sel])
            line += f" {np.nanmean(v):.2f} / {np.nanmedian(v):.2f} / {np.nanmax(v):.2f} | {(v > 5).sum()} |"
        out.append(line)
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--bodies", type=int, default=8)
    ap.add_argument("--set", choices=list(SETS), default="acrobatic")
    ap.add_argument("--templates", help="comma-separated names of the set (default: all)")
    ap.add_argument("--fit", action="store_true")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--retries", type=int, default=None, help="with --fit: Fitter(retries=...)")
    ap.add_argument("--crossing", nargs="*", default=[], metavar="KEY=VALUE",
                    help="with --fit: CrossingConfig fields")  # fmt: skip
    ap.add_argument("--fit-seed", type=int, default=0,
                    help="with --fit: Fitter(seed=...), the fitter's resampling of each scan")  # fmt: skip
    ap.add_argument("--json")
    a = ap.parse_args()
    t = time.perf_counter()
    templates = SETS[a.set]
    if a.templates:
        templates = {k: templates[k] for k in a.templates.split(",")}
    scans = make_scans(a.bodies, templates)
    rows = evaluate(a.ckpt, scans, a.fit, a.threads, a.retries, a.crossing, a.fit_seed)
    text = summary(rows)
    print(f"{a.ckpt}: {len(rows)} scans, {time.perf_counter() - t:.0f} s\n\n{text}")
    if a.json:
        Path(a.json).write_text(json.dumps({"ckpt": a.ckpt, "set": a.set, "rows": rows}, indent=1))


if __name__ == "__main__":
    main()
