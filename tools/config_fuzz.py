"""Walk every leaf key of each entry point's composed config, set it to each of a set of bad
values and check what the entry point's own validation (:func:`datt.tasks.validation.validate_config`,
what ``train.py``/``eval.py``/... run before any work) does with it.

    python tools/config_fuzz.py [train eval export deploy tables] [--json out.json]

Every case ends in one of:

* ``refused``: a one-line :class:`~datt.errors.ConfigError` that names the key (or the option
  node that holds it);
* ``accepted``: the value is a legal one for that key (a name or path the key allows, a number
  inside the declared range); the config records exactly the value given;
* ``traceback``: any other exception (a defect);
* ``silent_wrong``: accepted although non-finite (nan/inf) for a key whose value is a number
  (or a list of numbers), or the config records a different value than the one given (a defect);
* ``unbounded``: a numeric key accepted ``1e30`` or ``-1e30``: a range that only says "finite"
  lets a finite value switch off what the key feeds (a geofence of 1e30 m, an age limit of 1e30 s).
  Every numeric key's range is the meaningful one (a defect otherwise).

The key walk (``--walk-table out.md``) sets every numeric key to {0, -1, 1e30, -1e30} and to the two
edges of the range its refusal names (``in [lo, hi]``), which must be accepted.

A key that accepts every bad value has no check at all: the report lists these ``unchecked``
keys (free text by design, such as a wandb project name, or a gap).

The walk is in-process (the same composition and checks the command line runs, without
starting a job), so all entry points take seconds; ``tests/test_config_fuzz.py`` runs it, and
checks a sample through the real command line.
"""

from __future__ import annotations

import argparse
import json
import math
import re
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from datt.configuration import compose
from datt.errors import ConfigError

# entry point -> config name and the command-line arguments its walk starts from
ENTRY_POINTS: dict[str, tuple[str, list[str]]] = {
    "train": ("train", []),
    "fit_rma": ("fit_rma", []),
    "eval": ("eval", []),
    "export": ("export", []),
    "deploy": ("deploy", []),
    "tables": ("tables", ["table=ablation"]),
}
# bad value name -> the value as a command line gives it (parsed as Hydra parses it)
BAD_VALUES: dict[str, str] = {
    "nan": "nan",
    "inf": "inf",
    "minus_one": "-1",
    "zero": "0",
    "huge": "1e30",
    "minus_huge": "-1e30",
    "wrong_type": "not_a_value",
    "empty_list": "[]",
    "missing_file": "/nonexistent/datt-fuzz/missing.pt",
}
# leaves not walked: Hydra's own node and the bookkeeping keys no user sets
SKIPPED_PREFIXES = ("hydra",)


@dataclass
class Case:
    entry: str
    key: str
    bad: str
    outcome: str
    detail: str = ""


@dataclass
class Report:
    cases: list[Case] = field(default_factory=list)

    def counts(self) -> dict[str, dict[str, int]]:
        out: dict[str, dict[str, int]] = {}
        for entry in dict.fromkeys(c.entry for c in self.cases):
            mine = [c for c in self.cases if c.entry == entry]
            tally = Counter(c.outcome for c in mine)
            out[entry] = {
                "keys": len({c.key for c in mine}),
                "cases": len(mine),
                **{k: tally.get(k, 0) for k in ("refused", "accepted", "traceback", "silent_wrong", "unbounded")},
            }
        return out

    def defects(self) -> list[Case]:
        return [c for c in self.cases if c.outcome in ("traceback", "silent_wrong", "unbounded")]

    def unchecked(self) -> dict[str, list[str]]:
        """Entry point -> keys that accepted every bad value."""
        out: dict[str, list[str]] = {}
        for entry in dict.fromkeys(c.entry for c in self.cases):
            keys = dict.fromkeys(c.key for c in self.cases if c.entry == entry)
            out[entry] = [
                k for k in keys if all(c.outcome == "accepted" for c in self.cases if c.entry == entry and c.key == k)
            ]
        return out


def leaf_keys(cfg: DictConfig) -> list[str]:
    """Dotted keys of every leaf (a list counts as one leaf), without interpolations resolved."""
    keys: list[str] = []

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, DictConfig):
            for k in node.keys():
                path = f"{prefix}{k}"
                if path.startswith(SKIPPED_PREFIXES) or str(k) == "_target_":
                    continue
                child = node._get_node(k)
                if isinstance(child, DictConfig) and not child._is_none():
                    walk(child, path + ".")
                else:
                    keys.append(path)

    walk(cfg, "")
    return keys


