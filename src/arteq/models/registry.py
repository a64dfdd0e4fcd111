"""The network architectures by name (``model.net.arch``): one table, one builder.

Every architecture takes its config keys as keyword arguments, has ``num_parts`` and returns the
output dict of :meth:`arteq.models.ArtEqNet.forward`. Classes are imported when built, so reading
names (reports) does not load the networks.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import torch


@dataclass(frozen=True)
class Architecture:
    """A registered network: ``target`` is ``"module:Class"``, ``display`` its name in tables."""

    target: str
    display: str

    def load(self) -> type[torch.nn.Module]:
        module, _, cls = self.target.partition(":")
        return getattr(importlib.import_module(module), cls)


ARCHITECTURES: dict[str, Architecture] = {
    "arteq": Architecture("arteq.models.arteq_net:ArtEqNet", "ArtEq"),
    "pointnet2": Architecture("arteq.models.baselines:PointNet2Regressor", "PointNet++"),
}
DEFAULT_ARCH = "arteq"


def display_name(arch: str) -> str:
    """Table name of an architecture (the key itself when unknown)."""
    entry = ARCHITECTURES.get(arch)
    return entry.display if entry else arch


def build_net(cfg: Mapping[str, Any]) -> torch.nn.Module:
    """The network named by ``cfg["arch"]`` (default ``"arteq"``) built from the other keys."""
    cfg = dict(cfg)
    arch = cfg.pop("arch", DEFAULT_ARCH)
    if arch not in ARCHITECTURES:
        names = " or ".join(repr(a) for a in ARCHITECTURES)
        raise ValueError(f"model.net.arch must be {names}, got {arch!r}")
    return ARCHITECTURES[arch].load()(**cfg)
