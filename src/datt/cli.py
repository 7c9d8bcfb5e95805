"""Entry points: ``train.py`` / ``eval.py`` / ``tables.py`` / ``deploy.py`` (root shims), the
``datt`` console script and ``python -m datt``.

Only entry points and error reporting live here: every user error ends in one line on stderr
(``error: <key>: <what>``) and exit code 2; a diverged training run exits with 3.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig

from datt.configuration import CONF_PACKAGE, available_options, conf_dir, config_groups, root_from_uri
from datt.errors import ConfigError, TrainingDiverged


def _argv_search_roots(argv: list[str]) -> list[Path]:
    """The config search path the command line asks for: ``--config-dir``/``-cd`` and
    ``hydra.searchpath=[...]`` before the package's own tree (as Hydra orders them)."""
    roots: list[Path] = []
    for i, arg in enumerate(argv):
        value = None
        if arg in ("--config-dir", "-cd") and i + 1 < len(argv):
            value = argv[i + 1]
        elif arg.startswith("--config-dir="):
            value = arg.split("=", 1)[1]
        if value:
            roots.append(Path(value).expanduser().resolve())
        key = arg.lstrip("+")
        if key.startswith("hydra.searchpath="):
            for item in key.split("=", 1)[1].strip("[]").split(","):
                root = root_from_uri(item.strip().strip("'\""))
                if root is not None:
                    roots.append(root)
    return [*roots, conf_dir()]


def preflight(argv: list[str]) -> None:
    """Reject unknown config-group options (over the whole search path) in one line, before
    Hydra prints a multi-line error."""
    roots = _argv_search_roots(argv)
    groups = config_groups(roots)
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        group = key.lstrip("+~").split("@")[0]
        if group in groups and "," not in value and "(" not in value and value != "null":
            allowed = available_options(group, roots)
            if value not in allowed:
                raise ConfigError(f"{group}: unknown option {value!r}; allowed: {', '.join(allowed)}")


def _fail(message: str, code: int) -> None:
    print(f"error: {message}", file=sys.stderr)
    sys.exit(code)


def hydra_main(config_name: str, task: Callable[[DictConfig], object]) -> Callable[[], None]:
    """``task`` wrapped in ``@hydra.main`` (config tree from the package) with one-line errors."""
    import hydra

    @hydra.main(config_path=f"pkg://{CONF_PACKAGE}", config_name=config_name, version_base="1.3")
    def _main(cfg: DictConfig) -> None:
        try:
            task(cfg)
        except ConfigError as exc:
            _fail(str(exc), 2)
        except TrainingDiverged as exc:
            _fail(f"training diverged: {exc}", 3)

    def entry() -> None:
        try:
            preflight(sys.argv[1:])
        except ConfigError as exc:
            _fail(str(exc), 2)
        _main()

    return entry


def _task(module: str, name: str) -> Callable[[DictConfig], object]:
    """Import the task on first use: ``datt --help``-like paths stay free of torch/TorchRL imports."""

    def run(cfg: DictConfig) -> object:
        import importlib

        return getattr(importlib.import_module(module), name)(cfg)

    return run


def _tables_entry(inner: Callable[[], None]) -> Callable[[], None]:
    """``tables.py ablation`` = ``tables.py table=ablation`` (a positional table name)."""

    def entry() -> None:
        if len(sys.argv) > 1 and "=" not in sys.argv[1] and not sys.argv[1].startswith("-"):
            sys.argv[1] = f"table={sys.argv[1]}"
        inner()

    return entry


train_main = hydra_main("train", _task("datt.tasks.train", "run_train"))
eval_main = hydra_main("eval", _task("datt.tasks.eval", "run_eval"))
tables_main = _tables_entry(hydra_main("tables", _task("datt.tasks.tables", "run_tables")))
deploy_main = hydra_main("deploy", _task("datt.tasks.deploy", "run_deploy"))
COMMANDS = {"train": train_main, "eval": eval_main, "tables": tables_main, "deploy": deploy_main}


def main() -> None:
    """``datt <command> [hydra overrides]``."""
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS:
        print(f"usage: datt {{{','.join(COMMANDS)}}} [overrides...]", file=sys.stderr)
        sys.exit(2)
    command = sys.argv.pop(1)
    sys.argv[0] = f"datt {command}"
    COMMANDS[command]()


__all__ = ["main", "train_main", "eval_main", "tables_main", "deploy_main", "preflight"]
