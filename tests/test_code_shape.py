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


TORCH_FACTORIES = {"zeros", "ones", "empty", "tensor", "arange", "full", "rand", "randn", "randint", "linspace", "eye"}
TORCH_FACTORIES |= {"as_tensor"}
# Modules that run on the CPU by design: the vehicle's side (link, simulated Crazyflie, flight log,
# predictor) and the exports.
CPU_BY_DESIGN = ("deploy/", "export/")
# Tensors built on the host as construction data and moved where they are used (a module's
# parameters and buffers follow its .to(device); reference tables and MPPI's noise move at
# sample/bind; the L1 error dynamics are an analysis): file -> how many such calls it holds.
HOST_CONSTRUCTION = {
    "adapt/l1.py": 2,  # error_dynamics: float64 analysis matrices
    "adapt/rma.py": 3,  # input scales (a registered buffer) and the conv's size probe
    "control/mppi.py": 1,  # noise_std, moved to env.device at reset
    "envs/tracking.py": 3,  # set_state: as_tensor then copy_ into the device state
    "policies/networks.py": 6,  # initial weights and buffers of an nn.Module
    "refs/composite.py": 1,  # family weights, moved to the generator's device at sample
    "refs/csv.py": 1,  # the file's points, moved to the query's device at sample
    "sim/frames.py": 1,  # the rotation's quadratic form, .to(q) where used
}


def factories_without_device(root: Path) -> dict[str, int]:
    """Per file under ``root``: calls of a ``torch`` factory with neither ``device=`` nor ``**kw``."""
    counts: dict[str, int] = {}
    for path in sorted(root.rglob("*.py")):
        rel = str(path.relative_to(root))
        for node in ast.walk(ast.parse(path.read_text())):
            f = node.func if isinstance(node, ast.Call) else None
            if (
                isinstance(f, ast.Attribute)
                and isinstance(f.value, ast.Name)
                and f.value.id == "torch"
                and f.attr in TORCH_FACTORIES
                and not any(k.arg in ("device", None) for k in node.keywords)
            ):
                counts[rel] = counts.get(rel, 0) + 1
    return counts


def test_no_tensor_is_created_on_a_hard_coded_device():
    """env.device=cuda moves the env, policy, PPO, evaluation and MPPI: a factory call without a
    device outside the CPU-by-design modules is construction data counted above, or a bug."""
    found = {f: n for f, n in factories_without_device(SRC).items() if not f.startswith(CPU_BY_DESIGN)}
    assert found == HOST_CONSTRUCTION


def test_the_device_rule_finds_a_factory_call_without_a_device(tmp_path):
    (tmp_path / "m.py").write_text(
        "import torch\na = torch.zeros(3)\nb = torch.zeros(3, device=d)\nc = torch.ones(2, **kw)\n"
    )
    assert factories_without_device(tmp_path) == {"m.py": 1}
