"""OmegaConf resolvers used by ``conf/`` (registered when :mod:`arteq` is imported), and :func:`to_plain`."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any


def to_plain(x: Any) -> Any:
    """An OmegaConf container as plain Python (dicts and lists, interpolations resolved); anything else as
    it is. For code that takes a config or a plain mapping alike, and for what checkpoints store (they
    load with ``torch.load(weights_only=True)``, which refuses OmegaConf objects)."""
    from omegaconf import DictConfig, ListConfig, OmegaConf

    if isinstance(x, DictConfig | ListConfig):
        return OmegaConf.to_container(x, resolve=True)
    return x


def dataclass_from_strings(cls, items: Sequence[str], what: str, **base):
    """``cls`` (a dataclass) from ``KEY=VALUE`` strings (command lines: ``--set sigma_end=3``) over ``base``;
    each value is read as its field's type (``true`` / ``false`` / ``1`` / ``0`` for a bool). An unknown key
    or an unreadable value is a ``ValueError`` that names ``what`` and the item."""
    default = cls(**base)
    fields = default.__dataclass_fields__
    values = dict(base)
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or key not in fields:
            names = ", ".join(fields)
            raise ValueError(f"{what} setting {item!r}: expected KEY=VALUE with KEY one of {names}")
        kind = type(getattr(default, key))
        try:
            if kind is bool:
                if value.lower() not in ("true", "false", "1", "0"):
                    raise ValueError(value)
                values[key] = value.lower() in ("true", "1")
            else:
                values[key] = kind(value)
        except ValueError:
            raise ValueError(f"{what} setting {item!r}: {value!r} is not of type {kind.__name__}") from None
    return cls(**values)


def dataclass_from_mapping(cls, cfg: Any, what: str):
    """``cls`` (a dataclass) from a config group (a mapping, an OmegaConf node, None: the defaults, or
    already a ``cls``); an unknown key is a ``ValueError`` that names ``what`` and the known keys."""
    from dataclasses import fields

    if isinstance(cfg, cls):
        return cfg
    cfg = dict(to_plain(cfg) or {})
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(cfg) - known)
    if unknown:
        raise ValueError(f"{what} has unknown keys {unknown}; known: {sorted(known)}")
    return cls(**cfg)


def radii_for_points(radii: Sequence[float], num_points: int, reference_points: int = 5000) -> list[float]:
    """Ball radii given for ``reference_points`` input points, scaled to keep the same number of
    neighbours at ``num_points``: points per area scale with N, so radii scale with ``sqrt(ref / N)``.

    The paper's radii (0.08 ... 0.16 m) are for 5000 points; at 500 points they would hold ~5 of the
    32 neighbours a layer asks for, and the kernels would see almost nothing.
    """
    num_points, reference_points = int(num_points), int(reference_points)
    if num_points < 1 or reference_points < 1:
        raise ValueError(f"radii_for_points: point counts must be >= 1, got {num_points}, {reference_points}")
    s = math.sqrt(reference_points / num_points)
    return [round(float(r) * s, 4) for r in radii]


def register_resolvers() -> None:
    """Register ``${arteq.radii:RADII,N[,REF]}`` (idempotent)."""
    from omegaconf import OmegaConf

    if not OmegaConf.has_resolver("arteq.radii"):
        OmegaConf.register_new_resolver(
            "arteq.radii", lambda r, n, ref=5000: radii_for_points(list(r), n, ref)
        )
