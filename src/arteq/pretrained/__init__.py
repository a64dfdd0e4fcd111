"""Pretrained ArtEq models shipped with the package (weights only; no body-model data inside).

``resolve_checkpoint("anny22")`` returns the path of the shipped model trained on the free default body
``anny22``; any other string is taken as a checkpoint path. Each shipped file is a Lightning-style
checkpoint holding only ``state_dict`` and ``hyper_parameters`` (plus provenance under ``arteq``): it
loads with ``ArtEqModule.load_from_checkpoint(path, weights_only=True)``; the body model named in its
hyper-parameters is rebuilt from its own file at load time. Its model card is ``<name>.md`` beside it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

#: Folder of the shipped models.
PRETRAINED_DIR = Path(__file__).resolve().parent
#: The model tools load by default.
DEFAULT_MODEL = "anny_scan"


def available() -> list[str]:
    """Names of the shipped models."""
    return sorted(p.stem for p in PRETRAINED_DIR.glob("*.ckpt"))


def resolve_checkpoint(name_or_path: str | Path | None = None) -> Path:
    """Path of a shipped model (by name) or of a checkpoint file; clear error if neither exists."""
    name_or_path = DEFAULT_MODEL if name_or_path is None else name_or_path
    text = str(name_or_path)
    shipped = PRETRAINED_DIR / f"{text}.ckpt"
    if "/" not in text and not text.endswith(".ckpt") and shipped.is_file():
        return shipped
    path = Path(text).expanduser()
    if path.is_file():
        return path
    names = ", ".join(available()) or "none shipped in this install"
    raise FileNotFoundError(
        f"checkpoint {text!r}: no such file and no pretrained model of that name (pretrained: {names})"
    )


def export_weights(
    ckpt_path: str | Path | dict[str, Any], out_path: str | Path, info: dict[str, Any] | None = None
) -> Path:
    """Write a weights-only copy of a training checkpoint (no optimizer, loops or callbacks).

    ``ckpt_path``: a checkpoint file or its loaded dict. Keeps ``state_dict`` (network weights; body
    buffers are never saved) and ``hyper_parameters``; adds
    ``info`` under ``arteq``. Written atomically (temporary file, then rename).
    """
    if isinstance(ckpt_path, dict):
        state = ckpt_path
    else:
        from arteq.io.runs import read_checkpoint

        state = read_checkpoint(ckpt_path)
    if "state_dict" not in state or "hyper_parameters" not in state:
        raise ValueError(
            f"{ckpt_path}: not an arteq Lightning checkpoint (needs state_dict, hyper_parameters)"
        )
    slim = {
        "state_dict": {k: v.detach().clone() for k, v in state["state_dict"].items()},
        "hyper_parameters": state["hyper_parameters"],
        "pytorch-lightning_version": state.get("pytorch-lightning_version", ""),
        "arteq": dict(info or {}, source_global_step=int(state.get("global_step", -1))),
    }
    out = Path(out_path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    torch.save(slim, tmp)
    tmp.replace(out)
    return out
