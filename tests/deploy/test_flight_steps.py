"""The runner's flight sequence (``FlightRunner._flight``) and its end (``_disarm_and_write``)
with stand-ins for every step: the order, what each step hands the next, and what a stop request,
a lost link or a refusal at each phase leaves as the outcome. No vehicle, no radio."""

from __future__ import annotations

import signal
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from datt.deploy.link import LinkError
from datt.deploy.outcome import Kind, Outcome
from datt.deploy.runner import _Abort
from tests.deploy import bookkeeping_runner


def sequenced(tmp_path, fail_at: str | None = None, error: BaseException | None = None):
    """A runner whose steps record themselves in ``runner.steps``; ``error`` is raised at the
    step ``fail_at`` (connect, preflight, build, arm or airborne)."""
    steps = []
    link = SimpleNamespace(emergency_stop=lambda: steps.append("e-stop"))
    p = SimpleNamespace(origin_m=[0.5, -0.5], takeoff_height_m=1.0)
    runner = bookkeeping_runner(tmp_path, p=p, link=link, stop_request=None, outcome=Outcome(Kind.INCOMPLETE))
    runner.steps = steps

    def step(name, phase=None, result=None):
        def run(*args):
            if phase is not None:
                runner._set_phase(phase)
            steps.append((name, *args))
            if name == fail_at:
                raise error
            return result

        return run

    runner._connect = step("connect", "CONNECT")
    runner._preflight = step("preflight", result=np.array([0.6, -0.4, 0.02]))
    runner._arm = step("arm", "ARM")
    runner._disarm_and_write = lambda: steps.append("disarm") or {"outcome": runner.outcome.text}
    build = step("build", result="models")
    airborne = step("airborne", "TRACK")
    return runner, build, airborne


def names(steps):
    return [s if isinstance(s, str) else s[0] for s in steps]


def test_a_flight_runs_its_steps_in_order_and_hands_each_what_it_needs(tmp_path):
    """CONNECT, PREFLIGHT (its phase set by the sequence), the models built for the start relative
    to the hover point (0.5, −0.5, 1), ARM, the flight from the hover point with the built models,
    then DISARM and the log; the summary is what that last step wrote."""
    runner, build, airborne = sequenced(tmp_path)
    assert runner._flight(build, airborne) == {"outcome": runner.outcome.text}
    assert names(runner.steps) == ["connect", "preflight", "build", "arm", "airborne", "disarm"]
    (_, start_rel) = runner.steps[2]
    assert start_rel.tolist() == pytest.approx([0.1, 0.1, -0.98])
    (_, origin, built) = runner.steps[4]
    assert origin.tolist() == [0.5, -0.5, 1.0] and built == "models"
    phases = [e["text"] for e in runner.log.events if e["kind"] == "phase"]
    assert phases == ["CONNECT", "PREFLIGHT", "ARM", "TRACK"]


@pytest.mark.parametrize(
    "fail_at, error, kind, text, estop",
    [
        ("preflight", KeyboardInterrupt(), Kind.STOPPED, "Ctrl-C", False),
        ("build", KeyboardInterrupt("SIGTERM"), Kind.STOPPED, "SIGTERM", False),
        ("airborne", KeyboardInterrupt(), Kind.KILLED, "operator interrupt (Ctrl-C)", True),
        ("airborne", KeyboardInterrupt("SIGTERM"), Kind.KILLED, "operator interrupt (SIGTERM)", True),
        ("preflight", LinkError("link lost: no answer"), Kind.LINK_LOST, "link lost: no answer", False),
        ("airborne", LinkError("link lost: radio gone"), Kind.KILLED, "link lost: radio gone", True),
    ],
    ids=["stop_before_arming", "sigterm_before_arming", "stop_airborne", "sigterm_airborne", "link_lost_before_arming",
         "link_lost_airborne"],
)  # fmt: skip
def test_a_stop_or_a_lost_link_ends_the_flight_by_its_phase(tmp_path, fail_at, error, kind, text, estop):
    """Before arming a stop request ends the flight unarmed (STOPPED, naming the signal; Ctrl-C
    when none is named) and a lost link is LINK_LOST (logged as such); after arming both KILL
    (the motors stopped first). The log is written either way."""
    runner, build, airborne = sequenced(tmp_path, fail_at, error)
    runner._flight(build, airborne)
    assert runner.outcome == Outcome(kind, text)
    assert ("e-stop" in runner.steps) is estop and runner.steps[-1] == "disarm"
    assert "arm" not in names(runner.steps) or fail_at == "airborne"
    if kind is Kind.LINK_LOST:
        assert [(e["kind"], e["text"]) for e in runner.log.events][-1] == ("link lost", text)


