"""Mutation-testing report of the core (``docs/mutation.md``) from the last ``mutmut run``.

Run from the repository root after ``mutmut run`` (see docs/mutation.md):

    python tools/mutation_report.py            # prints the table and rewrites docs/mutation.md's table
    python tools/mutation_report.py --survivors  # also lists every surviving mutant's diff

Mutants listed in ``docs/mutation-equivalent.txt`` (``<mutant name>  # reason``) are equivalent:
no test can tell them from the original, so the score leaves them out.
Score = killed / (all - equivalent), per module; the goal is >= 90 % in each.
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
BEGIN, END = "<!-- mutation-table:begin -->", "<!-- mutation-table:end -->"


def results() -> dict[str, str]:
    out = subprocess.run(["mutmut", "results", "--all", "true"], capture_output=True, text=True, cwd=ROOT, check=True)
    found = {}
    for line in out.stdout.splitlines():
        name, sep, status = line.strip().rpartition(": ")
        if sep and "__mutmut_" in name:
            found[name] = status
    return found


def module_of(mutant: str) -> str:
    return re.split(r"\.x[_ǁ]", mutant, maxsplit=1)[0]


def equivalent() -> dict[str, str]:
    if not EQUIVALENT.is_file():
        return {}
    out = {}
    for line in EQUIVALENT.read_text().splitlines():
        name, _, reason = line.partition("#")
        if name.strip():
            out[name.strip()] = reason.strip()
    return out


def table(found: dict[str, str], equiv: dict[str, str]) -> list[str]:
    per: dict[str, Counter] = defaultdict(Counter)
    for name, status in found.items():
        per[module_of(name)]["equivalent" if name in equiv and status == "survived" else status] += 1
    rows = [
        "| module | mutants | killed | survived | equivalent | no tests | timeout | score |",
        "|---|---|---|---|---|---|---|---|",
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
    scored = n - c["equivalent"]
    score = 100.0 * c["killed"] / scored if scored else 100.0
    return (
        f"| {name} | {n} | {c['killed']} | {c['survived']} | {c['equivalent']} | {c['no tests']} | "
        f"{c['timeout']} | {score:.1f} % |"
    )


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--survivors", action="store_true", help="print each surviving mutant's diff")
    args = parser.parse_args()
    found = results()
    if not found:
        print("no mutmut results: run `mutmut run` first (docs/mutation.md)", file=sys.stderr)
        return 2
    equiv = equivalent()
    rows = table(found, equiv)
    print("\n".join(rows))
    if DOC.is_file():
        text = DOC.read_text()
        if BEGIN in text and END in text:
            head, rest = text.split(BEGIN, 1)
            DOC.write_text(head + BEGIN + "\n" + "\n".join(rows) + "\n" + END + rest.split(END, 1)[1])
    if args.survivors:
        for name, status in sorted(found.items()):
            if status == "survived" and name not in equiv:
                diff = subprocess.run(["mutmut", "show", name], capture_output=True, text=True, cwd=ROOT).stdout
                print(f"\n## {name}\n" + "\n".join(ln for ln in diff.splitlines() if ln.startswith(("-", "+"))))
    return 0


if __name__ == "__main__":
    sys.exit(main())
