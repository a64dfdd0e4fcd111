"""Probes of 2026-12-06 on single views (neither kept): run.py's default arm with one thing changed.

* ``unseen_identity``: the parts the network gave fewer points than the fitter calls seen (``MIN_PART_POINTS``
  of its first draw) start at their rest relation to their parent (local rotation = identity) instead of the
  network's guess; the pelvis, the hips, the spine and the neck keep theirs.
* ``mirror_gate``: the refinement's part gating (``allowed_parts``) also allows each allowed limb part's
  mirror twin, so the gated phase may match a point to either side.

    python experiments/single_view/hidden_parts_probe.py unseen_identity --arm refine_partial \\
        --ckpt anny_scan --scans 48 --splits front side back --threads 2 --out <dir>

(the arguments after the probe's name are run.py's; only partial scans should be run with ``mirror_gate``,
which patches the gating of full scans too).
"""

from __future__ import annotations

import runpy
import sys
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent


def unseen_identity() -> None:
    import arteq.fit.api as api

    place = api.Fitter._place_partial

    def patched(self, modes, net_in, pred, init):
        place(self, modes, net_in, pred, init)
        probs = pred["part_probs"]
        local = init["local_rotmats"].clone()
        for i in [i for i, m in enumerate(modes) if m["partial"]]:
            counts = torch.bincount(probs[i].argmax(-1), minlength=22)
            unseen = counts < max(api.MIN_PART_POINTS, api.MIN_PART_SHARE * probs.shape[1])
            unseen[[0, 1, 2, 3, 6, 9, 12]] = False  # pelvis, hips, spine and neck keep the network's
            local[i, unseen] = torch.eye(3, dtype=local.dtype)
        init["local_rotmats"] = local

    api.Fitter._place_partial = patched


def mirror_gate() -> None:
    import arteq.fit.refine as refine
    from arteq.models.sides import LEFT_PARTS, RIGHT_PARTS

    mirror = list(range(22))
    for left, right in zip(LEFT_PARTS, RIGHT_PARTS, strict=True):
        mirror[left], mirror[right] = right, left
    allowed = refine.allowed_parts

    def with_twins(probs, top=2, min_prob=0.2):
        a = allowed(probs, top, min_prob)
        return a | a[..., mirror]

    refine.allowed_parts = with_twins


if __name__ == "__main__":
    {"unseen_identity": unseen_identity, "mirror_gate": mirror_gate}[sys.argv[1]]()
    sys.argv = ["run.py", *sys.argv[2:]]
    runpy.run_path(str(HERE / "run.py"), run_name="__main__")
