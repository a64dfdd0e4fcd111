"""Mixed precision (``trainer.precision=bf16-mixed``) on CPU: float32 where it matters, no NaN, and
group equivariance within a stated bound.

Bound (tiny network, 128 points, 4 group rotations x 4 clouds; docs/training.md): under bfloat16
autocast the error of ``f(R x) = R f(x)`` on part rotations is at most 1 deg on average and 0.1 deg
median (measured 0.16 deg / 0.005 deg at initialisation, 0.20 / 0.013 after 200 bf16 steps), the fitted
vertices move at most 3 mm on average (measured 1.0 mm); in float32 the same error is below 0.05 deg.
For scale, bfloat16 itself moves the prediction for the *same* cloud by about 1 deg (median) and 6-12 mm.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest
import torch

from arteq.equivariant import group_rotations
from arteq.geometry.rotations import geodesic_deg
from arteq.training.module import ArtEqModule

#: Beyond the tiny presets: 128 points, every step logged and trained, bfloat16.
BF16 = ["data.num_points=128", "data.val_size=2", "data.test_size=2", "~trainer.limit_train_batches",
        "trainer.log_every_n_steps=1", "trainer.precision=bf16-mixed", "model.optimizer.lr=3e-3"]  # fmt: skip


@pytest.fixture(scope="module")
def clouds():
    from arteq.data import BodyScanDataModule

    dm = BodyScanDataModule(body_model={"name": "anny22"}, num_points=128, train_size=4, batch_size=4,
                            num_workers=0, cache=False)  # fmt: skip
    dm.setup("fit")
    return next(iter(dm.train_dataloader()))["points"]


def equivariance_errors(module: ArtEqModule, points: torch.Tensor, bf16: bool) -> dict[str, float]:
    """Errors of f(R x) = R f(x) over 4 group rotations: part rotations (deg) and vertices (mm)."""
    rot, verts = [], []
    with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
        a = module(points)
    for k in ("global_rotmats", "local_rotmats", "vertices", "joints", "transl", "part_probs"):
        assert a[k].dtype == torch.float32, (k, a[k].dtype)  # full-precision islands
    for e in (1, 15, 29, 43):
        r = group_rotations()[e]
        rotated = points @ r.T  # outside autocast: a bf16 product here would round the input itself
        with torch.no_grad(), torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
            b = module(rotated)
        rot.append(geodesic_deg(b["global_rotmats"].double(), (r @ a["global_rotmats"]).double()).flatten())
        verts.append((b["vertices"] - a["vertices"] @ r.T).norm(dim=-1).mean(-1) * 1000)
    rot_all = torch.cat(rot)
    return {"rot_mean": rot_all.mean().item(), "rot_median": rot_all.median().item(),
            "rot_max": rot_all.max().item(), "v2v_mm": torch.cat(verts).mean().item()}  # fmt: skip


def _check_bf16_bounds(err: dict[str, float]) -> None:
    assert err["rot_mean"] < 1.0 and err["rot_median"] < 0.1 and err["v2v_mm"] < 3.0, err


def test_bf16_autocast_keeps_float32_islands_and_equivariance(clouds, tiny_net):
    torch.manual_seed(0)
    module = ArtEqModule(net=tiny_net, body_model={"name": "anny22"}, stage=2).eval()
    assert equivariance_errors(module, clouds, bf16=False)["rot_max"] < 0.05
    _check_bf16_bounds(equivariance_errors(module, clouds, bf16=True))


def _train_bf16(tiny_config, tmp_path: Path, steps: int) -> tuple[list[float], dict]:
    from arteq.train import train

    cfg = tiny_config("+experiment=stage1", *BF16, f"data.train_size={2 * steps}",
                      f"paths.output_dir={tmp_path / 'r'}",
                      f"data.cache_root={tmp_path / 'cache'}")  # fmt: skip
    summary = train(cfg)
    rows = list(csv.DictReader(open(tmp_path / "r" / "csv" / "metrics.csv")))
    losses = [float(r["train/loss"]) for r in rows if r.get("train/loss")]
    assert len(losses) == steps
    assert all(math.isfinite(x) for x in losses)
    for split in ("test_id", "test_ood"):
        assert all(math.isfinite(v) for v in summary["metrics"][split].values() if isinstance(v, float))
    state = torch.load(summary["last_ckpt"], weights_only=True)["state_dict"]
    assert all(torch.isfinite(v).all() for v in state.values())
    return losses, summary


def test_bf16_mixed_training_steps_are_finite(tmp_path, tiny_config):
    _train_bf16(tiny_config, tmp_path, steps=8)


@pytest.mark.slow
def test_bf16_mixed_few_hundred_steps_train_and_stay_equivariant(tmp_path, clouds, tiny_config):
    losses, summary = _train_bf16(tiny_config, tmp_path, steps=200)
    assert sum(losses[-20:]) / 20 < 0.75 * sum(losses[:20]) / 20  # it trains, not only survives
    module = ArtEqModule.load_from_checkpoint(summary["last_ckpt"], map_location="cpu", weights_only=True)
    _check_bf16_bounds(equivariance_errors(module.eval(), clouds, bf16=True))
