"""Cached fixed sets: checksum + size checks; a truncated, corrupted or foreign file is removed and
regenerated with a warning (never loaded); writes are atomic; concurrent creators do not collide."""

from __future__ import annotations

import logging
import multiprocessing as mp
import time
from pathlib import Path

import pytest
import torch

from arteq.data import BodyScanDataModule
from arteq.data.datamodule import CorruptCacheError, read_cache, write_cache


def _dm(root: Path, **kw) -> BodyScanDataModule:
    args = dict(
        body_model={"name": "toy"}, num_points=64, train_size=4, val_size=6, test_size=4, batch_size=2
    )
    args.update(kw)
    return BodyScanDataModule(cache_root=str(root), **args)


@pytest.fixture()
def cached(tmp_path):
    dm = _dm(tmp_path)
    ds = dm.fixed_set("val")
    assert dm.generated == ["val"]
    (path,) = tmp_path.glob("val-*.pt")
    return path, {k: v.clone() for k, v in ds.tensors.items()}


def _flip_byte_inside_points(path: Path, original: dict[str, torch.Tensor]) -> None:
    """Change one float of the stored ``points`` in place (the zip container stays readable)."""
    data = bytearray(path.read_bytes())
    needle = original["points"].contiguous().numpy().tobytes()[:64]
    at = data.find(needle)
    assert at > 0
    data[at + 10] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("damage", ["truncated", "flipped_byte", "empty", "old_format"])
def test_bad_cache_file_is_removed_and_regenerated(cached, tmp_path, caplog, damage):
    path, original = cached
    if damage == "truncated":
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif damage == "flipped_byte":
        _flip_byte_inside_points(path, original)
    elif damage == "empty":
        path.write_bytes(b"")
    else:  # a plain dict of tensors, as version 1 wrote
        torch.save(original, path)
    with pytest.raises(CorruptCacheError):
        read_cache(path, "val")
    dm = _dm(tmp_path)
    with caplog.at_level(logging.WARNING, logger="arteq.data.datamodule"):
        ds = dm.fixed_set("val")
    assert dm.generated == ["val"]  # regenerated, not loaded
    assert any("corrupt" in r.getMessage() and "regenerating" in r.getMessage() for r in caplog.records)
    for k, v in original.items():
        assert torch.equal(ds.tensors[k], v), k
    assert torch.equal(read_cache(path, "val")["points"], original["points"])  # the file is good again


def test_valid_cache_is_loaded_not_regenerated(cached, tmp_path):
    path, original = cached
    dm = _dm(tmp_path)
    ds = dm.fixed_set("val")
    assert dm.generated == [] and torch.equal(ds.tensors["points"], original["points"])


def test_interrupted_write_leaves_no_file(tmp_path, monkeypatch):
    tensors = {k: v for k, v in _dm(tmp_path / "a", cache=False).fixed_set("val").tensors.items()}
    target = tmp_path / "val-x.pt"

    def dies_half_way(obj, f, *a, **k):
        Path(f).write_bytes(b"PK\x03\x04 half a file")
        raise KeyboardInterrupt  # the process being killed mid-write

    monkeypatch.setattr(torch, "save", dies_half_way)
    with pytest.raises(KeyboardInterrupt):
        write_cache(target, tensors, "val")
    assert list(tmp_path.glob("*.pt")) == [] and list(tmp_path.glob(".*tmp")) == []


def _create_slowly(cache_root: str, barrier, results) -> None:
    dm = _dm(Path(cache_root))
    original = dm._generate

    def slow(ds):  # widen the window in which both processes would write
        time.sleep(1.0)
        return original(ds)

    dm._generate = slow
    barrier.wait()
    ds = dm.fixed_set("val")
    results.put((list(dm.generated), ds.tensors["points"].numpy().tobytes()))


def test_two_processes_creating_the_same_cache(tmp_path):
    ctx = mp.get_context("spawn")
    barrier, results = ctx.Barrier(2), ctx.Queue()
    procs = [ctx.Process(target=_create_slowly, args=(str(tmp_path), barrier, results)) for _ in range(2)]
    for p in procs:
        p.start()
    outs = [results.get(timeout=300) for _ in procs]
    for p in procs:
        p.join(timeout=60)
        assert p.exitcode == 0
    generated = [g for g, _ in outs]
    assert sorted(generated) == [[], ["val"]]  # one created it, the other waited and loaded it
    assert outs[0][1] == outs[1][1]
    (path,) = tmp_path.glob("val-*.pt")
    read_cache(path, "val")  # complete and consistent
    assert list(tmp_path.glob(".*tmp")) == []
