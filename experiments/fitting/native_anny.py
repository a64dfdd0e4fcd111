"""Scans of bodies posed on Anny's own rig (104 bones, Anny's own skinning), fitted through the public API.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/fitting/native_anny.py [--ckpt anny_scan] [--seed 0] \
        [--bodies 12] [--out experiments/fitting/native_anny/native_seed0.md] [--json ...] [--no-hands] \
        [--no-lost-hand] [--versions rig22,native,hands,spread]

Why: every other labelled scan of the project is drawn from the fitted body itself (``anny_allages``: Anny's
mesh, its rig folded to 22 parts, linear blend skinning on the baked T-pose). A user who has ``anny`` poses
the stock model: 104 bones, the twist bones of the arms and legs, five spine and three neck bones, fingers
and toes, Anny's own skinning weights from its A-pose. The fitter cannot represent all of that; this script
measures what it costs. Each body (anny's age-aware sampler, ages 3-90, a seed of its own; the phenotype
itself, not its projection on the body's components) in an everyday template pose (user_scans.EVERYDAY) is
scanned in four versions, the same body, pose, orientation and scanning seed:

- ``rig22``: the body's own rig, as in the user-scan suite (its truth: the phenotype's T-pose projected on
  anny_allages' 32 stored components and posed by the fitted body's LBS);
- ``native``: the stock Anny model posed with the same 22 rotations (every folded bone follows its part:
  :func:`arteq.body.anny_rig.anny_deltas_from_pose`), Anny's own skinning;
- ``hands``: ``native`` with the fingers curled (each finger joint 20-80 deg towards the palm, the thumb half
  that) and the toes 0-20 deg: a relaxed or closed hand, which the body's rigid hand part cannot bend;
- ``spread``: ``native`` with ``hands``' fingers and toes and the folded bones moved as a body moves them:
  the forearms' and upper arms' twist bones turned 0-45 deg about their own axis, the lower spine bones
  (spine05, spine04) and the upper neck bones (neck02, neck03) bent up to 12 deg each about random axes,
  the clavicles' ``shoulder01`` bones 0-10 deg.

Truth per version: its own mesh (Anny's topology, the fitted body's) and joints (``rig22``: the body's; the
others: Anny's bone heads, which the body's regressor matches within ~5 mm on the rest pose). Columns: V2V
(mean vertex distance; also without the hands, a quarter of the vertices, and of the hands alone), Chamfer
(symmetric nearest-vertex distance; usable <= 3 cm), the 15-joint error and the stature error of the Anny
export against the phenotype's own stature. Points: 5000, 5 mm noise, non-uniform density, any orientation
(user_scans.surface_scan).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import roma
import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))

from user_scans import (  # noqa: E402
    EVERYDAY,
    People,
    Scan,
    joint_error_cm,
    measurement_errors,
    pose_from_template,
    random_rotation,
    surface_distance_cm,
    surface_scan,
)

from arteq.body.skeleton import JOINT_NAMES  # noqa: E402

VERSIONS = ("rig22", "native", "hands", "spread")
#: the parts whose vertices are the hands (a quarter of Anny's 13 718 vertices: 1596 each)
HANDS = ("left_wrist", "right_wrist")


def _rot(axis: np.ndarray, deg: float) -> torch.Tensor:
    """Rotation ``[3, 3]`` (float64) by ``deg`` about ``axis``."""
    a = torch.as_tensor(axis, dtype=torch.float64)
    return roma.rotvec_to_rotmat(a / a.norm() * np.deg2rad(deg))


class NativeAnny:
    """Stock-Anny meshes of a phenotype in a 22-joint pose, with the extra bone motions of ``hands`` and
    ``spread`` (module docstring)."""

    def __init__(self, people: People) -> None:
        from arteq.body import anny_rig

        self.rig = anny_rig
        self.model = people.ex.model  # anny_rig.load_anny(): local-ref, no reference orientations
        self.bake = people.ex.bake
        self.C = torch.as_tensor(anny_rig.ANNY_TO_SMPL, dtype=torch.float64)
        self.labels = list(self.model.bone_labels)
        self.idx = {b: i for i, b in enumerate(self.labels)}
        self.parents = list(self.model.bone_parents)
        self.children: dict[int, list[int]] = {}
        for i, p in enumerate(self.parents):
            self.children.setdefault(p, []).append(i)
        self.body = people.body

    def _rest_heads(self, kw: dict) -> torch.Tensor:
        """Bone heads ``[n_bones, 3]`` of the phenotype in Anny's rest pose (A-pose, Anny axes)."""
        eye = {"root": torch.eye(4, dtype=torch.float64)[None]}
        return self.model(pose_parameters=eye, phenotype_kwargs=kw)["bone_poses"][0, :, :3, 3]

    def _axis(self, heads: torch.Tensor, bone: str) -> np.ndarray:
        """A bone's own direction at rest: its head to its first child's head."""
        i = self.idx[bone]
        return (heads[self.children[i][0]] - heads[i]).numpy()

    def extras(self, kw: dict, version: str, rng: np.random.Generator) -> dict[int, torch.Tensor]:
        """``{bone index: rotation [3, 3]}`` right-multiplied onto the bones' local-ref deltas."""
        if version in ("rig22", "native"):
            return {}
        heads = self._rest_heads(kw)
        out: dict[int, torch.Tensor] = {}
        for s in ("L", "R"):
            # across the palm (index -> little finger knuckles); the palm's normal towards the midline
            across = (heads[self.idx[f"finger5-1.{s}"]] - heads[self.idx[f"finger2-1.{s}"]]).numpy()
            along = (heads[self.idx[f"finger3-1.{s}"]] - heads[self.idx[f"wrist.{s}"]]).numpy()
            normal = np.cross(along, across)
            midline = -heads[self.idx[f"wrist.{s}"]].numpy() * np.array([1.0, 0.0, 0.0])
            if normal @ midline < 0:
                normal = -normal
            # curl: the finger's tip (along) turned towards the palm (normal): about along x normal
            curl_axis = np.cross(along, normal)
            for f in range(1, 6):
                top = rng.uniform(20.0, 80.0) * (0.5 if f == 1 else 1.0)
                for k in range(1, 4):
                    out[self.idx[f"finger{f}-{k}.{s}"]] = _rot(curl_axis, top * rng.uniform(0.7, 1.0))
            for t in range(1, 6):
                for k in range(1, 4):
                    name = f"toe{t}-{k}.{s}"
                    if name in self.idx:
                        out[self.idx[name]] = _rot(np.array([1.0, 0.0, 0.0]), rng.uniform(0.0, 20.0))
            if version == "spread":
                for bone in (f"upperarm02.{s}", f"lowerarm02.{s}"):
                    out[self.idx[bone]] = _rot(self._axis(heads, bone), rng.uniform(-45.0, 45.0))
                out[self.idx[f"shoulder01.{s}"]] = _rot(rng.normal(size=3), rng.uniform(0.0, 10.0))
        if version == "spread":
            for bone in ("spine05", "spine04", "neck02", "neck03"):
                out[self.idx[bone]] = _rot(rng.normal(size=3), rng.uniform(0.0, 12.0))
        return out

    def posed(self, phen: torch.Tensor, pose: torch.Tensor, version: str, rng: np.random.Generator):
        """Vertices ``[V, 3]`` (SMPL axes, metres) of the stock model and its 22 joints (Anny's bone heads,
        as :func:`arteq.body.anny_rig.anny_tpose` takes them), the vertices' centroid at the origin."""
        from arteq.fit.anny_params import PHENOTYPE_LABELS

        kw = {k: phen[i : i + 1].double() for i, k in enumerate(PHENOTYPE_LABELS)}
        deltas = self.rig.anny_deltas_from_pose(self.model, self.bake, pose[None].double())
        for b, r in self.extras(kw, version, rng).items():
            deltas[0, b, :3, :3] = deltas[0, b, :3, :3] @ r
        with torch.no_grad():
            out = self.model(pose_parameters=deltas, phenotype_kwargs=kw)
        v, j = self.rig._to_smpl(self.model, out["vertices"], out["bone_poses"][..., :3, 3])
        c = v[0].mean(0)
        return (v[0] - c).numpy(), (j[0] - c).numpy()


