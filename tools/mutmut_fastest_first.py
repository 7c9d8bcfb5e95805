"""pytest plugin for mutation runs: each mutant's tests run nearest and fastest first.

mutmut stops a mutant's test run at the first failure (``-x``), and pytest otherwise runs the
tests in file order, so a mutant of the simulator that ``tests/sim/test_quadrotor.py`` kills in
milliseconds may first sit through seconds of deploy and training tests from earlier files. This
plugin orders the collected tests by

1. nearness to the mutated module (mutmut names the mutant in ``MUTANT_UNDER_TEST``, e.g.
   ``datt.sim.quadrotor.xǁQuadrotorǁstep__mutmut_3``): first the test files named after it
   (``tests/**/test_quadrotor*.py``), then the tests of its package (``tests/sim/``), then the rest;
2. within each group, the durations mutmut recorded in ``mutmut-stats.json`` (in the working
   directory, ``mutants/`` during a run), shortest first; tests without one go last, in order.

The set of tests run is unchanged, so a mutant is killed or survives exactly as before; only the
time to kill it changes. Outside a mutant run (no ``MUTANT_UNDER_TEST``) nearness is not used, and
without the stats file the durations are not.

Loaded through the environment (docs/mutation.md): ``PYTEST_PLUGINS=tools.mutmut_fastest_first``.
"""

from __future__ import annotations

import json
import os
from pathlib import PurePosixPath

from tools.mutation_report import module_of

_durations: dict[str, float] | None = None


def _load() -> dict[str, float]:
    global _durations
    if _durations is None:
        try:
            with open("mutmut-stats.json") as f:
                _durations = dict(json.load(f)["duration_by_test"])
        except (OSError, ValueError, KeyError):
            _durations = {}
    return _durations


def nearness(nodeid: str, mutant: str) -> int:
    """0: a test file named after the mutant's module; 1: the module's package's tests; 2: other.
    ``mutant`` is a mutmut name (``datt.<package>.<module>.x…``); "" gives 2 for every test."""
    parts = module_of(mutant).split(".")
    if len(parts) < 3:
        return 2
    package, module = parts[1], parts[-1]
    path = PurePosixPath(nodeid.split("::", 1)[0])
    if path.name.startswith(f"test_{module}"):
        return 0
    return 1 if package in path.parts[:-1] else 2


def pytest_collection_modifyitems(config, items) -> None:
    durations = _load()
    mutant = os.environ.get("MUTANT_UNDER_TEST", "")
    unknown = float("inf")
    # list.sort is stable: tests that tie keep pytest's order
    items.sort(key=lambda item: (nearness(item.nodeid, mutant), durations.get(item.nodeid, unknown)))
