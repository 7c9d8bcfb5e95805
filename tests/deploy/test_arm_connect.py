"""The runner's ARM and CONNECT steps (``FlightRunner._arm``, ``_connect``) with stand-ins for the
link, the predictor and the mocap source: what is sent, in which order, what is logged and when
the flight is aborted. No vehicle, no radio."""

from __future__ import annotations

from types import SimpleNamespace

import pytest

from datt.deploy.mocap import MocapSource
from datt.deploy.outcome import Kind
from datt.deploy.runner import UNLOCK_TICKS, FlightRunner, _Abort
from tests.deploy import FakeClock, bookkeeping_runner


class ArmingLink:
    """Records arm requests, the timeout asked of ``wait_armed`` and the setpoints, with the clock
    of each setpoint."""

    def __init__(self, clock, armed: bool):
        self.clock, self.armed, self.sent, self.waited = clock, armed, [], []

    def arm(self, on: bool) -> None:
        self.sent.append(("arm", on))

    def wait_armed(self, timeout_s: float) -> bool:
        self.waited.append(timeout_s)
        return self.armed

    def send_rates(self, *values) -> None:
        self.sent.append(("rates", values, round(self.clock.now_s - 1000.0, 6)))


def arming(tmp_path, monkeypatch, armed: bool, rate_hz: float = 50.0):

    clock = FakeClock()
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    p = SimpleNamespace(arm_timeout_s=1.5, rate_hz=rate_hz)
    return bookkeeping_runner(tmp_path, p=p, link=ArmingLink(clock, armed))


@pytest.mark.parametrize("rate_hz", [50.0, 100.0])
def test_an_armed_vehicle_gets_its_thrust_unlocked_once_per_tick(tmp_path, monkeypatch, rate_hz):
    """Armed within ``arm_timeout_s``: the event says so, then ``UNLOCK_TICKS`` (5) zero-thrust
    setpoints one control period apart (the firmware's thrust lock; one lost packet must not
    leave it locked)."""
    runner = arming(tmp_path, monkeypatch, armed=True, rate_hz=rate_hz)
    runner._arm()
    period = 1.0 / rate_hz
    assert UNLOCK_TICKS == 5 and runner.link.waited == [1.5]
    assert runner.link.sent == [("arm", True)] + [
        ("rates", (0.0, 0.0, 0.0, 0), round(k * period, 6)) for k in range(UNLOCK_TICKS)
    ]
    events = [(e["kind"], e["text"]) for e in runner.log.events]
    assert events == [("phase", "ARM"), ("armed", "the supervisor reports the vehicle armed")]
    assert runner.log.phase == "ARM"


def test_a_vehicle_not_armed_in_time_is_disarmed_and_nothing_flies(tmp_path, monkeypatch):
    """Not reported armed within ``arm_timeout_s``: the disarm request, the outcome ARMING_FAILED
    naming the timeout, the flight aborted before any setpoint."""
    runner = arming(tmp_path, monkeypatch, armed=False)
    with pytest.raises(_Abort) as aborted:
        runner._arm()
    text = "arming failed: the supervisor did not report the vehicle armed within 1.5 s (supervisor.info); nothing flew"
    assert runner.outcome.kind is Kind.ARMING_FAILED and runner.outcome.text == text and str(aborted.value) == text
    assert runner.link.sent == [("arm", True), ("arm", False)]
    assert [(e["kind"], e["text"]) for e in runner.log.events] == [("phase", "ARM"), ("arming failed", text)]


class ConnectingLink:
    round_trip_s = 0.1609  # a latency of 100.45 ms: in ms (x 1000) it rounds to 100, x 1001 would give 101

    def __init__(self):
        self.connected = []

    def connect(self, external_position: bool) -> None:
        self.connected.append(external_position)


class Source(MocapSource):
    def __init__(self, name: str):
        super().__init__()
        self.name, self.calls = name, []

    def subscribe(self, callback) -> None:
        self.calls.append(("subscribe", callback))

    def start(self) -> None:
        self.calls.append(("start",))


class Predictor:
    round_trip_s = None

    @property
    def latency_s(self) -> float:  # half the round trip and a tick, as the real one counts it
        return self.round_trip_s / 2 + 0.02


@pytest.mark.parametrize("source", [None, "none", "sim"])
def test_connect_opens_the_link_and_starts_forwarding_mocap_only_from_a_source(tmp_path, source):
    """CONNECT: the link opened asking for external positions only with a mocap source; the
    predictor gets the measured round trip (its latency logged); a source's frames are forwarded
    from a thread of their own; a configured source is started (the "none" source too: it is how
    that source reports nothing)."""
    import threading

    mocap = None if source is None else Source(source)
    predictor = Predictor()
    runner = bookkeeping_runner(tmp_path, link=ConnectingLink(), mocap=mocap, predictor=predictor, _forwarding=False)
    runner._frame_ready, runner._frame_lock, runner._pending_frame = threading.Event(), threading.Lock(), None
    before = {t.name for t in threading.enumerate()}
    try:
        runner._connect()
        forwarding = source == "sim"
        assert runner.link.connected == [forwarding] and runner.log.phase == "CONNECT"
        assert predictor.round_trip_s == 0.1609
        assert [(e["kind"], e["text"]) for e in runner.log.events] == [
            ("phase", "CONNECT"),
            ("predictor", "latency 100 ms compensated"),
        ]
        assert runner._forwarding is forwarding
        started = [t for t in threading.enumerate() if t.name == "mocap-forward" and t.name not in before]
        assert len(started) == (1 if forwarding else 0) and all(t.daemon for t in started)  # never holds exit
        if mocap is not None:
            want = [("subscribe", runner._forward_frame), ("start",)] if forwarding else [("start",)]
            assert mocap.calls == want
    finally:
        runner._forwarding = False  # the forwarding thread ends within its 50 ms wait


def test_connect_without_a_predictor_logs_no_latency(tmp_path):
    runner = bookkeeping_runner(tmp_path, link=ConnectingLink(), mocap=None, predictor=None)
    runner._connect()
    assert runner.link.connected == [False] and [e["kind"] for e in runner.log.events] == ["phase"]


def test_the_mocap_age_and_position_come_from_the_sources_latest_frame(tmp_path, monkeypatch):
    """No source (or the "none" source): no age, no position; a source without a frame yet: age
    inf, no position; with one: its age on the runner's clock and its position as floats."""
    import math

    clock = FakeClock()
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    frames = []
    source = SimpleNamespace(name="sim", read=lambda: frames[-1] if frames else None)
    runner = bookkeeping_runner(tmp_path, mocap=None)
    assert runner._mocap_age() is None and runner._mocap_position() is None
    runner.mocap = SimpleNamespace(name="none", read=lambda: ((1, 2, 3), None, 999.0))
    assert runner._mocap_age() is None and runner._mocap_position() is None
    runner.mocap = source
    assert runner._mocap_age() == math.inf and runner._mocap_position() is None
    frames.append(((1, 2, 3), None, 999.75))
    assert runner._mocap_age() == 0.25
    position = runner._mocap_position()
    assert position.dtype == float and position.tolist() == [1.0, 2.0, 3.0]


def test_an_event_without_text_has_an_empty_one(tmp_path):
    runner = bookkeeping_runner(tmp_path)
    runner._event("armed")
    assert (runner.log.events[-1]["kind"], runner.log.events[-1]["text"]) == ("armed", "")
