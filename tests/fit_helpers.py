"""Helpers shared by the fitting tests (not a test module)."""

from __future__ import annotations

from pathlib import Path

import torch

from arteq.fit.api import Fitter


class CentreKeepingFitter(Fitter):
    """A ``Fitter`` that remembers the last prepared scan's centre (``self._centre``), for test subclasses
    whose ``_network`` stands in for the network with a known answer in the scan's frame."""

    def prepare(self, points, units="m", name="points"):
        item = super().prepare(points, units, name)
        self._centre = item["center"]
        return item


def write_tiny_checkpoint(path: Path, net: dict) -> Path:
    """An untrained, weights-only checkpoint of ``net`` (the ``tiny_net`` fixture: ArtEqNet keyword
    arguments) in the shipped format (network input: 500 points)."""
    import lightning

    from arteq.training.module import ArtEqModule

    torch.manual_seed(0)
    m = ArtEqModule(net=net, body_model={"name": "anny22"}, data={"num_points": 500})
    state = {"state_dict": m.state_dict(), "hyper_parameters": dict(m.hparams)}
    torch.save({**state, "pytorch-lightning_version": lightning.__version__}, path)
    return path
