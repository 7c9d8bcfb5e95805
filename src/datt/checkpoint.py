"""Checkpoints: plain dicts of tensors and primitives, written atomically, loaded with
``torch.load(..., weights_only=True)`` so a file can never execute code.

Layout (``FORMAT``): actor/critic/optimizer ``state_dict``s, ``frames``, ``iteration``, the
composed config as YAML text, RNG states, curriculum reference, best metric, and ``lineage``: the
checkpoints the weights were fine-tuned from (``train.init_from``, oldest first), each as
``{checkpoint, frames, config_yaml}``, so a chain of commands can be rerun from the last file alone.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import Any

import torch

from datt.errors import ConfigError
from datt.runs import atomic_write

FORMAT = "datt-checkpoint-v1"


def save_checkpoint(path: str | Path, payload: dict[str, Any]) -> Path:
    """Write ``payload`` to ``path`` via a temp file in the same directory and ``os.replace``:
    a crash mid-write leaves the previous checkpoint intact."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()  # serialise first: a full disk is then an OSError naming the file, not torch's zip error
    torch.save({"format": FORMAT, **payload}, buffer)
    with atomic_write(path, "wb") as f:
        f.write(buffer.getbuffer())
    return path


def load_checkpoint(path: str | Path, key: str = "checkpoint") -> dict[str, Any]:
    """Load and check a checkpoint; any problem is a one-line :class:`ConfigError` naming ``key``."""
    path = Path(path).expanduser()
    if path.is_dir():
        path = path / "last.pt"
    if not path.is_file():
        raise ConfigError(f"{key}: file {str(path)!r} not found")
    try:
        data = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # truncated, not a zip, foreign pickle...
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:160]
        raise ConfigError(f"{key}: {str(path)!r} is not a readable checkpoint ({first})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ConfigError(f"{key}: {str(path)!r} is not a datt checkpoint (expected format {FORMAT})")
    return data