def native_scans(seed: int, bodies: int) -> list[Scan]:
    """``bodies`` people (a third children 3-12 y, the rest 18-90 y) x :data:`VERSIONS`."""
    people = People()
    native = NativeAnny(people)
    faces = people.faces
    rng = np.random.default_rng(9000 + seed)
    kids = max(1, bodies // 3)
    phens = [("child", p) for p in people.sample(kids, (3.0, 12.0), 9100 + seed)]
    phens += [("adult", p) for p in people.sample(bodies - kids, (18.0, 90.0), 9200 + seed)]
    everyday = list(EVERYDAY)
    scans = []
    for k, (kind, phen) in enumerate(phens):
        person = people.person(phen)
        pose_name = everyday[k % len(everyday)]
        pose = pose_from_template(EVERYDAY[pose_name], rng)
        rot, off, scan_seed, extra_seed = (
            random_rotation(rng),
            rng.uniform(-2, 2, 3),
            rng.integers(1 << 31),
            rng.integers(1 << 31),
        )
        truth = {k2: person[k2] for k2 in ("stature_m", "waist_circumference_m", "age_years")}
        for version in VERSIONS:
            if version == "rig22":
                v, j = people.posed(person, pose, np.eye(3), np.zeros(3))
                c = v.mean(0)
                v, j = v - c, j - c
            else:
                v, j = native.posed(phen, pose, version, np.random.default_rng(extra_seed))
            v, j = v @ rot.T + off, j @ rot.T + off
            pts = surface_scan(v, faces, 5000, np.random.default_rng(scan_seed))
            name = f"{kind} {person['age_years']:.0f} y, {pose_name} [{version}]"
            scans.append(Scan(version, name, pts, v, j, truth))
    return scans


def fit_native(fitter, scan: Scan, hands: np.ndarray, dump: str | None = None) -> dict:
    """Fit one scan: status, V2V (all vertices; the body without its hands, ``v2v_body_cm``; the hands
    alone, ``v2v_hands_cm``), Chamfer, 15-joint and stature error, as :func:`user_scans.fit_scan`; the fitted
    and true vertices written to ``dump`` if given."""
    r = fitter.fit_points(scan.points, name=scan.name)
    rec = {"group": scan.group, "name": scan.name, "status": r.status,
           "reason": r.uncertain_reason or r.message, "fit_s": r.timings.get("total")}  # fmt: skip
    q = r.quality or {}
    rec["check"] = {k: q[k] for k in ("inlier_frac", "coverage", "off_group_frac", "off_group_cm", "flags")
                    if k in q}  # fmt: skip
    if r.crossing:
        c = r.crossing
        rec["crossing"] = {"taken": c.get("taken", ""), "tried": sorted(c.get("tried_cm", {})),
                           "lost_hand": c.get("lost_hand")}  # fmt: skip
    if r.vertices is None:
        return rec
    v = r.vertices.astype(np.float64)
    e = np.linalg.norm(v - scan.vertices, axis=1) * 100
    parts = fitter.vertex_parts
    per_part = np.bincount(parts, weights=e, minlength=len(JOINT_NAMES)) / np.maximum(
        np.bincount(parts, minlength=len(JOINT_NAMES)), 1
    )
    worst = int(per_part.argmax())
    seen = int(r.part_points[worst]) if r.part_points is not None else -1  # the network's points of it
    rec["worst_part"] = {"name": JOINT_NAMES[worst], "cm": float(per_part[worst]), "net_points": seen}
    rec.update(v2v_cm=float(e.mean()), v2v_body_cm=float(e[~hands].mean()),
               v2v_hands_cm=float(e[hands].mean()),
               chamfer_cm=surface_distance_cm(v, scan.vertices),
               joints15_cm=joint_error_cm(r.joints.astype(np.float64), scan.joints))  # fmt: skip
    if r.anny:
        rec.update(measurement_errors(r.anny, scan.truth))
    if dump:
        Path(dump).mkdir(parents=True, exist_ok=True)
        stem = "".join(c if c.isalnum() else "_" for c in scan.name)
        np.savez(
            Path(dump) / f"{stem}.npz",
            fit=r.vertices,
            truth=scan.vertices,
            points=scan.points,
            fit_joints=r.joints,
            truth_joints=scan.joints,
        )
    return rec


def table(records: list[dict]) -> str:
    def f(x, signed=False):
        return "-" if x is None else (f"{x:+.2f}" if signed else f"{x:.2f}")

    versions = [v for v in VERSIONS if any(r["group"] == v for r in records)]
    by = {}
    for r in records:
        by.setdefault(r["name"].split(" [")[0], {})[r["group"]] = r
    head = "| body, pose | " + " | ".join(f"{v}: V2V (no hands) / J15 / stature" for v in versions) + " |"
    lines = [head, "|---|" + "---|" * len(versions)]
    for name, row in by.items():
        cells = []
        for v in versions:
            r = row.get(v, {})
            st = "" if r.get("status") == "ok" else f" ({r.get('status')})"
            v2v = f"{f(r.get('v2v_cm'))} ({f(r.get('v2v_body_cm'))})"
            cells.append(f"{v2v} / {f(r.get('joints15_cm'))} / {f(r.get('stature_err_cm'), True)}{st}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    summary = ["", "| version | V2V mean / median / worst cm | V2V without the hands, mean / worst "
               "| hands' V2V mean | Chamfer mean cm | 15-joint mean cm | "
               "|stature err| mean / worst cm | ok / uncertain / refused |",
               "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for v in versions:
        rs = [r for r in records if r["group"] == v]
        e = np.array([r["v2v_cm"] for r in rs if r.get("v2v_cm") is not None])
        eb = np.array([r["v2v_body_cm"] for r in rs if r.get("v2v_body_cm") is not None])
        eh = np.array([r["v2v_hands_cm"] for r in rs if r.get("v2v_hands_cm") is not None])
        ch = np.array([r["chamfer_cm"] for r in rs if r.get("chamfer_cm") is not None])
        jj = np.array([r["joints15_cm"] for r in rs if r.get("joints15_cm") is not None])
        st = np.abs([r["stature_err_cm"] for r in rs if r.get("stature_err_cm") is not None])
        n = {s: sum(r["status"] == s for r in rs) for s in ("ok", "uncertain")}
        refused = len(rs) - n["ok"] - n["uncertain"]
        summary.append(
            f"| {v} | {e.mean():.2f} / {np.median(e):.2f} / {e.max():.2f} | "
            f"{eb.mean():.2f} / {eb.max():.2f} | "
            f"{eh.mean():.2f} | {ch.mean():.2f} | {jj.mean():.2f} | "
            + (f"{st.mean():.2f} / {st.max():.2f}" if len(st) else "-")
            + f" | {n['ok']} / {n['uncertain']} / {refused} |"
        )
    return "\n".join(lines + summary)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ckpt", default="anny_scan")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--bodies", type=int, default=12)
    ap.add_argument("--versions", default=",".join(VERSIONS))
    ap.add_argument("--out", default=None)
    ap.add_argument("--json", default=None)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--dump", default=None, help="write each fit's and truth's vertices here (.npz)")
    ap.add_argument("--no-hands", action="store_true", help="Fitter(hands=False): the hands left flat")
    ap.add_argument("--no-lost-hand", action="store_true", help="CrossingConfig(lost_hand=False)")
    ap.add_argument("--export", default=None, help="write the scans here (.npz, points only) and stop")
    a = ap.parse_args(argv)
    torch.set_num_threads(a.threads)
    t0 = time.perf_counter()
    keep = set(a.versions.split(","))
    scans = [s for s in native_scans(a.seed, a.bodies) if s.group in keep]
    if a.export:
        out = Path(a.export)
        out.mkdir(parents=True, exist_ok=True)
        for i, s in enumerate(scans):
            np.savez(out / f"{i:03d}_{s.group}.npz", points=s.points.astype(np.float32))
        print(f"wrote {len(scans)} scans to {out}")
        return
    from arteq.fit import Fitter
    from arteq.fit.crossing import CrossingConfig

    crossing = CrossingConfig(lost_hand=not a.no_lost_hand)
    fitter = Fitter(ckpt=a.ckpt, device="cpu", points=5000, anny=True, hands=not a.no_hands,
                    crossing=crossing)  # fmt: skip
    hands = np.isin(fitter.body.lbs_weights.argmax(1).numpy(), [JOINT_NAMES.index(n) for n in HANDS])
    records = []
    for s in scans:
        rec = fit_native(fitter, s, hands, a.dump)
        records.append(rec)
        print(
            f"{rec['name']:46s} {rec['status']:15s} V2V {rec.get('v2v_cm', float('nan')):6.2f} "
            f"J15 {rec.get('joints15_cm', float('nan')):6.2f} fit {rec.get('fit_s') or 0:.2f} s",
            flush=True,
        )
    text = (
        f"# Bodies posed on Anny's own rig: {fitter.checkpoint_id}\n\n"
        f"```\nOMP_NUM_THREADS={a.threads} python "
        f"experiments/fitting/native_anny.py {' '.join(sys.argv[1:] if argv is None else argv)}\n```\n\n"
        f"{len(scans)} scans, {time.perf_counter() - t0:.0f} s.\n\n{table(records)}\n"
    )
    print("\n" + text)
    if a.out:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text)
    if a.json:
        Path(a.json).write_text(
            json.dumps({"checkpoint": fitter.checkpoint_id, "records": records}, indent=1, default=float)
        )


if __name__ == "__main__":
    main()
