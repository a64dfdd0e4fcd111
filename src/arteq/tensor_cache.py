"""``tensor_cache``: ``functools.lru_cache`` for functions that build constant tensors (group tables,
Fourier bases, index tensors), always built outside inference mode.

A tensor created under ``torch.inference_mode()`` (Lightning's validation / test loops, ``arteq-fit``)
can never be saved for backward; cached there first, it would break every later training step of the
process ("Inference tensors cannot be saved for backward").
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import TypeVar

import torch

F = TypeVar("F", bound=Callable)


def tensor_cache(maxsize: int | None = None) -> Callable[[F], F]:
    def deco(fn: F) -> F:
        @functools.lru_cache(maxsize=maxsize)
        @functools.wraps(fn)
        def cached(*args, **kwargs):
            with torch.inference_mode(False):
                return fn(*args, **kwargs)

        return cached  # type: ignore[return-value]

    return deco
