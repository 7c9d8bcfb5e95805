"""Re-check every kill listed in ``docs/mutation-by-hand.txt``: apply the mutant to a copy of the
tree and run the test named for it, which must fail.

mutmut reports these mutants as survived (docs/mutation.md says why: a test outside its selection,
a test newer than its cached result, a default argument its trampoline cannot switch). This tool
is what "killed by hand" means, made repeatable. It needs mutmut's ``mutants/`` directory (the
diffs come from ``mutmut show``) and is run from the directory that holds it::

    python tools/check_by_hand.py --tree /path/to/checkout [--only <substring>]

``--tree`` is the checkout whose ``src/`` and ``tests/`` are copied (default: this repository);
the copy lives in a temporary directory, so the tree itself is never modified. Exit 0 when every
listed test fails on its mutant, 1 otherwise (each failure to kill, or to apply, on its own line).
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run as a script: the repository root
from tools.mutation_report import BY_HAND, ROOT, equivalent  # noqa: E402

TEST_ID = re.compile(r"(tests/\S+?\.py::[\w\[\]\-.]+)")


@dataclass
class Entry:
    mutant: str
    test: str


def entries(path: Path = BY_HAND) -> list[Entry]:
    """The (mutant, test node id) pairs of the by-hand list; the test is the first node id in the
    line's comment."""
    return [Entry(name, match.group(1)) for name, note in equivalent(path).items() if (match := TEST_ID.search(note))]


def parse_diff(diff: str) -> tuple[str, list[str], list[str]]:
    """``mutmut show`` output -> (file, old lines, new lines) of its one hunk (context included)."""
    file = next(line[4:].strip() for line in diff.splitlines() if line.startswith("--- "))
    body = diff.split("\n@@", 1)[1].split("\n", 1)[1]
    old, new = [], []
    for line in body.splitlines():
        tag, text = line[:1], line[1:]
        if tag in (" ", "-"):
            old.append(text)
        if tag in (" ", "+"):
            new.append(text)
    return file, old, new


def apply(source: str, old: list[str], new: list[str]) -> str:
    """Replace the one run of lines equal to ``old`` up to indentation (mutmut prints a method
    dedented) by ``new``, re-indented by the same offset. Raises ValueError unless exactly one
    run matches."""
    lines = source.splitlines(keepends=True)
    want = [s.strip() for s in old]
    hits = [i for i in range(len(lines) - len(old) + 1) if [s.strip() for s in lines[i : i + len(old)]] == want]
    if len(hits) != 1:
        raise ValueError(f"the mutant's context matches {len(hits)} places, not one")
    i = hits[0]
    if len(old) == len(new):  # only the lines that differ, each at its own line's indentation (a
        # docstring's lines keep theirs where mutmut dedents a method, so no one offset fits all)
        replaced = [
            line if o == n else " " * (len(line) - len(line.lstrip()) - (len(o) - len(o.lstrip()))) + n + "\n"
            for line, o, n in zip(lines[i : i + len(old)], old, new)
        ]
        return "".join(lines[:i] + replaced + lines[i + len(old) :])
    first = next(k for k, s in enumerate(old) if s.strip())
    indent = len(lines[i + first]) - len(lines[i + first].lstrip()) - (len(old[first]) - len(old[first].lstrip()))
    pad = " " * indent
    replaced = [(pad + s if s.strip() else s) + "\n" for s in new]
    return "".join(lines[:i] + replaced + lines[i + len(old) :])


def show(mutant: str) -> str:
    return subprocess.run(["mutmut", "show", mutant], capture_output=True, text=True, check=True).stdout


def pytest(test: str, work: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-x", "-n", "0", "-p", "no:cacheprovider", "-m", "", test],
        cwd=work,
        capture_output=True,
        text=True,
        env={**_env(), "PYTHONPATH": str(work / "src")},
    )


def check(entry: Entry, tree: Path, work: Path) -> str | None:
    """None when the test fails on the mutant (a kill); otherwise what went wrong."""
    try:
        file, old, new = parse_diff(show(entry.mutant))
    except (subprocess.CalledProcessError, StopIteration, IndexError):
        return "mutmut show gave no diff for it (a renamed function? run from the mutmut directory)"
    target = work / file
    original = (tree / file).read_text()
    try:
        target.write_text(apply(original, old, new))
        run = pytest(entry.test, work)
    except ValueError as exc:
        return f"not applied: {exc}"
    finally:
        target.write_text(original)
    return verdict(run, entry.test)


def verdict(run: subprocess.CompletedProcess, test: str) -> str | None:
    """None when ``test`` failed on the mutant: an assertion (exit 1), or its module no longer
    imports (pytest reports ``ERROR <file> - <exception>`` while collecting it: every test that
    imports the mutated module errors, a mutant evaluated at import time such as a module-level
    table's); otherwise what happened."""
    if run.returncode == 1:
        return None
    if run.returncode == 0:
        return "the test passes on the mutant"
    if f"ERROR {test.split('::')[0]} - " in run.stdout:
        return None
    return f"pytest exit {run.returncode}: {run.stdout.strip().splitlines()[-1] if run.stdout.strip() else ''}"


def _env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("PYTEST_PLUGINS", "PYTHONPATH")}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tree", type=Path, default=ROOT, help="checkout whose src/ and tests/ are copied")
    parser.add_argument("--only", default="", help="check only mutants whose name contains this")
    args = parser.parse_args(argv)
    if shutil.which("mutmut") is None or not Path("mutants").is_dir():
        print("check_by_hand: needs mutmut on PATH and its mutants/ directory here (docs/mutation.md)", file=sys.stderr)
        return 2
    todo = [e for e in entries() if args.only in e.mutant]
    failed = 0
    with tempfile.TemporaryDirectory(prefix="by_hand_") as tmp:
        work = Path(tmp)
        # the entry points too: tests of the command line run them from the checkout's root
        for part in ("src", "tests", "pyproject.toml", *(p.name for p in args.tree.glob("*.py"))):
            src = args.tree / part
            (shutil.copytree if src.is_dir() else shutil.copy)(src, work / part)
        passing: dict[str, bool] = {}
        for entry in todo:
            if entry.test not in passing:  # a kill only counts if the test passes without the mutant
                passing[entry.test] = pytest(entry.test, work).returncode == 0
            problem = check(entry, args.tree, work) if passing[entry.test] else "the test fails without the mutant"
            print(f"{'killed' if problem is None else 'NOT KILLED'}  {entry.mutant}  {entry.test}", flush=True)
            if problem is not None:
                failed += 1
                print(f"    {problem}", flush=True)
    print(f"{len(todo) - failed} of {len(todo)} by-hand kills confirmed")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
