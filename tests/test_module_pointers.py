"""Every ``datt.*`` name the configs and the docs point a reader to exists: a module, or an
attribute of one (stale pointers such as ``datt.config`` after a rename fail here). Firmware
parameter and log names of the DATT app (``datt.run``, ``datt.errM``) and file names are not
Python names and are told apart by their own tables."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

from datt.deploy.onboard import LOGS, PARAMS

ROOT = Path(__file__).resolve().parents[1]
NAME = re.compile(r"\bdatt(?:\.[A-Za-z_][A-Za-z0-9_]*)+")
FIRMWARE = {f"datt.{p[0]}" for p in PARAMS} | {f"datt.{name}" for name, _ in LOGS}
FILE_SUFFIXES = (".py", ".yaml", ".c", ".h", ".pt", ".md")


def sources() -> list[Path]:
    return [
        *sorted((ROOT / "src" / "datt" / "conf").rglob("*.yaml")),
        ROOT / "README.md",
        *sorted((ROOT / "docs").glob("*.md")),
    ]


def resolves(name: str) -> bool:
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for attr in parts[i:]:
                obj = getattr(obj, attr)
        except AttributeError:
            return False
        return True
    return False


def test_every_datt_name_in_configs_and_docs_resolves():
    names = {(path.relative_to(ROOT), m) for path in sources() for m in NAME.findall(path.read_text())}
    assert len(names) > 50  # the scan reads what it should
    bad = sorted(
        f"{path}: {name}"
        for path, name in names
        if name not in FIRMWARE and not name.endswith(FILE_SUFFIXES) and not resolves(name)
    )
    assert bad == []


def test_a_stale_pointer_is_caught():
    assert not resolves("datt.config.EnvParams") and resolves("datt.envs.params.EnvParams")
