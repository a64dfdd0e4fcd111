"""FPS computed in the data workers (``data.fps_points``): the same indices as the backbone's own, the same
network outputs, the same training run; clear errors for bad indices or settings."""

from __future__ import annotations

import pickle

import pytest
import torch

from arteq.data import BodyScanDataModule, FpsCollate
from arteq.data.datamodule import resolve_fps_points
from arteq.equivariant import EquivariantBackbone
from arteq.models import ArtEqNet
from conftest import compose_config


def _items(b: int, n: int, seed: int, scale: float = 1.0) -> list[dict[str, torch.Tensor]]:
    g = torch.Generator().manual_seed(seed)
    pts = (torch.randn(b, n, 3, generator=g) * scale).float()
    return [{"points": pts[i], "labels": torch.zeros(n, dtype=torch.long)} for i in range(b)]


@pytest.mark.parametrize(
    ("b", "n", "strides"), [(1, 200, (2, 1, 2, 1)), (4, 501, (2, 1, 2, 1)), (3, 300, (1, 3, 2))]
)
def test_collate_indices_equal_backbone_fps(b, n, strides):
    bb = EquivariantBackbone(channels=[4] * len(strides), strides=strides, radii=[0.3] * len(strides),
                             neighbours=[8] * len(strides), kernel="ico13")  # fmt: skip
    need = bb.fps_size(n)
    for seed in range(3):
        # clouds as the dataset makes them: float32, centred (plus a few exact ties: duplicated points)
        items = _items(b, n, seed, scale=0.5)
        items[0]["points"][: n // 10] = items[0]["points"][n // 10 : 2 * (n // 10)]
        for m in (need, n):  # more than needed: a prefix-consistent superset
            batch = FpsCollate(m)(items)
            assert batch["fps_idx"].shape == (b, m) and batch["fps_idx"].dtype == torch.long
            own = bb.compute_fps(batch["points"])
            assert torch.equal(batch["fps_idx"][:, :need], own)
            # per cloud: the same as the backbone on that cloud alone
            for i in range(b):
                assert torch.equal(FpsCollate(m)([items[i]])["fps_idx"][0], batch["fps_idx"][i])


def test_collate_is_picklable_and_checks_m():
    c = pickle.loads(pickle.dumps(FpsCollate(7)))
    assert c.m == 7
    with pytest.raises(ValueError, match="more than the 5 points"):
        FpsCollate(6)(_items(1, 5, 0))
    with pytest.raises(ValueError, match="int >= 1"):
        FpsCollate(0)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_network_outputs_bit_identical_with_batch_fps(dtype, tiny_net_200):
    torch.manual_seed(0)
    net = ArtEqNet(**tiny_net_200).to(dtype).eval()
    items = _items(3, 200, 1, scale=0.4)
    batch = FpsCollate(100)(items)
    with torch.no_grad():
        a = net(batch["points"])
        b = net(batch["points"], fps_idx=batch["fps_idx"])
    assert a.keys() == b.keys()
    for k in a:
        assert torch.equal(a[k], b[k]), k


def test_module_step_uses_batch_fps_and_gives_identical_losses(tiny_net_200):
    from arteq.training.module import ArtEqModule, batch_fps_idx

    dm = BodyScanDataModule(
        body_model={"name": "anny22"}, num_points=200, train_size=4, val_size=2, test_size=2, batch_size=2,
        cache=False, fps_points="auto", net=tiny_net_200,
    )  # fmt: skip
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["fps_idx"].shape == (2, 100)
    plain = {k: v for k, v in batch.items() if k != "fps_idx"}
    runs = []
    for b in (batch, plain):
        torch.manual_seed(0)
        module = ArtEqModule(net=tiny_net_200, body_model={"name": "anny22"}, stage=2)
        opt = torch.optim.Adam(module.net.parameters(), lr=1e-3)
        losses = []
        for _ in range(3):  # a few optimisation steps: identical losses and weights
            _, _, terms = module._step(b, use_gt_parts=False)
            opt.zero_grad()
            terms["loss"].backward()
            opt.step()
            losses.append(terms["loss"].detach())
        runs.append((torch.stack(losses), [p.detach().clone() for p in module.net.parameters()]))
    assert torch.equal(runs[0][0], runs[1][0])
    assert all(torch.equal(p, q) for p, q in zip(runs[0][1], runs[1][1]))
    # indices computed from float32 clouds are not used on converted (half-precision) points
    assert batch_fps_idx(batch) is batch["fps_idx"]
    assert batch_fps_idx({**batch, "points": batch["points"].bfloat16()}) is None
    assert batch_fps_idx(plain) is None


def test_bad_fps_idx_gives_clear_errors():
    bb = EquivariantBackbone(
        channels=[4, 4], strides=[2, 1], radii=[0.5, 0.5], neighbours=[8, 8], kernel="ico13"
    )
    pts = torch.randn(2, 40, 3)
    good = bb.compute_fps(pts)
    with pytest.raises(ValueError, match=r"fps_idx must be \[B=2, >=20\] for N=40"):
        bb(pts, fps_idx=good[:, :10])
    with pytest.raises(ValueError, match=r"fps_idx must be \[B=2"):
        bb(pts, fps_idx=good[:1])
    with pytest.raises(ValueError, match=r"fps_idx must be \[B=2"):
        bb(pts, fps_idx=good[0])
    with pytest.raises(ValueError, match="long"):
        bb(pts, fps_idx=good.int())
    bad = good.clone()
    bad[1, 3] = 40
    with pytest.raises(ValueError, match=r"indices in \[0, 40\), got values in \[0, 40\]"):
        bb(pts, fps_idx=bad)
    bad[1, 3] = -1
    with pytest.raises(ValueError, match=r"indices in \[0, 40\)"):
        bb(pts, fps_idx=bad)
    # extra columns are ignored (prefix-consistent FPS)
    torch.manual_seed(0)
    out = bb(pts, fps_idx=torch.cat([good, good], 1))
    assert torch.equal(out, bb(pts))


def test_resolve_fps_points():
    arteq = {"backbone": {"strides": [2, 1, 2, 1]}}
    assert resolve_fps_points(None, arteq, 5000) == 0
    assert resolve_fps_points(0, arteq, 5000) == 0
    assert resolve_fps_points("auto", arteq, 5000) == 2500
    assert resolve_fps_points("auto", {}, 5000) == 0  # no network known: off
    assert resolve_fps_points("auto", {"backbone": {"strides": [1, 3]}}, 500) == 166
    assert resolve_fps_points("auto", {"backbone": {"strides": [1, 1]}}, 500) == 0
    assert resolve_fps_points("auto", {"arch": "pointnet2"}, 5000) == 0
    assert resolve_fps_points(3000, arteq, 5000) == 3000
    with pytest.raises(ValueError, match="fewer than the 2500"):
        resolve_fps_points(1000, arteq, 5000)
    with pytest.raises(ValueError, match="only the ArtEq backbone"):
        resolve_fps_points(100, {"arch": "pointnet2"}, 5000)
    with pytest.raises(ValueError, match="null, auto or an int"):
        resolve_fps_points("yes", arteq, 5000)
    with pytest.raises(ValueError, match="more than data.num_points"):
        BodyScanDataModule(body_model={"name": "toy"}, num_points=100, fps_points=101)


def test_config_presets_and_validation():
    from arteq.training.build import build_datamodule
    from arteq.training.validate import ConfigError, validate_train_config

    cfg = compose_config(["+experiment=paper"], hydra_config=False)
    assert cfg.data.fps_points == "auto"
    assert build_datamodule(cfg, body=torch.nn.Module()).fps_points == 2500
    default = compose_config([], hydra_config=False)
    assert default.data.fps_points is None  # the CPU default: off (its outputs are unchanged anyway)
    validate_train_config(compose_config(["paths.output_dir=/tmp/unused", "+experiment=paper"]))
    bad = [["data.fps_points=-1"], ["data.fps_points=99999"], ["data.fps_points=many"],
           ["data.fps_points=100"], ["model=pointnet2", "data.fps_points=300"]]  # fmt: skip
    for overrides in bad:
        with pytest.raises(ConfigError, match="data.fps_points"):
            validate_train_config(compose_config(["paths.output_dir=/tmp/unused", *overrides]))


def test_datamodule_workers_yield_fps_idx(tmp_path):
    dm = BodyScanDataModule(
        body_model={"name": "toy"}, num_points=300, train_size=4, val_size=4, test_size=4, batch_size=2,
        num_workers=2, cache_root=str(tmp_path), fps_points="auto", net={"backbone": {"strides": [2, 1, 2]}},
    )  # fmt: skip
    dm.setup()
    bb = EquivariantBackbone(channels=[4] * 4, radii=[0.3] * 4, neighbours=[8] * 4, kernel="ico13")
    loaders = [dm.train_dataloader(), dm.val_dataloader(), *dm.test_dataloader()]
    for loader in loaders:
        assert loader.num_workers == 2
        n = 0
        for batch in loader:
            assert batch["fps_idx"].shape == (batch["points"].shape[0], 150)
            assert torch.equal(batch["fps_idx"], bb.compute_fps(batch["points"]))
            n += 1
        assert n == 2
    # the cached fixed sets keep their format (no fps key on disk)
    assert "fps_idx" not in dm.datasets["val"].tensors


def test_training_run_identical_with_and_without_worker_fps(tmp_path, monkeypatch, tiny_config):
    from arteq.train import train

    calls = []  # the network's own FPS: never run when the batches carry fps_idx
    own = EquivariantBackbone.compute_fps
    monkeypatch.setattr(EquivariantBackbone, "compute_fps", lambda self, p: calls.append(1) or own(self, p))
    metrics, own_fps = [], []
    for fps in ("auto", "null"):
        cfg = tiny_config(
            f"paths.output_root={tmp_path}",
            "+experiment=stage1",
            "stage1.init=false",
            f"paths.output_dir={tmp_path / fps}",
            f"data.fps_points={fps}",
            f"data.cache_root={tmp_path}",
        )
        calls.clear()
        metrics.append(train(cfg)["metrics"])
        own_fps.append(len(calls))
    assert own_fps[0] == 0 and own_fps[1] > 0
    assert metrics[0] == metrics[1]
    assert metrics[0]["test_id"]["v2v_cm"] > 0
