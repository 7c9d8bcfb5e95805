"""User paths: relative to where the command ran, else to the installed package (so the shipped
``checkpoints/datt_h10.pt`` is found from any directory and from a wheel)."""

from __future__ import annotations

from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent


def original_cwd() -> Path:
    """The directory the command ran in (Hydra may change the working directory of a job)."""
    try:
        from hydra.utils import get_original_cwd

        return Path(get_original_cwd())
    except ValueError:  # not inside a Hydra job
        return Path.cwd()


def resolve_path(path: str | Path) -> Path:
    """A user path: absolute; else relative to the working directory if it exists there; else the
    package's own file of that name (``checkpoints/...``); else the working-directory path (so
    the error names what the user typed)."""
    p = Path(str(path)).expanduser()
    if p.is_absolute():
        return p
    here = original_cwd() / p
    shipped = PACKAGE_DIR / p
    return here if here.exists() or not shipped.exists() else shipped
