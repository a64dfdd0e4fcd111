"""Where arteq finds its configs and keeps derived artefacts (built body models, cached evaluation sets).

Configs: :func:`conf_dir`, the Hydra config folder (``train.yaml``, ``eval.yaml`` and their groups): the
top-level ``conf/`` of a checkout, or ``arteq/conf/`` inside an installed wheel (``setup.py`` copies the
checkout's ``conf/`` there when the wheel is built).

Cache: the root is ``$ARTEQ_CACHE_DIR`` if set, else ``~/.cache/arteq``. Nothing is ever downloaded:
everything under it is derived from installed packages or from files the user points at.
"""

from __future__ import annotations

import os
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent


def conf_dir() -> Path:
    """The Hydra config folder, found the same way by every command and test.

    An installed wheel carries it inside the package (``<site-packages>/arteq/conf``); a checkout (editable
    install, or ``PYTHONPATH=src``) has it at the top, beside ``src/`` (``<checkout>/conf``).
    """
    candidates = [_PACKAGE / "conf"]
    if _PACKAGE.parent.name == "src":
        candidates.append(_PACKAGE.parent.parent / "conf")
    for path in candidates:
        if (path / "train.yaml").is_file():
            return path
    tried = ", ".join(str(p) for p in candidates)
    raise FileNotFoundError(
        f"arteq: no config folder (conf/ with train.yaml) at {tried}: the package was installed without its "
        "configs; reinstall it from a wheel built by this project's setup.py, or run from a checkout"
    )


def cache_dir(*parts: str) -> Path:
    """Return (and create) a folder under the arteq cache root."""
    root = Path(os.environ.get("ARTEQ_CACHE_DIR", Path.home() / ".cache" / "arteq")).expanduser()
    path = root.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path
