"""The config fuzzer (tools/config_fuzz.py): every leaf key of each entry point's composed config
set to bad values. Each case must be refused in one line naming the key, or accepted with
exactly the value given recorded; never a traceback, never a non-finite number accepted, and no
key without any check except the free-text ones listed here."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from tools.config_fuzz import BAD_VALUES, ENTRY_POINTS, try_case, walk

ROOT = Path(__file__).resolve().parents[1]
# keys that take any text by design (labels and names); everything else must refuse something
FREE_TEXT = {"logger.project", "logger.group", "sweep_name", "controller.name", "out_dir"}


def assert_clean(report) -> None:
    assert report.defects() == [], "\n".join(
        f"{c.entry} {c.key}={BAD_VALUES[c.bad]}: {c.outcome}: {c.detail}" for c in report.defects()
    )
    for entry, keys in report.unchecked().items():
        assert set(keys) <= FREE_TEXT, f"{entry}: keys with no check at all: {sorted(set(keys) - FREE_TEXT)}"


def test_training_config_walk_refuses_or_records_every_bad_value():
    report = walk(["train"], {k: BAD_VALUES[k] for k in ("nan", "minus_one", "wrong_type")})
    counts = report.counts()["train"]
    assert counts["keys"] >= 100 and counts["refused"] > 0.9 * counts["cases"]
    assert_clean(report)


def test_the_fuzzer_sees_a_missing_check():
    """The walk can fail: a key whose check is removed shows up as a defect or an unchecked key."""
    from datt.configuration import compose

    base = compose("train", [])
    assert try_case("train", base, "algo.max_grad_norm", "nan")[0] == "refused"
    assert try_case("train", base, "algo.max_grad_norm", "-1")[0] == "refused"
    assert try_case("train", base, "algo.max_grad_norm", "0.3") == ("accepted", "0.3")
    assert try_case("train", base, "train.stages", "7")[0] == "refused"  # was a traceback


@pytest.mark.slow
def test_every_entry_point_config_walk_is_clean():
    report = walk(list(ENTRY_POINTS))
    assert_clean(report)
    assert set(report.counts()) == set(ENTRY_POINTS)


@pytest.mark.slow
@pytest.mark.parametrize(
    "entry, args, line",
    [
        (
            "train.py",
            ["algo.clip_epsilon=-0.2"],
            "error: algo.clip_epsilon: must be a finite number in (0, 1], got -0.2",
        ),
        (
            "train.py",
            ["traj=zigzag", "traj.seg_min_s=nan"],
            "error: traj.seg_min_s: must be a finite number in (0, 3600], got nan",
        ),
        ("eval.py", ["eval.seeds=[]"], "error: eval.seeds: must be a list, each an integer in [0, 4294967295], got []"),
        (
            "eval.py",
            ["controller=mppi", "controller.temperature=inf"],
            "error: controller.temperature: must be a finite",
        ),
        ("deploy.py", ["deploy.server.radio_loss=1.5"], "error: deploy.server.radio_loss: must be a finite number in"),
        ("tables.py", ["ablation", "runs=/nonexistent/sweep"], "error: runs: '/nonexistent/sweep' does not exist"),
    ],
)
def test_bad_values_through_the_command_line_are_one_line_exit_2(tmp_path, entry, args, line):
    proc = subprocess.run(
        [sys.executable, str(ROOT / entry), *args, f"hydra.run.dir={tmp_path / 'run'}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
    )
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith(line), proc.stderr[-2000:]
    assert not (tmp_path / "run").exists()  # refused before any work: no run dir


def _declared_ranges():
    """(where, field, Range) of every schema field (``ranged``) and every ``ARG_RANGES`` entry in
    the package's modules."""
    import dataclasses
    import importlib
    import inspect
    import pkgutil

    import datt
    from datt.configuration import Range

    found, modules = [], 0
    for info in pkgutil.walk_packages(datt.__path__, "datt."):
        if info.name.endswith(".__main__"):
            continue
        module = importlib.import_module(info.name)
        modules += 1
        for name, obj in vars(module).items():
            if not inspect.isclass(obj) or obj.__module__ != module.__name__:
                continue
            if dataclasses.is_dataclass(obj):
                for f in dataclasses.fields(obj):
                    if isinstance(f.metadata.get("range"), Range):
                        found.append((f"{module.__name__}.{name}", f.name, f.metadata["range"]))
            for arg, rng in (getattr(obj, "ARG_RANGES", None) or {}).items():
                found.append((f"{module.__name__}.{name}", arg, rng))
    return found, modules


def test_every_declared_range_has_two_finite_bounds():
    """The class behind "a range that only says finite": no numeric range of any schema or
    ``_target_`` argument is open-ended, so no finite value can switch off what its key feeds."""
    import math

    found, modules = _declared_ranges()
    assert modules > 80 and len(found) > 200, (modules, len(found))  # 93 modules, 237 ranges
    open_ended = [
        f"{where}.{name}: {rng.text()}"
        for where, name, rng in found
        if not rng.choices and not (math.isfinite(rng.low) and math.isfinite(rng.high))
    ]
    assert open_ended == []


@pytest.mark.slow  # every numeric key of every entry point x 6 values: ~30 s
def test_the_key_walk_refuses_huge_values_everywhere_and_accepts_the_ranges_edges():
    from tools.config_fuzz import key_walk

    table = key_walk(list(ENTRY_POINTS))
    # an edge a rule across keys refuses: the memory a rollout needs (on this machine), a hover
    # shorter than the trim's window, a kill voltage above the landing one, a gravity the thrust's
    # lower bound (-9.8 m/s²) would pull down with
    crossed = {
        "algo.rollout_steps": "hi",
        "deploy.flight.hover_s": "lo",
        "deploy.safety.kill_battery_v": "hi",
        "env.quad.gravity_mps2": "lo",
    }
    for entry, rows in table.items():
        for key, row in rows.items():
            assert row["1e30"] == "refused" and row["-1e30"] == "refused", (entry, key, row)
            for side in ("lo", "hi"):
                if side in row and crossed.get(key) != side:
                    assert row[side] == "accepted", (entry, key, side, row)
