"""One way to get a body model: :func:`create_body` (Hydra target of ``conf/body_model/*.yaml``)."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from torch import nn

from arteq.body.model import BodyModel, load_body_model


def _plain(spec: Any) -> dict[str, Any]:
    try:
        from omegaconf import DictConfig, OmegaConf

        if isinstance(spec, DictConfig):
            return OmegaConf.to_container(spec, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    if spec is not None and not isinstance(spec, Mapping):
        raise TypeError(f"create_body: expected a body module or a config mapping, got {type(spec).__name__}")
    return dict(spec or {})


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
    cfg = {**_plain(spec), **kwargs}
    cfg.pop("_target_", None)
    if cfg.get("name") == "toy":
        from arteq.body.toy import ToyBody

        return ToyBody(num_betas=int(cfg.get("num_betas", 2)))
    return load_body_model(**cfg)
