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
    return write_torch(path, {"format": FORMAT, **payload})


def write_torch(path: str | Path, value: Any) -> Path:
    """``torch.save(value)`` to ``path``, serialised first (a full disk is then an OSError naming
    the file, not torch's zip error) and written through :func:`datt.runs.atomic_write` (no
    partial file is ever left as if whole)."""
    buffer = io.BytesIO()
    torch.save(value, buffer)
    with atomic_write(path, "wb") as f:
        f.write(buffer.getbuffer())
    return Path(path)


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
    bad = first_non_finite(data)
    if bad is not None:
        name, count, numel = bad
        raise ConfigError(
            f"{key}: {str(path)!r} holds non-finite values ({name}: {count} of {numel} are NaN or inf); "
            "the run that wrote it diverged: use an earlier checkpoint (its best.pt) or train again"
        )
    return data


def first_non_finite(value: Any, name: str = "") -> tuple[str, int, int] | None:
    """The first floating tensor in ``value`` (dicts and lists walked) with a NaN or inf, as
    (its dotted name, how many, of how many values); None when every one is finite."""
    if isinstance(value, torch.Tensor):
        if value.is_floating_point():
            bad = int((~torch.isfinite(value)).sum())
            if bad:
                return name or "tensor", bad, value.numel()
        return None
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, (list, tuple)) else ()
    for k, v in items:
        found = first_non_finite(v, f"{name}.{k}" if name else str(k))
        if found is not None:
            return found
    return None
