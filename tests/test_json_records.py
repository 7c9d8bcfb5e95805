"""Every JSON file a run writes is strict (no NaN: null) and written atomically: one writer,
:func:`datt.runs.write_json`. The rule is checked on the source, so a new record cannot bypass it."""

import ast
import json
import math
from pathlib import Path

import datt
from datt.runs import write_json

SRC = Path(datt.__file__).parent
# json.dumps for what is not a file: the motion-capture client's protocol lines and its settings
NOT_FILES = {"deploy/mocap_stream.py", "deploy/mocap.py"}


def _json_writes(tree: ast.AST) -> list[int]:
    """Lines that call json.dump / json.dumps (a file's text built by hand)."""
    return [
        node.lineno
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr in ("dump", "dumps")
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == "json"
    ]


def test_no_module_writes_json_but_through_write_json():
    offenders = {}
    for path in sorted(SRC.rglob("*.py")):
        rel = path.relative_to(SRC).as_posix()
        if rel == "runs.py" or rel in NOT_FILES:
            continue
        lines = _json_writes(ast.parse(path.read_text()))
        if lines:
            offenders[rel] = lines
    assert offenders == {}


def test_write_json_is_strict_and_names_values_json_has_no_type_for(tmp_path):
    path = write_json(tmp_path / "m.json", {"a": math.nan, "b": [1.0, math.inf], "c": Path("x")}, default=str)
    text = path.read_text()
    assert json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c))) == {
        "a": None,
        "b": [1.0, None],
        "c": "x",
    }
    assert [p.name for p in tmp_path.iterdir()] == ["m.json"]  # no temporary file left beside it
