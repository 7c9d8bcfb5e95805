"""pytest plugin for mutation runs: the selected tests run fastest first.

mutmut stops a mutant's test run at the first failure (``-x``), and pytest otherwise runs the
tests in file order, so a mutant that a 10 ms unit test kills may first sit through seconds of
env rollouts from an earlier file. This plugin orders the collected tests by the durations
mutmut recorded in ``mutmut-stats.json`` (in the working directory, which is ``mutants/`` during
a run); tests it has no duration for go last, in their own order. The set of tests run is
unchanged, so a mutant is killed or survives exactly as before; only the time to kill it
changes. Without the stats file (mutmut's first, stats-collecting pass) the order is left alone.

Loaded through ``[tool.mutmut] pytest_add_cli_args`` (``-p tools.mutmut_fastest_first``).
"""

from __future__ import annotations

import json
from pathlib import Path

_durations: dict[str, float] | None = None


def _load() -> dict[str, float]:
    global _durations
    if _durations is None:
        path = Path("mutmut-stats.json")
        try:
            _durations = dict(json.loads(path.read_text())["duration_by_test"])
        except (OSError, ValueError, KeyError):
            _durations = {}
    return _durations


def pytest_collection_modifyitems(config, items) -> None:
    durations = _load()
    if not durations:
        return
    unknown = float("inf")
    order = {id(item): i for i, item in enumerate(items)}
    items.sort(key=lambda item: (durations.get(item.nodeid, unknown), order[id(item)]))
