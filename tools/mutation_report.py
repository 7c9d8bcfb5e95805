"""Mutation-testing report of the core (``docs/mutation.md``) from the last ``mutmut run``.

Run from the repository root after ``mutmut run`` (see docs/mutation.md):

    python tools/mutation_report.py            # prints the table and rewrites docs/mutation.md's table
    python tools/mutation_report.py --survivors  # also lists every surviving mutant's diff
    python tools/mutation_report.py --results a.txt b.txt  # saved `mutmut results --all true`
                                                           # outputs instead, later files win
    python tools/mutation_report.py --results a.txt --fresh c.txt  # c.txt is a complete re-run of
                                                           # its modules: it replaces their results
    python tools/mutation_report.py ... --functions d.txt  # d.txt ran some functions' mutants: it
                                                           # replaces those functions' results

Mutants listed in ``docs/mutation-equivalent.txt`` (``<mutant name>  # reason``) are equivalent:
no test can tell them from the original, so the score leaves them out (also when a loaded machine
made one time out). Mutants listed in
``docs/mutation-by-hand.txt`` (``<mutant name>  # test``) survived under mutmut (or crashed its
test process: ``segfault``) but fail the named test when applied to a copy of the tree by hand
(``tools/check_by_hand.py`` re-checks them all); they count as killed.
Score = (killed + timeout) / (checked - equivalent), per module; the goal is >= 90 % in each. A
timed-out mutant made the tests run past mutmut's limit (a hang the tests noticed), so it counts
as detected, as mutation tools usually count it.
"""

from __future__ import annotations

import argparse
import re
import subprocess
import sys
from collections import Counter, defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "mutation.md"
EQUIVALENT = ROOT / "docs" / "mutation-equivalent.txt"
BY_HAND = ROOT / "docs" / "mutation-by-hand.txt"
BEGIN, END = "<!-- mutation-table:begin -->", "<!-- mutation-table:end -->"


def parse(text: str) -> dict[str, str]:
    found = {}
    for line in text.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep and "__mutmut_" in name:
            found[name] = status
    return found


def results(files: list[Path] | None = None) -> dict[str, str]:
    """Mutant -> status, from ``mutmut results --all true`` or from saved outputs of it (a later
    file's verdict replaces an earlier one's unless it says "not checked")."""
    if not files:
        cmd = ["mutmut", "results", "--all", "true"]
        return parse(subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, check=True).stdout)
    found: dict[str, str] = {}
    for path in files:
        for name, status in parse(Path(path).read_text()).items():
            if status != "not checked" or name not in found:
                found[name] = status
    return found


def refreshed(found: dict[str, str], fresh: dict[str, str]) -> dict[str, str]:
    """``found`` with every module that ``fresh`` holds replaced by ``fresh``'s results: a module
    mutated anew (its code changed, so mutmut numbered its mutants anew) keeps none of the names
    of an earlier run, which would otherwise be counted beside the new ones."""
    modules = {module_of(name) for name in fresh}
    kept = {name: status for name, status in found.items() if module_of(name) not in modules}
    return {**kept, **fresh}


def functions_refreshed(found: dict[str, str], run: dict[str, str]) -> dict[str, str]:
    """``found`` with every function of which ``run`` checked a mutant replaced by ``run``'s
    results for it (its checked and unchecked mutants alike: a function whose code changed is
    numbered anew); the functions ``run`` did not check keep their earlier results."""
    checked = {function_of(name) for name, status in run.items() if status != "not checked"}
    kept = {name: status for name, status in found.items() if function_of(name) not in checked}
    return {**kept, **{name: status for name, status in run.items() if function_of(name) in checked}}


def function_of(mutant: str) -> str:
    return mutant.rsplit("__mutmut_", 1)[0]


def module_of(mutant: str) -> str:
    return re.split(r"\.x[_ǁ]", mutant, maxsplit=1)[0]


def equivalent(path: Path = EQUIVALENT) -> dict[str, str]:
    """``<mutant>  # note`` lines of ``path`` (comments and blank lines skipped)."""
    if not path.is_file():
        return {}
    out = {}
    for line in path.read_text().splitlines():
        name, _, reason = line.partition("#")
        if name.strip():
            out[name.strip()] = reason.strip()
    return out


def table(found: dict[str, str], equiv: dict[str, str], by_hand: dict[str, str]) -> list[str]:
    per: dict[str, Counter] = defaultdict(Counter)
    for name, status in found.items():
        if status in ("survived", "timeout") and name in equiv:
            status = "equivalent"
        elif status in ("survived", "segfault", "no tests") and name in by_hand:  # a test named for it kills it
            status = "killed"
        per[module_of(name)][status] += 1
    rows = [
        "| module | mutants | checked | killed | survived | equivalent | no tests | timeout | score of checked |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    total = Counter()
    for module in sorted(per):
        c = per[module]
        total.update(c)
        rows.append(_row(module, c))
    rows.append(_row("**all**", total))
    return rows


def _row(name: str, c: Counter) -> str:
    n = sum(c.values())
    checked = n - c["not checked"]
    scored = checked - c["equivalent"]
    score = f"{100.0 * (c['killed'] + c['timeout']) / scored:.1f} %" if scored else "—"
    return (
        f"| {name} | {n} | {checked} | {c['killed']} | {c['survived']} | {c['equivalent']} | {c['no tests']} | "
        f"{c['timeout']} | {score} |"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--survivors", action="store_true", help="print each surviving mutant's diff")
    parser.add_argument("--results", nargs="+", type=Path, help="saved `mutmut results --all true` outputs")
    parser.add_argument(
        "--fresh", nargs="+", type=Path, default=[], help="saved outputs of complete re-runs: each replaces its modules"
    )
    parser.add_argument(
        "--functions",
        nargs="+",
        type=Path,
        default=[],
        help="saved outputs of runs of some functions' mutants, read last: each replaces the functions it checked",
    )
    args = parser.parse_args()
    found = results(args.results)
    for path in args.fresh:
        found = refreshed(found, parse(path.read_text()))
    for path in args.functions:
        found = functions_refreshed(found, parse(path.read_text()))
    if not found:
        print("no mutmut results: run `mutmut run` first (docs/mutation.md)", file=sys.stderr)
        return 2
    equiv = equivalent()
    by_hand = equivalent(BY_HAND)
    rows = table(found, equiv, by_hand)
    print("\n".join(rows))
    if DOC.is_file():
        text = DOC.read_text()
        if BEGIN in text and END in text:
            head, rest = text.split(BEGIN, 1)
            DOC.write_text(head + BEGIN + "\n" + "\n".join(rows) + "\n" + END + rest.split(END, 1)[1])
    if args.survivors:
        for name, status in sorted(found.items()):
            if status == "survived" and name not in equiv and name not in by_hand:
                diff = subprocess.run(["mutmut", "show", name], capture_output=True, text=True, cwd=ROOT).stdout
                print(f"\n## {name}\n" + "\n".join(ln for ln in diff.splitlines() if ln.startswith(("-", "+"))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
