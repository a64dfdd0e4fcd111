"""Helpers shared by the fitting tests (not a test module)."""

from __future__ import annotations

from pathlib import Path

import torch

from conftest import TINY_NET


def write_tiny_checkpoint(path: Path) -> Path:
    """An untrained, weights-only checkpoint in the shipped format (network input: 500 points)."""
    import lightning

    from arteq.training.module import ArtEqModule

    torch.manual_seed(0)
    m = ArtEqModule(net=TINY_NET, body_model={"name": "anny22"}, data={"num_points": 500})
    state = {"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams)}
    torch.save({**state, "pytorch-lightning_version": lightning.__version__}, path)
    return path