def test_a_link_that_fails_at_connect_is_the_commands_error_and_the_log_is_still_written(tmp_path):
    runner, build, airborne = sequenced(tmp_path, "connect", LinkError("no Crazyradio found"))
    with pytest.raises(LinkError, match="^no Crazyradio found$"):
        runner._flight(build, airborne)
    assert names(runner.steps) == ["connect", "disarm"]


def test_a_refusal_ends_the_flight_quietly_with_the_log_written(tmp_path):
    runner, build, airborne = sequenced(tmp_path, "build", _Abort("preflight failed: x"))
    assert runner._flight(build, airborne) == {"outcome": runner.outcome.text}
    assert names(runner.steps) == ["connect", "preflight", "build", "disarm"]


def test_a_stop_requested_while_the_flight_was_prepared_ends_it_before_connecting(tmp_path):
    runner, build, airborne = sequenced(tmp_path)
    runner.stop_request = SimpleNamespace(signal="SIGTERM")
    runner._flight(build, airborne)
    assert names(runner.steps) == ["disarm"] and runner.outcome == Outcome(Kind.STOPPED, "SIGTERM")


class EndingLink:
    """The link at the end of a flight: records the disarm sends and the close; any of them may
    fail."""

    def __init__(self, fail=(), lost_reason=None):
        self.fail, self.calls = set(fail), []
        self.link_lost = threading.Event()
        self.lost_reason = lost_reason
        if lost_reason is not None:
            self.link_lost.set()

    def _call(self, name, *args):
        self.calls.append((name, *args))
        if name in self.fail:
            raise LinkError(f"{name} failed")

    def send_rates(self, *values):
        self._call("rates", *values)

    def arm(self, on):
        self._call("arm", on)

    def close(self):
        self._call("close")


def ending(tmp_path, link, mocap=True):
    writes = []
    runner = bookkeeping_runner(tmp_path, link=link, _forwarding=True)
    runner.mocap = SimpleNamespace(stop=lambda: link.calls.append(("mocap stop",))) if mocap else None

    def write():
        writes.append(signal.getsignal(signal.SIGINT))
        return {"written": len(writes)}

    runner._write = write
    return runner, writes


def test_disarm_sends_zero_thrust_disarms_writes_the_log_then_closes(tmp_path):
    """DISARM: a zero setpoint and the disarm request, the log written (with a second Ctrl-C
    ignored meanwhile) before mocap and the link are closed; forwarding stops."""
    runner, writes = ending(tmp_path, EndingLink())
    handler = signal.signal(signal.SIGINT, signal.default_int_handler)  # (pytest-xdist workers ignore it)
    try:
        assert runner._disarm_and_write() == {"written": 1}
        assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # back afterwards
    finally:
        signal.signal(signal.SIGINT, handler)
    assert runner.link.calls == [("rates", 0.0, 0.0, 0.0, 0), ("arm", False), ("mocap stop",), ("close",)]
    assert writes == [signal.SIG_IGN] and runner._forwarding is False and runner.log.phase == "DISARM"
    assert [e["kind"] for e in runner.log.events] == ["phase"]


def test_a_dead_link_at_disarm_is_logged_and_the_log_still_written(tmp_path):
    runner, writes = ending(tmp_path, EndingLink(fail={"rates"}, lost_reason="no packets for 0.5 s"), mocap=False)
    assert runner._disarm_and_write() == {"written": 1}
    events = [(e["kind"], e["text"]) for e in runner.log.events if e["kind"] != "phase"]
    assert events == [("disarm failed", "rates failed"), ("link lost", "no packets for 0.5 s")]
    assert runner.link.calls == [("rates", 0.0, 0.0, 0.0, 0), ("close",)]


def test_a_close_that_fails_is_logged_and_the_log_written_again_with_it(tmp_path):
    runner, writes = ending(tmp_path, EndingLink(fail={"close"}))
    assert runner._disarm_and_write() == {"written": 2}
    assert [(e["kind"], e["text"]) for e in runner.log.events][-1] == ("close failed", "close failed")


def test_a_flight_without_track_ticks_has_no_tracking_error_and_the_log_gets_the_track_rows(tmp_path):
    """``_write``: no TRACK tick flown: ``track_steps`` 0 and both errors None (not a mean of
    nothing); the outcome and the run's extra keys in the summary; the log is handed the TRACK
    rows (here none) for its plots."""
    handed = []
    runner = bookkeeping_runner(
        tmp_path, link=SimpleNamespace(round_trip_s=0.01), outcome=Outcome(Kind.STOPPED, "SIGTERM")
    )
    runner.summary_extra = {"policy": "p.pt"}
    runner.log.write = lambda summary, track: handed.append(track) or summary
    summary = runner._write()
    assert summary == {
        "outcome": Outcome(Kind.STOPPED, "SIGTERM").text,
        "outcome_kind": Kind.STOPPED.value,
        "track_steps": 0,
        "track_error_m": None,
        "track_error_received_m": None,
        "policy": "p.pt",
    }
    assert handed == [[]]
