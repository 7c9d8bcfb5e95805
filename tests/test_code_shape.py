"""The code's shape rules that a reviewer would otherwise check by eye."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "datt"
MAX_FUNCTION_LINES = 60
ONE_PIECE = "# one piece:"  # the comment a longer function carries, saying why it is not split


def long_functions(root: Path, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """``path:line name (n lines)`` of every function in ``root`` longer than ``limit`` lines
    (decorators excluded, docstring included) whose body does not open with a ``# one piece:`` comment."""
    found = []
    for path in sorted(root.rglob("*.py")):
        text = path.read_text()
        lines = text.splitlines()
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            n = node.end_lineno - node.lineno + 1
            head = "\n".join(lines[node.lineno - 1 : node.lineno + 8])
            if n > limit and ONE_PIECE not in head:
                found.append(f"{path.relative_to(root.parent)}:{node.lineno} {node.name} ({n} lines)")
    return found


def test_no_function_is_longer_than_the_limit_without_saying_why():
    assert long_functions(SRC) == []


def test_the_length_rule_finds_a_long_function_and_accepts_one_that_says_why(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    (tmp_path / "pkg").mkdir()
    (tmp_path / "pkg" / "long.py").write_text(f"def long():\n{body}\n\n\ndef short():\n    return 1\n")
    why = f"def why():\n    {ONE_PIECE} a state machine read top to bottom\n{body}\n"
    (tmp_path / "pkg" / "why.py").write_text(why)
    assert long_functions(tmp_path / "pkg") == [f"pkg/long.py:1 long ({MAX_FUNCTION_LINES + 1} lines)"]


ISSUE_REFERENCE = re.compile(r"\b(issue|PR|pull request)\s*#?\d+|\B#\d{2,}\b", re.IGNORECASE)
DATED = re.compile(r"\b20\d\d-\d\d-\d\d\b")


@pytest.mark.parametrize("pattern", [ISSUE_REFERENCE, DATED], ids=["issue-numbers", "dates"])
def test_code_and_configs_carry_no_issue_numbers_or_dated_results(pattern):
    """Provenance lives in checkpoint lineage and docs/results/, not in code, configs or docstrings."""
    hits = []
    for path in sorted(SRC.rglob("*")):
        if path.suffix in {".py", ".yaml", ".c", ".h"}:
            for k, line in enumerate(path.read_text().splitlines(), 1):
                if pattern.search(line):
                    hits.append(f"{path.relative_to(SRC.parent)}:{k}: {line.strip()}")
    assert hits == []


def test_the_history_patterns_match_what_they_are_meant_to():
    assert ISSUE_REFERENCE.search("# see issue 37") and ISSUE_REFERENCE.search("fixed in #123")
    assert not ISSUE_REFERENCE.search("thrust[0] += 1")
    assert DATED.search("measured 2026-12-03") and not DATED.search("version 2026.08")
