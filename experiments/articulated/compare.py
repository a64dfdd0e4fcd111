"""Controlled comparisons for articulated equivariance (issue: backbone locality, parent conditioning,
wider training poses): every arm trains the same stage-1 schedule with the same seed and data, then is
tested on every test set (ID, hard OOD, the graded OOD scale).

    OMP_NUM_THREADS=1 .venv/bin/python experiments/articulated/compare.py ARM [ARM ...] [--steps 500]
    .venv/bin/python experiments/articulated/compare.py --table          # the table of every finished arm

Each arm is one ``python -m arteq.train +experiment=stage1`` run under ``outputs/compare/<arm>/`` (its
``metrics.json``); ``--table`` prints the Markdown table of the arms found there (and writes
``experiments/articulated/compare.md``). The arms are the overrides in ``ARMS`` on top of ``COMMON``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
OUT = ROOT / "outputs" / "compare"

OLD_BACKBONE = [
    "model.net.backbone.radii=[0.253,0.3573,0.506,0.506]", "model.net.backbone.strides=[2,1,2,1]",
    "model.net.backbone.neighbours=[32,16,32,16]", "model.net.backbone.normalize=false",
    # the default network's head and loss as these arms ran (the default now has torso sides and group_ce 1)
    "model.net.sides=learned", "model.loss_weights.group_ce=0.0",
]  # fmt: skip
# model=arteq_local as first screened (before its geometry tokens, group cross-entropy and torso-frame sides
# became its defaults)
LOCAL = ["model=arteq_local", "model.net.pose_head.geometry=false", "model.loss_weights.group_ce=0.0",
         "model.net.sides=learned"]  # fmt: skip
ARMS: dict[str, list[str]] = {
    # the configuration the shipped anny22 model has (radii scaled to 500 points, plain sums, aligned parent)
    "old": [*OLD_BACKBONE, "model.net.parent_conditioning=aligned", "model.net.pose_head.logit_eps=null"],
    # the same with the bounded logit standardisation of the new pose head (isolates the backbone)
    "old_eps": [*OLD_BACKBONE, "model.net.parent_conditioning=aligned", "model.net.pose_head.logit_eps=1e-4"],
    # the part-local network (model=arteq_local: metric radii, neighbour means, 250 deep centres, logit_eps)
    # with each parent conditioning
    "local_aligned": [*LOCAL, "model.net.parent_conditioning=aligned"],
    "local_invariant": [*LOCAL, "model.net.parent_conditioning=invariant"],
    "local_none": [*LOCAL, "model.net.parent_conditioning=none"],
    # + widened everyday training poses (half the training draws)
    "local_invariant_wide": [
        *LOCAL,
        "model.net.parent_conditioning=invariant",
        "data.wide_poses=0.5",
    ],
    # smaller balls
    "small_invariant": [
        *LOCAL,
        "model.net.parent_conditioning=invariant",
        "model.net.backbone.radii=[0.06,0.08,0.11,0.11]",
    ],
    # + the part's point distribution seen from each group element in every pose-head token
    # (pose_head.geometry, arteq.models.heads.part_geometry)
    "local_invariant_geo": [
        *LOCAL,
        "model.net.parent_conditioning=invariant",
        "model.net.pose_head.geometry=true",
    ],
    "old_geo": [
        *OLD_BACKBONE,
        "model.net.parent_conditioning=aligned",
        "model.net.pose_head.logit_eps=null",
        "model.net.pose_head.geometry=true",
    ],
    # + the anchor cross-entropy on the pose head's group weights (loss_weights.group_ce)
    "local_invariant_ce": [
        *LOCAL,
        "model.net.parent_conditioning=invariant",
        "model.loss_weights.group_ce=1.0",
    ],
    "local_invariant_geo_ce": [
        *LOCAL,
        "model.net.parent_conditioning=invariant",
        "model.net.pose_head.geometry=true",
        "model.loss_weights.group_ce=1.0",
    ],
    # parent conditioning on the head of model=arteq_local as it is now (geometry tokens + group_ce)
    "local_aligned_geo_ce": [
        *LOCAL,
        "model.net.parent_conditioning=aligned",
        "model.net.pose_head.geometry=true",
        "model.loss_weights.group_ce=1.0",
    ],
    "local_none_geo_ce": [
        *LOCAL,
        "model.net.parent_conditioning=none",
        "model.net.pose_head.geometry=true",
        "model.loss_weights.group_ce=1.0",
    ],
    # model=arteq_local as it is now (= local_invariant_geo_ce) with the segmenter reading the max and the
    # spread over the group beside the mean (segmenter.group_pool)
    "local_invariant_geo_ce_stats": [
        *LOCAL,
        "model.net.parent_conditioning=invariant",
        "model.net.pose_head.geometry=true",
        "model.loss_weights.group_ce=1.0",
        "model.net.segmenter.group_pool=mean_max_std",
    ],
    "old_ce": [
        *OLD_BACKBONE,
        "model.net.parent_conditioning=aligned",
        "model.net.pose_head.logit_eps=null",
        "model.loss_weights.group_ce=1.0",
    ],
    # the old backbone with the invariant parent (isolates the backbone from the head)
    "old_invariant": [
        *OLD_BACKBONE,
        "model.net.parent_conditioning=invariant",
        "model.net.pose_head.logit_eps=1e-4",
    ],
}


def common(steps: int) -> list[str]:
    epochs = 2
    return [
        "+experiment=stage1", "seed=0", "data.seed=0", "data.augment=so3", "data.eval_augment=so3",
        f"data.train_size={steps * 8 // epochs}", f"trainer.max_epochs={epochs}", "data.batch_size=8",
        "data.val_size=32", "data.test_size=128", "mean_pose_baseline=false",
        "trainer.enable_progress_bar=false",
    ]  # fmt: skip


def run(arm: str, steps: int) -> None:
    out = OUT / arm
    if (out / "metrics.json").exists():
        print(f"{arm}: done already ({out})")
        return
    cmd = [sys.executable, "-m", "arteq.train", *common(steps), *ARMS[arm], f"hydra.run.dir={out}"]
    print(" ".join(cmd[1:]), flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)


def _recorded(path: Path) -> dict[str, dict[str, list[str]]]:
    """``{metric: {arm: cells}}`` of an existing compare.md (arms measured on another machine)."""
    got: dict[str, dict[str, list[str]]] = {}
    metric = None
    for line in path.read_text().splitlines() if path.is_file() else []:
        if line.startswith("**") and line.endswith("**"):
            metric = line.strip("*")
        elif metric and line.startswith("| ") and not line.startswith("| arm "):
            cells = [c.strip() for c in line.strip("|").split("|")]
            got.setdefault(metric, {})[cells[0]] = cells[1:]
    return got


def table(recorded: Path | None = None) -> str:
    """Every arm's test metrics: from its run under ``outputs/compare``, else its row in ``recorded``
    (the committed compare.md: arms whose run folders are not on this machine keep their rows)."""
    from arteq.results import METRIC_KEYS, SPLIT_LABELS, TEST_SPLITS

    old = _recorded(recorded) if recorded else {}
    rows = {}
    for arm in ARMS:
        f = OUT / arm / "metrics.json"
        if f.exists():
            rows[arm] = json.loads(f.read_text())["metrics"]
    if not rows and not old:
        return "no finished arm under " + str(OUT)
    out = []
    for m in METRIC_KEYS:
        out += [f"**{m}**", "", "| arm | " + " | ".join(SPLIT_LABELS[s] for s in TEST_SPLITS) + " |",
                "|---|" + "---:|" * len(TEST_SPLITS)]  # fmt: skip
        for arm in ARMS:
            if arm in rows:
                cells = [f"{rows[arm][s][m]:.2f}" if s in rows[arm] else "–" for s in TEST_SPLITS]
            elif arm in old.get(m, {}):
                cells = old[m][arm]
            else:
                continue
            out.append(f"| {arm} | " + " | ".join(cells) + " |")
        out.append("")
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("arms", nargs="*", help=f"any of {', '.join(ARMS)}")
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--table", action="store_true")
    args = ap.parse_args()
    unknown = [a for a in args.arms if a not in ARMS]
    if unknown:
        ap.error(f"unknown arms {unknown}; known: {', '.join(ARMS)}")
    for arm in args.arms:
        run(arm, args.steps)
    if args.table or not args.arms:
        path = ROOT / "experiments" / "articulated" / "compare.md"
        text = table(path)
        print(text)
        path.write_text(text + "\n")


if __name__ == "__main__":
    main()
