"""The second-person test's values (``Fitter._second_person``, QualityThresholds.person_*), on scans it must
refuse and on fits it must not, with every threshold at 0 (the fit's coverage gate too) so that each group
off a fit is fitted alone and its values printed: the fit's coverage, the group, and the group's own fit
(status, inliers, coverage, surface ratio, tube share, |beta|, flags):

    OMP_NUM_THREADS=1 python experiments/fitting/second_person/probe.py pairs > pairs.log
    OMP_NUM_THREADS=1 python experiments/fitting/second_person/probe.py limbs > limbs.log

``pairs``: an adult and a child (2-8 y) standing side by side on one floor, 0.3 or 0.45 m between their
pelvises (they touch), seeds 0-3, 3500 + 1500 points. ``limbs``: two adults and two children (6-12 y)
standing, each fitted, then the fit's left leg swung 100 degrees forward, the right leg 70 degrees sideways,
the left arm 80 degrees down, or both legs forward (a lost limb's group: a limb's points off the fit), the
check's values recomputed for that fit and the test run on it.
"""

import copy
import sys
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import user_scans as us  # noqa: E402

import arteq.fit.api as api  # noqa: E402
from arteq.fit import Fitter  # noqa: E402
from arteq.fit.quality import QualityThresholds, fit_quality  # noqa: E402

torch.set_num_threads(1)
people = us.People()
zero = QualityThresholds(person_min_coverage=0.0, person_inliers=0.0, person_coverage=0.0, person_ratio=0.0)
f = Fitter(anny=False, ckpt="anny_scan", device="cpu", points=5000, hands=False, thresholds=zero)
KEYS = ("inlier_frac", "coverage", "surface_ratio", "tube_frac", "max_abs_beta", "extent_m", "flags")
seen: dict = {}
fit_batch = api.Fitter._fit_batch


def spy(self, items):
    """The fitter's batch fit, keeping the values of a group's own fit."""
    res, ex = fit_batch(self, items)
    if items and items[0]["name"].endswith("(points off its fit)"):
        q2 = res[0].quality or {}
        seen.update(status=res[0].status, q2={k: round(v, 3) if isinstance(v, float) else v
                                              for k, v in q2.items() if k in KEYS})  # fmt: skip
    return res, ex


api.Fitter._fit_batch = spy


def show(name: str, r) -> None:
    q = r.quality or {}
    group = (f"fit coverage {q.get('coverage', 0):.3f}, group {q.get('off_group_frac', 0):.3f} of the "
             f"points, {q.get('off_group_cm', 0):.0f} cm")  # fmt: skip
    print(f"{name}: {group} |", seen.pop("status", None), seen.pop("q2", None), flush=True)


def pairs() -> None:
    for seed in (0, 1, 2, 3):
        for gap in (0.3, 0.45):
            rng = np.random.default_rng(100 + seed)
            adult = people.person(people.sample(1, (25.0, 50.0), 900 + seed)[0])
            child = people.person(people.sample(1, (2.0, 8.0), 950 + seed)[0])
            rot, off = us.z_up_heading(rng), rng.uniform(-2, 2, 3)
            side = rot @ np.array([1.0, 0.0, 0.0])
            stand = us.EVERYDAY["stand"]
            va, _ = people.posed(adult, us.pose_from_template(stand, rng), rot, off)
            vc, _ = people.posed(child, us.pose_from_template(stand, rng), rot, off + gap * side)
            vc[:, 2] += va[:, 2].min() - vc[:, 2].min()
            pts = np.concatenate([us.surface_scan(va, people.faces, 3500, rng),
                                  us.surface_scan(vc, people.faces, 1500, rng)])  # fmt: skip
            show(f"pair seed {seed}, gap {gap} m, child {np.ptp(vc[:, 2]):.2f} m", f.fit_points(pts))


def limbs() -> None:
    swings = {"left leg forward": [(1, [-100, 0, 0])], "right leg sideways": [(2, [0, 0, 70])],
              "left arm down": [(16, [0, 0, 80])],
              "both legs forward": [(1, [-100, 0, 0]), (2, [-100, 0, 0])]}  # fmt: skip
    dt = f.body.v_template.dtype
    for k in range(4):
        rng = np.random.default_rng(30 + k)
        person = people.person(people.sample(1, (25.0, 50.0) if k < 2 else (6.0, 12.0), 910 + k)[0])
        pose0 = us.pose_from_template(us.EVERYDAY["stand"], rng)
        v, _ = people.posed(person, pose0, us.z_up_heading(rng), np.zeros(3))
        item = f.prepare(us.surface_scan(v, people.faces, 5000, rng), name="one")
        base = f.fit_prepared([item])[0]
        seen.clear()
        for name, turns in swings.items():
            pose = roma.rotvec_to_rotmat(torch.as_tensor(base.pose_aa, dtype=torch.float64))
            for j, deg in turns:
                pose[j] = pose[j] @ roma.rotvec_to_rotmat(torch.tensor(np.deg2rad(deg), dtype=torch.float64))
            with torch.no_grad():
                out = f.body(betas=torch.as_tensor(base.betas)[None].to(dt), pose=pose[None].to(dt),
                             transl=torch.as_tensor(base.transl_m)[None].to(dt))  # fmt: skip
            verts = out.vertices[0].double().numpy()
            pts = base.scan_points.astype(np.float64) * base.scale_to_m
            r = copy.copy(base)
            r.quality = fit_quality(pts, verts, f.vertex_parts, f.subset, base.betas, None, f.thresholds,
                                    item["conditions"])  # fmt: skip
            r.vertices, r.status = (verts / base.scale_to_m).astype(np.float32), "uncertain"
            f._second_person([item], [r])
            show(f"{'adult' if k < 2 else 'child'} {k}, {name}", r)


{"pairs": pairs, "limbs": limbs}[sys.argv[1]]()
