"""Test-only Lightning callback, added to subprocess runs with
``+callbacks.record._target_=helpers.record.RecordBatches`` (``tests/`` on ``PYTHONPATH``).

Writes ``<run>/record_rank<R>.pt`` at the end of each fit/test: per training batch its epoch and the
samples' ``betas`` (a fingerprint of each sample), per test batch its split and the samples' ``center``.
"""

from __future__ import annotations

from pathlib import Path

import lightning as L
import torch


class RecordBatches(L.Callback):
    def __init__(self) -> None:
        self.train: list[tuple[int, torch.Tensor]] = []
        self.test: list[tuple[int, torch.Tensor]] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        self.train.append((trainer.current_epoch, batch["betas"].detach().cpu().clone()))

    def on_test_batch_start(self, trainer, pl_module, batch, batch_idx, dataloader_idx=0):
        self.test.append((dataloader_idx, batch["center"].detach().cpu().clone()))

    def _dump(self, trainer):
        path = Path(trainer.default_root_dir) / f"record_rank{trainer.global_rank}.pt"
        torch.save({"train": self.train, "test": self.test, "world_size": trainer.world_size}, path)

    def on_train_end(self, trainer, pl_module):
        self._dump(trainer)

    def on_test_end(self, trainer, pl_module):
        self._dump(trainer)
