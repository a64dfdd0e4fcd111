"""Where a trained network's part labels go wrong, and what the torso-frame side rule does to them.

    OMP_NUM_THREADS=1 .venv/bin/python experiments/articulated/sides_probe.py CKPT [--n 64] [--splits ...]

Per test set (random orientation, ``--n`` clouds, the project's cached sets): part accuracy as the network
outputs it; side-free accuracy (a point given the mirror part of its own counts as right); the errors split
into left/right swaps, tree neighbours (parent / child) and the rest; then the segmenter's raw 22-way
answer re-split by :func:`arteq.models.sides.resolve_sides` in the predicted torso frame and in the
ground-truth one (post hoc, no training), with the mean rotation error of the parts pooled with each.
Numbers: experiments/articulated/README.md, section 3c.
"""

from __future__ import annotations

import argparse
import copy

import roma
import torch
from hydra import compose, initialize_config_dir

from arteq.body.skeleton import JOINT_NAMES, PARENTS
from arteq.io import runs
from arteq.models.sides import LEFT_PARTS, RIGHT_PARTS, TORSO_PARTS, resolve_sides, torso_frame
from arteq.paths import conf_dir
from arteq.results import TEST_SPLITS
from arteq.training.build import build_datamodule

K = len(JOINT_NAMES)


def mirror_table() -> torch.Tensor:
    m = torch.arange(K)
    m[list(LEFT_PARTS)], m[list(RIGHT_PARTS)] = torch.tensor(RIGHT_PARTS), torch.tensor(LEFT_PARTS)
    return m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("ckpt")
    ap.add_argument("--n", type=int, default=64, help="clouds per test set")
    ap.add_argument("--splits", nargs="+", default=list(TEST_SPLITS))
    ap.add_argument("--per-part", action="store_true", help="also each part's accuracy per set")
    ap.add_argument("--confusions", type=int, default=0, help="also the N most frequent (true -> predicted)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    module = runs.load_module(args.ckpt)
    net = module.net
    with initialize_config_dir(str(conf_dir()), version_base="1.3"):
        cfg = compose(
            "eval", overrides=[f"ckpt_path={args.ckpt}", "data.eval_augment=so3", f"data.test_size={args.n}"]
        )
    dm = build_datamodule(cfg, body=copy.deepcopy(module.body), net=module.hparams.net)
    dm.prepare_data()
    dm.setup("test")
    mirror = mirror_table()
    adj = torch.zeros(K, K, dtype=torch.bool)
    for k, p in enumerate(PARENTS):
        if p >= 0:
            adj[k, p] = adj[p, k] = True
    print(f"# {args.ckpt} (sides: {getattr(net, 'sides', 'learned')})\n")
    print(
        "| set | part acc % | side-free % | swaps / tree nbr / other (% of errors) | rot err deg "
        "| side rule, pred torso: acc % / rot deg | side rule, GT torso: acc % / rot deg |"
    )
    print("|---|---:|---:|---|---:|---|---|")
    for split in args.splits:
        loader = torch.utils.data.DataLoader(dm.fixed_set(split), batch_size=8)
        s = dict.fromkeys(
            ("n", "ok", "free", "swap", "nbr", "rot", "ok_p", "rot_p", "ok_g", "rot_g", "b"), 0.0
        )
        hits, count = torch.zeros(K), torch.zeros(K)
        conf = torch.zeros(K * K)
        for batch in loader:
            pts, gt, grot = batch["points"], batch["labels"], batch["global_rotmats"]
            with torch.no_grad():
                out = net(pts, fps_idx=batch.get("fps_idx"))
                feats = net.backbone(pts, fps_idx=batch.get("fps_idx"))
                raw = net.segmenter(net.segmenter.invariant(feats))
                pred = out["seg_logits"].argmax(-1)
                wrong = pred != gt
                s["n"] += gt.numel()
                s["ok"] += (~wrong).sum().item()
                count += torch.bincount(gt.flatten(), minlength=K)
                hits += torch.bincount(gt[~wrong], minlength=K)
                conf += torch.bincount((gt * K + pred)[wrong], minlength=K * K)
                s["free"] += ((~wrong) | (pred == mirror[gt])).sum().item()
                s["swap"] += (wrong & (pred == mirror[gt])).sum().item()
                s["nbr"] += (wrong & adj[gt, pred]).sum().item()
                s["rot"] += roma.rotmat_geodesic_distance(out["global_rotmats"], grot).mean().item()
                probs = raw.softmax(-1)
                torso_pred = net._pose(feats, pts, probs, parts=TORSO_PARTS)["rotmats"]
                for key, rt in (("p", torso_pred), ("g", grot[:, list(TORSO_PARTS)])):
                    centre, left = torso_frame(pts, probs, rt)
                    logp = resolve_sides(raw, pts, centre, left, getattr(net, "side_scale", 0.02))
                    s["ok_" + key] += (logp.argmax(-1) == gt).sum().item()
                    rot = net._pose(feats, pts, logp.exp())["rotmats"]
                    s["rot_" + key] += roma.rotmat_geodesic_distance(rot, grot).mean().item()
            s["b"] += 1
        err = s["n"] - s["ok"]

        def pct(key: str, s: dict = s) -> float:
            return 100 * s[key] / s["n"]

        def deg(key: str, s: dict = s) -> float:
            return float(torch.rad2deg(torch.tensor(s[key] / s["b"])))

        print(
            f"| {split} | {pct('ok'):.1f} | {pct('free'):.1f} | {100 * s['swap'] / err:.0f} / "
            f"{100 * s['nbr'] / err:.0f} / {100 * (err - s['swap'] - s['nbr']) / err:.0f} | {deg('rot'):.1f} "
            f"| {pct('ok_p'):.1f} / {deg('rot_p'):.1f} | {pct('ok_g'):.1f} / {deg('rot_g'):.1f} |",
            flush=True,
        )
        if args.confusions:
            top = conf.topk(args.confusions)
            pairs = [f"{JOINT_NAMES[i // K]} -> {JOINT_NAMES[i % K]} {100 * v / s['n']:.1f} %"
                     for v, i in zip(top.values.tolist(), top.indices.tolist())]  # fmt: skip
            print(f"<!-- {split} most frequent errors (share of all points): " + ", ".join(pairs) + " -->")
        if args.per_part:
            acc = 100 * hits / count.clamp(min=1)
            print(
                f"<!-- {split} per part: "
                + ", ".join(f"{n} {a:.0f}" for n, a in zip(JOINT_NAMES, acc))
                + " -->"
            )


if __name__ == "__main__":
    main()
