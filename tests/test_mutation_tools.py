"""The mutation-testing helpers: the plugin (tools/mutmut_fastest_first.py) orders only, never the
set; tools/check_by_hand.py applies a mutant exactly where mutmut made it."""

import json
from types import SimpleNamespace

import pytest

from tools import check_by_hand, mutation_report
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


SHOWN = """# datt.sim.quadrotor.xǁQuadrotorParamsǁvalidate__mutmut_22: survived
--- src/datt/sim/quadrotor.py
+++ src/datt/sim/quadrotor.py
@@ -7,4 +7,4 @@
         raise ConfigError(f"{prefix}.latency_steps: must be >= 0, got {self.latency_steps}")
-    if not self.max_thrust_mps2 > 0:
+    if not self.max_thrust_mps2 >= 0:
         raise ConfigError(f"{prefix}.max_thrust_mps2: must be > 0, got {self.max_thrust_mps2}")
"""

METHOD = """class P:
    def validate(self):
        if self.latency_steps < 0:
            raise ConfigError(f"{prefix}.latency_steps: must be >= 0, got {self.latency_steps}")
        if not self.max_thrust_mps2 > 0:
            raise ConfigError(f"{prefix}.max_thrust_mps2: must be > 0, got {self.max_thrust_mps2}")
        if not self.max_rate_radps > 0:
            raise ConfigError(f"{prefix}.max_thrust_mps2: must be > 0, got {self.max_thrust_mps2}")
"""


def test_a_shown_mutant_is_applied_at_its_place_with_the_files_indentation():
    file, old, new = check_by_hand.parse_diff(SHOWN)
    assert file == "src/datt/sim/quadrotor.py" and len(old) == len(new) == 3
    got = check_by_hand.apply(METHOD, old, new)
    assert got == METHOD.replace("if not self.max_thrust_mps2 > 0:", "if not self.max_thrust_mps2 >= 0:")
    # the same line twice with different context: the context picks the place; none or two: refused
    with pytest.raises(ValueError, match="matches 0 places"):
        check_by_hand.apply(METHOD.replace("max_thrust_mps2 > 0", "max_thrust > 0"), old, new)
    with pytest.raises(ValueError, match="matches 2 places"):
        check_by_hand.apply(METHOD + METHOD, old, new)


SHOWN_AFTER_A_DOCSTRING = '''# datt.x.xǁMǁact__mutmut_12: survived
--- src/datt/x.py
+++ src/datt/x.py
@@ -1,4 +1,4 @@
         time, while the adaptation is updated."""
     self.env.set_state(pos_m)
-    self.env.adaptation.update(self.env.sim.state, self.last_cmd, None)
+    self.env.adaptation.update(self.env.sim.state, self.last_cmd, )
     self.env.set_reference_lead(lead_steps)
'''

METHOD_WITH_A_DOCSTRING = '''class M:
    def act(self, pos_m, lead_steps):
        """The command;
        time, while the adaptation is updated."""
        self.env.set_state(pos_m)
        self.env.adaptation.update(self.env.sim.state, self.last_cmd, None)
        self.env.set_reference_lead(lead_steps)
'''


def test_a_mutant_after_a_docstring_keeps_the_methods_indentation():
    """mutmut dedents a method's code but not its docstring's text: each changed line takes the
    indentation of the line it replaces (one offset from the first context line broke the file)."""
    _, old, new = check_by_hand.parse_diff(SHOWN_AFTER_A_DOCSTRING)
    got = check_by_hand.apply(METHOD_WITH_A_DOCSTRING, old, new)
    assert got == METHOD_WITH_A_DOCSTRING.replace("self.last_cmd, None)", "self.last_cmd, )")
    compile(got, "m.py", "exec")


def test_the_by_hand_list_names_a_test_for_every_mutant():
    listed = [line for line in check_by_hand.BY_HAND.read_text().splitlines() if line and not line.startswith("#")]
    got = check_by_hand.entries()
    assert len(got) == len(listed) and all(e.test.startswith("tests/") and "::" in e.test for e in got)


def test_the_report_scores_by_hand_kills_as_killed_and_leaves_equivalents_out():
    found = {
        "datt.sim.frames.x_a__mutmut_1": "killed",
        "datt.sim.frames.x_a__mutmut_2": "survived",  # equivalent
        "datt.sim.frames.x_a__mutmut_3": "survived",  # killed by hand
        "datt.sim.frames.x_a__mutmut_4": "segfault",  # killed by hand
        "datt.sim.frames.x_a__mutmut_5": "timeout",
        "datt.sim.frames.x_a__mutmut_6": "survived",
        "datt.sim.frames.x_a__mutmut_7": "not checked",
        "datt.sim.frames.x_a__mutmut_8": "timeout",  # equivalent (a loaded machine)
    }
    equiv = {"datt.sim.frames.x_a__mutmut_2": "why", "datt.sim.frames.x_a__mutmut_8": "why"}
    by_hand = {"datt.sim.frames.x_a__mutmut_3": "t", "datt.sim.frames.x_a__mutmut_4": "t"}
    rows = mutation_report.table(found, equiv, by_hand)
    # 8 mutants, 7 checked, 3 killed, 1 survived, 2 equivalent, 1 timeout: (3 + 1) / (7 - 2) = 80 %
    assert rows[2] == "| datt.sim.frames | 8 | 7 | 3 | 1 | 2 | 0 | 1 | 80.0 % |"


