"""The mutation-testing helper plugin (tools/mutmut_fastest_first.py): order only, never the set."""

import json
from types import SimpleNamespace

import pytest

from tools import mutmut_fastest_first as plugin


@pytest.fixture
def in_dir(tmp_path, monkeypatch):
    monkeypatch.delenv("MUTANT_UNDER_TEST", raising=False)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(plugin, "_durations", None)  # the plugin reads the stats once per process
    return tmp_path


def items(*nodeids):
    return [SimpleNamespace(nodeid=n) for n in nodeids]


def test_tests_run_fastest_first_and_unknown_ones_last_in_their_order(in_dir):
    stats = {"duration_by_test": {"t.py::slow": 3.0, "t.py::fast": 0.01, "t.py::mid": 0.5}}
    (in_dir / "mutmut-stats.json").write_text(json.dumps(stats))
    got = items("t.py::new_b", "t.py::slow", "t.py::new_a", "t.py::mid", "t.py::fast")
    plugin.pytest_collection_modifyitems(None, got)
    assert [i.nodeid for i in got] == ["t.py::fast", "t.py::mid", "t.py::slow", "t.py::new_b", "t.py::new_a"]


@pytest.mark.parametrize("stats", [None, "not json", "{}"], ids=["missing", "unreadable", "no_durations"])
def test_without_recorded_durations_the_order_is_left_alone(in_dir, stats):
    if stats is not None:
        (in_dir / "mutmut-stats.json").write_text(stats)
    got = items("t.py::b", "t.py::a")
    plugin.pytest_collection_modifyitems(None, got)
    assert [i.nodeid for i in got] == ["t.py::b", "t.py::a"]


def test_a_mutants_own_module_tests_come_first_then_its_package_then_the_rest(in_dir, monkeypatch):
    stats = {"duration_by_test": {"tests/deploy/test_a.py::x": 0.001, "tests/sim/test_frames.py::y": 0.01}}
    (in_dir / "mutmut-stats.json").write_text(json.dumps(stats))
    monkeypatch.setenv("MUTANT_UNDER_TEST", "datt.sim.quadrotor.xǁQuadrotorǁstep__mutmut_3")
    got = items(
        "tests/deploy/test_a.py::x",
        "tests/sim/test_frames.py::y",
        "tests/sim/test_quadrotor.py::slow_unknown",
        "tests/train/test_quadrotor_use.py::z",
    )
    plugin.pytest_collection_modifyitems(None, got)
    assert [i.nodeid for i in got] == [
        "tests/sim/test_quadrotor.py::slow_unknown",
        "tests/train/test_quadrotor_use.py::z",
        "tests/sim/test_frames.py::y",
        "tests/deploy/test_a.py::x",
    ]
    assert plugin.nearness("tests/train/test_ppo_wiring.py::t", "datt.train.ppo.x_crash_rate__mutmut_1") == 0
    assert plugin.nearness("tests/train/test_rma.py::t", "datt.train.ppo.x_crash_rate__mutmut_1") == 1
    assert plugin.nearness("tests/sim/test_frames.py::t", "") == 2
