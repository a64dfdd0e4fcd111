"""Where arteq keeps derived artefacts (built body models, cached evaluation sets).

The cache root is ``$ARTEQ_CACHE_DIR`` if set, else ``~/.cache/arteq``. Nothing is ever downloaded:
everything under it is derived from installed packages or from files the user points at.
"""

from __future__ import annotations

import os
from pathlib import Path


def cache_dir(*parts: str) -> Path:
    """Return (and create) a folder under the arteq cache root."""
    root = Path(os.environ.get("ARTEQ_CACHE_DIR", Path.home() / ".cache" / "arteq")).expanduser()
    path = root.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path