def parse_value(text: str) -> Any:
    """A command-line value as Hydra's override parser reads it."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create().parse_override(f"k={text}").value()


def _non_finite(value: Any) -> bool:
    items = value if isinstance(value, (list, tuple, ListConfig)) else [value]
    return any(isinstance(v, float) and not math.isfinite(v) for v in items)


def _same(recorded: Any, given: Any) -> bool:
    if isinstance(recorded, ListConfig):
        recorded = OmegaConf.to_container(recorded)
    if isinstance(given, float) and math.isnan(given):
        return isinstance(recorded, float) and math.isnan(recorded)
    if isinstance(recorded, str) and not isinstance(given, str):
        return recorded == str(given)  # a str field keeps the text of a number
    return recorded == given or (isinstance(recorded, (int, float)) and recorded == given)


def is_numeric(value: Any) -> bool:
    """A number, or a non-empty list of numbers (bools are not numbers here)."""
    if isinstance(value, (list, tuple, ListConfig)):
        return bool(value) and all(is_numeric(v) for v in value)
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def try_case(config_name: str, base: DictConfig, key: str, text: str, numeric: bool = True) -> tuple[str, str]:
    from datt.tasks.validation import validate_composed

    cfg = base.copy()
    value = parse_value(text)
    try:
        OmegaConf.update(cfg, key, value, merge=False)
        validate_composed(config_name, cfg, only=key)
    except ConfigError as exc:
        msg = str(exc)
        if "\n" in msg:
            return "traceback", f"multi-line error: {msg!r}"
        top = key.split(".")[0]
        if top not in msg and key.rsplit(".", 1)[-1] not in msg:
            return "traceback", f"error does not name {key}: {msg}"
        return "refused", msg
    except (OmegaConfBaseException, ValueError, TypeError) as exc:
        # OmegaConf's own type check is what Hydra's composition runs: the command line turns it
        # into one line naming the key (datt.configuration.hydra_error_to_config_error)
        if isinstance(exc, OmegaConfBaseException):
            return "refused", f"{key}: {type(exc).__name__} at composition"
        return "traceback", f"{type(exc).__name__}: {exc}"
    except Exception as exc:  # anything else is a defect to report, not to hide
        return "traceback", f"{type(exc).__name__}: {exc}"
    recorded = OmegaConf.select(cfg, key)
    if not _same(recorded, value):
        return "silent_wrong", f"recorded {recorded!r} for {value!r}"
    if numeric and _non_finite(recorded):
        return "silent_wrong", f"non-finite {recorded!r} accepted"
    if numeric and _huge(recorded):
        return "unbounded", f"{recorded!r} accepted: the range has no meaningful bound"
    return "accepted", repr(recorded)


def _huge(value: Any) -> bool:
    items = value if isinstance(value, (list, tuple, ListConfig)) else [value]
    return any(isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) >= 1e29 for v in items)


_RANGE = re.compile(r"in ([\[(])(-?[\d.e+-]+), (-?[\d.e+-]+)([\])])")


def range_edges(message: str) -> list[str]:
    """The closed edges of the range a refusal names (``in [lo, hi]`` / ``(lo, hi]`` ...)."""
    m = _RANGE.search(message)
    if m is None:
        return []
    lo_closed, lo, hi, hi_closed = m.group(1) == "[", m.group(2), m.group(3), m.group(4) == "]"
    return [v for v, closed in ((lo, lo_closed), (hi, hi_closed)) if closed]


# the values of the key walk, in its table's column order
WALK_VALUES = {"0": "0", "-1": "-1", "1e30": "1e30", "-1e30": "-1e30"}


def key_walk(entries: list[str]) -> dict[str, dict[str, dict[str, str]]]:
    """Entry -> numeric key -> value -> outcome (``refused`` / ``accepted`` / a defect), the
    values of :data:`WALK_VALUES` and the edges of the key's declared range (``lo``, ``hi``)."""
    table: dict[str, dict[str, dict[str, str]]] = {}
    for entry in entries:
        config_name, args = ENTRY_POINTS[entry]
        base = compose(config_name, args)
        rows = table.setdefault(entry, {})
        for key in leaf_keys(base):
            value = OmegaConf.select(base, key, throw_on_resolution_failure=False)
            if not is_numeric(value):
                continue
            row = rows.setdefault(key, {})
            edges: list[str] = []
            for name, text in WALK_VALUES.items():
                outcome, detail = try_case(config_name, base, key, text)
                row[name] = outcome
                edges = edges or (range_edges(detail) if outcome == "refused" else [])
            if len(edges) == 2:
                lo, hi = float(edges[0]), float(edges[1])
                for side, text, inward in (("lo", edges[0], 1.0), ("hi", edges[1], -1.0)):
                    row[side] = try_case(config_name, base, key, text)[0]
                    if row[side] == "refused":  # the message rounds the edge (34.9066 for 34.906585...)
                        nudged = float(text) + inward * 1e-4 * (hi - lo)
                        row[side] = try_case(config_name, base, key, repr(nudged))[0]
    return table


