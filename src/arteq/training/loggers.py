"""Logger factories. wandb is opt-in and offline unless the user is logged in."""

from __future__ import annotations

import os
from pathlib import Path


def wandb_logged_in() -> bool:
    """True if a wandb API key is available (env var or ~/.netrc), without touching the network."""
    if os.environ.get("WANDB_API_KEY"):
        return True
    netrc = Path(os.environ.get("NETRC", Path.home() / ".netrc"))
    try:
        return "api.wandb.ai" in netrc.read_text()
    except OSError:
        return False


def wandb_logger(project: str = "arteq", mode: str = "auto", save_dir: str = ".", **kwargs):
    """A Lightning ``WandbLogger``; ``mode="auto"`` is online only when logged in, else offline.

    Offline runs land in ``<save_dir>/wandb`` and can be uploaded later with ``wandb sync``.
    """
    from lightning.pytorch.loggers import WandbLogger

    if mode not in ("auto", "online", "offline", "disabled"):
        raise ValueError(f"logger.wandb.mode must be auto, online, offline or disabled, got {mode!r}")
    if mode == "auto":
        mode = "online" if wandb_logged_in() else "offline"
    return WandbLogger(project=project, save_dir=save_dir, offline=mode == "offline", mode=mode, **kwargs)