def test_a_fresh_run_of_a_module_replaces_every_earlier_result_of_it():
    """A module's code changed and was mutated anew: the earlier run's names (other functions,
    other numbers) go, the other modules' results stay."""
    found = {
        "datt.deploy.calibration.xǁCalibrationFlightǁ_square__mutmut_1": "no tests",
        "datt.deploy.calibration.xǁCalibrationFlightǁfly__mutmut_140": "no tests",
        "datt.deploy.calibration.xǁCalibrationFlightǁfly__mutmut_1": "no tests",
        "datt.deploy.thrust.x_fit_hover__mutmut_1": "killed",
    }
    fresh = {
        "datt.deploy.calibration.xǁCalibrationFlightǁfly__mutmut_1": "killed",
        "datt.deploy.calibration.x_square_wave__mutmut_1": "killed",
    }
    assert mutation_report.refreshed(found, fresh) == {"datt.deploy.thrust.x_fit_hover__mutmut_1": "killed", **fresh}


def test_check_by_hand_says_what_it_needs_without_mutmuts_directory(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)  # no mutants/ here
    assert check_by_hand.main([]) == 2
    assert capsys.readouterr().err == (
        "check_by_hand: needs mutmut on PATH and its mutants/ directory here (docs/mutation.md)\n"
    )


@pytest.mark.parametrize(
    "code, stdout, verdict",
    [
        (1, "F\n1 failed", None),
        (0, ". 1 passed", "the test passes on the mutant"),
        (4, "ERROR tests/a/test_b.py - TypeError: unsupported operand\nERROR: found no collectors for x", None),
        (
            4,
            "ERROR tests/a/test_other.py - TypeError: x\nERROR: found no collectors",
            "pytest exit 4: ERROR: found no collectors",
        ),
        (2, "usage: pytest", "pytest exit 2: usage: pytest"),
    ],
    ids=["assertion", "passes", "module-does-not-import", "another-module", "usage"],
)
def test_a_test_fails_on_a_mutant_by_an_assertion_or_by_its_module_no_longer_importing(code, stdout, verdict):
    import subprocess

    run = subprocess.CompletedProcess([], code, stdout=stdout, stderr="")
    assert check_by_hand.verdict(run, "tests/a/test_b.py::test_c") == verdict


def test_a_run_of_some_functions_replaces_only_the_functions_it_checked():
    """A run named the mutants of two functions of the current code: their earlier results go
    (other numbers of the same function too), the run's own unchecked mutants of a function it
    checked count as unchecked, and every function it did not check keeps its earlier results."""
    found = {
        "datt.deploy.runner.xǁFlightRunnerǁ_arm__mutmut_1": "killed",
        "datt.deploy.runner.xǁFlightRunnerǁ_arm__mutmut_60": "survived",
        "datt.deploy.runner.xǁFlightRunnerǁ_trim__mutmut_3": "killed",
        "datt.deploy.thrust.xǁThrustMapǁcommand__mutmut_2": "killed",
    }
    run = {
        "datt.deploy.runner.xǁFlightRunnerǁ_arm__mutmut_1": "survived",
        "datt.deploy.runner.xǁFlightRunnerǁ_arm__mutmut_2": "not checked",
        "datt.deploy.runner.xǁFlightRunnerǁ_lifted_off__mutmut_1": "killed",
        "datt.deploy.runner.xǁFlightRunnerǁ_trim__mutmut_3": "not checked",
        "datt.deploy.thrust.xǁThrustMapǁcommand__mutmut_2": "not checked",
    }
    assert mutation_report.functions_refreshed(found, run) == {
        "datt.deploy.runner.xǁFlightRunnerǁ_arm__mutmut_1": "survived",
        "datt.deploy.runner.xǁFlightRunnerǁ_arm__mutmut_2": "not checked",
        "datt.deploy.runner.xǁFlightRunnerǁ_lifted_off__mutmut_1": "killed",
        "datt.deploy.runner.xǁFlightRunnerǁ_trim__mutmut_3": "killed",
        "datt.deploy.thrust.xǁThrustMapǁcommand__mutmut_2": "killed",
    }