def walk_markdown(table: dict[str, dict[str, dict[str, str]]]) -> str:
    """The key walk as Markdown: one table per entry point, R = refused in one line, A = accepted
    (0 and -1 only where the range means them), the range's edges accepted; anything else named."""
    short = {"refused": "R", "accepted": "A"}
    cols = [*WALK_VALUES, "lo", "hi"]
    out = [
        "# The key walk (`python tools/config_fuzz.py --walk-table docs/results/config_key_walk.md`)",
        "",
        "Every numeric key of each entry point set to 0, -1, 1e30, -1e30 and to the two edges of the range",
        "its refusal names. R: refused in one line naming the key; A: accepted (the range means it);",
        "blank: the range has an open edge or names none. No key accepts 1e30 or -1e30: a finite value",
        "cannot switch off what the key feeds (`tests/test_config_fuzz.py`). An edge refused is refused by a rule",
        "across keys: `algo.rollout_steps` at 100,000 with 1024 drones needs more memory than the machine has,",
        "`deploy.flight.hover_s` 0 is shorter than the hover trim's window, `deploy.safety.kill_battery_v` 4.2 V",
        "is above `land_battery_v`, `env.quad.gravity_mps2` 0.1 is below the thrust's lower bound (-9.8 m/s²).",
    ]
    out += [
        "",
        "fires: for a key that feeds a per-tick safety check (`deploy.safety.*`), the check still decides",
        "LAND or KILL just beyond the limit when the limit is at the loosest value its range accepts",
        "(`tests/deploy/test_safety_edges.py`, one case per limit; a limit without a case fails it).",
    ]
    for entry, rows in table.items():
        out += ["", f"## {entry} ({len(rows)} numeric keys)", "", "| key | " + " | ".join(cols) + " | fires |"]
        out.append("|---|" + "---|" * (len(cols) + 1))
        for key, row in rows.items():
            cells = " | ".join(short.get(row.get(c, ""), row.get(c, "")) for c in cols)
            out.append(f"| `{key}` | {cells} | {'yes' if key.startswith('deploy.safety.') else ''} |")
    return "\n".join(out) + "\n"


def walk(entries: list[str], bad_values: dict[str, str] | None = None) -> Report:
    report = Report()
    for entry in entries:
        config_name, args = ENTRY_POINTS[entry]
        base = compose(config_name, args)
        for key in leaf_keys(base):
            numeric = is_numeric(OmegaConf.select(base, key, throw_on_resolution_failure=False))
            for name, text in (bad_values or BAD_VALUES).items():
                outcome, detail = try_case(config_name, base, key, text, numeric)
                report.cases.append(Case(entry, key, name, outcome, detail))
    return report


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("entries", nargs="*", choices=[*ENTRY_POINTS, []], help="default: all")
    parser.add_argument("--json", type=Path, help="write every case here")
    parser.add_argument("--walk-table", type=Path, help="write the key walk of the numeric keys here (Markdown)")
    args = parser.parse_args(argv)
    if args.walk_table:
        args.walk_table.write_text(walk_markdown(key_walk(args.entries or list(ENTRY_POINTS))))
        print(f"wrote {args.walk_table}")
        return 0
    report = walk(args.entries or list(ENTRY_POINTS))
    print(
        f"{'entry':8} {'keys':>5} {'cases':>6} {'refused':>8} {'accepted':>9} {'traceback':>10} "
        f"{'silent_wrong':>13} {'unbounded':>10}"
    )
    for entry, c in report.counts().items():
        print(
            f"{entry:8} {c['keys']:>5} {c['cases']:>6} {c['refused']:>8} {c['accepted']:>9} "
            f"{c['traceback']:>10} {c['silent_wrong']:>13} {c['unbounded']:>10}"
        )
    for case in report.defects():
        print(f"DEFECT {case.entry} {case.key}={BAD_VALUES[case.bad]}: {case.outcome}: {case.detail}")
    for entry, keys in report.unchecked().items():
        if keys:
            print(f"unchecked ({entry}): {', '.join(keys)}")
    if args.json:
        args.json.write_text(json.dumps([c.__dict__ for c in report.cases], indent=1) + "\n")
    return 1 if report.defects() else 0


if __name__ == "__main__":
    sys.exit(main())
