"""One way to get a body model: :func:`create_body` (Hydra target of ``conf/body_model/*.yaml``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from torch import nn

from arteq.body.model import BodyModel, load_body_model
from arteq.config import to_plain


def create_body(spec: nn.Module | Mapping[str, Any] | None = None, /, **kwargs: Any) -> BodyModel:
    """The body model a config names, or ``spec`` itself when it already is a module.

    Args:
        spec: a body ``nn.Module`` (returned as is), or a config mapping (plain or OmegaConf) with
            ``name`` (``anny22`` default, ``anny_allages``, ``smpl``, ``smplh``, or ``toy``: the procedural
            test body),
            ``model_path``, ``num_betas``, ``gender``; ``_target_`` is ignored.
        kwargs: config keys given directly (they win over ``spec``'s); how Hydra calls it.
    Returns:
        A :class:`BodyModel` (buffers non-persistent: never part of a state dict), no parameters.
    """
    if isinstance(spec, nn.Module):
        if kwargs:
            raise TypeError("create_body: config keys given together with a body module")
        return spec
    spec = to_plain(spec)
    if spec is not None and not isinstance(spec, Mapping):
        raise TypeError(f"create_body: expected a body module or a config mapping, got {type(spec).__name__}")
    cfg = {**dict(spec or {}), **kwargs}
    cfg.pop("_target_", None)
    if cfg.get("name") == "toy":
        from arteq.body.toy import ToyBody

        return ToyBody(num_betas=int(cfg.get("num_betas", 2)))
    return load_body_model(**cfg)
