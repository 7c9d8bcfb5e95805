"""The onboard flight's host side without a vehicle (``datt.deploy.onboard_flight.OnboardFlight``):
the app's parameters from the flight's settings, its log read into per-step errors, and what the
host decides from the app's phase. The flights themselves are in ``test_first_flight.py`` and
``test_onboard.py``."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest

from datt.deploy import onboard
from datt.deploy.flight_log import FlightLog
from datt.deploy.onboard_flight import OnboardFlight
from datt.deploy.runner import FlightRunner
from datt.deploy.safety import KILL, LAND, OK
from tests.deploy import FakeClock


class Link:
    """Records the parameters the host writes and an emergency stop."""

    def __init__(self) -> None:
        self.writes: list[tuple[str, float]] = []
        self.stopped = False

    def set_param(self, name: str, value: float) -> None:
        self.writes.append((name, value))

    def emergency_stop(self) -> None:
        self.stopped = True


def host(tmp_path) -> OnboardFlight:
    """The host's bookkeeping alone: no link to a vehicle, settings that all differ."""
    flight = OnboardFlight.__new__(OnboardFlight)
    flight.log = FlightLog(tmp_path)
    flight.outcome = None
    flight.link = Link()
    flight._app = {"samples": {}, "last": None}
    flight._onboard_steps = 0
    flight.p = SimpleNamespace(land_s=2.5, onboard_max_pos_std_m=0.07)
    limits = SimpleNamespace(max_command=59000, app_max_command=61000, max_rate_degps=[700.0, 650.0, 300.0])
    flight.thrust = SimpleNamespace(hover_command=47123.5, slope=1.7e-4, p=limits)
    flight.safety = SimpleNamespace(max_tilt_deg=55.0)
    return flight


def test_every_app_parameter_comes_from_its_own_setting(tmp_path):
    """The origin is the takeoff point (mocap frame); the app lands to 5 cm above the floor, which
    from a start 0.4 m up (a vehicle on a box) is 0.35 m below its origin."""
    settings = host(tmp_path)._app_settings(np.array([1.5, -2.0, 0.4]), n_points=812, steps=600)
    assert settings == {
        "originX": 1.5, "originY": -2.0, "originZ": 0.4, "nPoints": 812, "trackSteps": 600,
        "landZ": pytest.approx(-0.35), "landS": 2.5, "landHoldS": 0.5, "hoverCmd": 47123.5, "slope": 1.7e-4,
        "maxCmd": 61000, "maxRateRoll": 700.0, "maxRatePitch": 650.0, "maxRateYaw": 300.0, "maxTiltDeg": 55.0,
        "maxPosStdM": 0.07,
    }  # fmt: skip


def log_values(phase: int, step: int, err_m: float = 0.0, ref=(0.0, 0.0, 0.0)) -> dict:
    return {
        "datt.phase": phase, "datt.step": step, "datt.errM": err_m,
        "datt.refX": ref[0], "datt.refY": ref[1], "datt.refZ": ref[2],
    }  # fmt: skip


def test_the_apps_log_gives_each_step_its_error(tmp_path):
    """The app counts a step after flying it, so ``errM`` with ``step`` = k is step k − 1's error
    (the first step's is sent with step 1); idle samples give none; landing and done samples
    still do. The latest sample is kept with its reference point."""
    flight = host(tmp_path)
    flight._on_app_log(log_values(onboard.IDLE, 0, 9.0))
    flight._on_app_log(log_values(onboard.IDLE, 3, 9.0))  # stopped mid-track: its count kept, no step flown
    flight._on_app_log(log_values(onboard.ABORTED, 3, 9.0))
    flight._on_app_log(log_values(onboard.TRACK, 0, 9.0))  # started, no step flown yet
    assert flight._app["samples"] == {}
    for k, err in enumerate([0.11, 0.12, 0.13], start=1):
        flight._on_app_log(log_values(onboard.TRACK, k, err, ref=(k, 2.0 * k, 1.0)))
    flight._on_app_log(log_values(onboard.LAND, 4, 0.14))
    flight._on_app_log(log_values(onboard.DONE, 5, 0.15))
    assert flight._app["samples"] == {0: 0.11, 1: 0.12, 2: 0.13, 3: 0.14, 4: 0.15}
    phase, step, ref, _ = flight._app["last"]
    assert (phase, step, ref) == (onboard.DONE, 5, (0.0, 0.0, 0.0))
    flight._onboard_steps = 3  # the errors of the track's steps are the flight's tracking error
    assert flight._track_errors() == [0.11, 0.12, 0.13] and flight._received_errors() == []


def test_what_the_host_decides_from_the_apps_phase(tmp_path):
    """Aborted: KILL, with the outcome saying the app stopped the motors; done: OK, ``datt.run``
    back to 0 and the log says the app landed; refused: LAND with ``datt.run`` back to 0; tracking:
    nothing to decide."""
    flight = host(tmp_path)
    flight._on_app_log(log_values(onboard.TRACK, 3))
    assert flight._app_verdict(1.0, [-1, 0.0]) is None and flight.link.writes == []

    flight._on_app_log(log_values(onboard.ABORTED, 3))
    assert flight._app_verdict(1.0, [3, 0.0]) == KILL
    assert flight.outcome.text == "killed: the onboard app aborted (tilt or a non-finite state/action), motors stopped"
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == ("KILL", flight.outcome.text)

    flight = host(tmp_path)
    flight._on_app_log(log_values(onboard.DONE, 9))
    assert flight._app_verdict(1.0, [9, 0.0]) == OK
    assert flight.link.writes == [("datt.run", 0)]
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == ("onboard", "the app has landed")

    flight = host(tmp_path)
    flight._on_app_log(log_values(onboard.REFUSED, 0))
    assert flight._app_verdict(1.0, [-1, 0.0]) == LAND
    assert flight.link.writes == [("datt.run", 0)]
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == (
        "LAND",
        "the app refused to start (table incomplete or a parameter invalid)",
    )


def watching(tmp_path, app_phase: int | None) -> OnboardFlight:
    """A host watching the app fly, with the configured safety limits (the floor at 5 cm)."""
    import threading

    from datt.configuration import compose
    from datt.deploy.safety import BatteryFilter
    from datt.deploy.schema import deploy_params

    flight = host(tmp_path)
    flight.safety = deploy_params(compose("deploy").deploy)[2]
    flight.p.rate_hz = 50.0
    flight.battery = BatteryFilter(0.0)
    flight.estop = threading.Event()
    flight._mocap_age = lambda: None  # no mocap source
    if app_phase is not None:
        flight._on_app_log(log_values(app_phase, 7, ref=(0.5, 0.0, 1.0)))
    return flight


def state_at(z_m: float, now_s: float, vx_mps: float = 0.0):
    from datt.deploy.link import StateSample

    return StateSample(
        t_s=now_s, pos_m=(0.0, 0.0, z_m), vel_mps=(vx_mps, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), vbat_v=4.0
    )


def test_the_host_kills_a_vehicle_on_the_floor_only_while_the_app_tracks(tmp_path):
    """The floor limit (``track_floor_m``) applies while the app tracks: at 2 cm in TRACK the host
    KILLs; the same height before the app reports tracking (it is still on the ground) is logged
    as a TRACK row with no reference (an idle app's logged one is stale) and no host command."""
    import time

    now = time.monotonic()
    tracking = watching(tmp_path, onboard.TRACK)
    assert tracking.safety.track_floor_m == 0.05
    assert tracking._watch_step(state_at(0.02, now), now, 0.0, np.zeros(3)) == KILL
    assert tracking.link.stopped and tracking.outcome.text.startswith("killed: on the floor while tracking")

    waiting = watching(tmp_path, onboard.IDLE)  # heard, not started yet: its logged reference is stale
    assert waiting._watch_step(state_at(0.02, now), now, 1.5, np.array([1.0, 2.0, 0.0])) is None
    assert not waiting.link.stopped and waiting.outcome is None
    (row,) = waiting.rows
    assert row["phase"] == "TRACK" and row["jitter_ms"] == 1.5 and row["compute_ms"] == 0.0
    assert row["t_s"] == pytest.approx(now - waiting.log.t0) and len(row["ref"]) == 3
    assert all(math.isnan(v) for v in row["ref"] + row["action"] + row["d_hat"]) and row["thrust_cmd"] == 0

    landing = watching(tmp_path, onboard.LAND)
    assert landing._watch_step(state_at(1.0, now), now, 0.0, np.array([1.0, 2.0, 0.0])) is None
    assert landing.rows[-1]["phase"] == "LAND" and landing.rows[-1]["ref"] == [1.5, 2.0, 1.0]


def test_a_land_decision_hands_the_commander_back_and_says_why(tmp_path):
    """Too fast (4 m/s is the limit): the host decides LAND, writes ``datt.run = 0`` (the app hands
    the commander back to the radio's setpoints) and logs the reason as a LAND event."""
    import time

    now = time.monotonic()
    flight = watching(tmp_path, onboard.TRACK)
    assert flight._watch_step(state_at(1.0, now, vx_mps=5.0), now, 0.0, np.zeros(3)) == LAND
    assert flight.link.writes == [("datt.run", 0)] and not flight.link.stopped
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == ("LAND", "speed 5.0 m/s > 4.0 m/s")


def test_the_host_waits_for_the_apps_track_landing_and_hold_and_a_margin(tmp_path):
    """150 steps at 50 Hz (3 s), a 2.5 s landing ramp, the app's hold (the one its parameters
    carry) and the margin: after that, the host stops waiting for the app to report landing."""
    from datt.deploy.onboard_flight import APP_LAND_HOLD_S, APP_LANDED_MARGIN_S

    flight = host(tmp_path)
    flight.p.rate_hz, flight._onboard_steps = 50.0, 150
    assert flight._app_budget_s() == pytest.approx(3.0 + 2.5 + APP_LAND_HOLD_S + APP_LANDED_MARGIN_S)
    assert flight._app_settings(np.zeros(3), 200, 150)["landHoldS"] == APP_LAND_HOLD_S == 0.5
    flight.p.rate_hz = 100.0
    assert flight._app_budget_s() == pytest.approx(1.5 + 2.5 + 0.5 + 2.0)


class StartingLink(Link):
    """A link for the hand-over to the app: the trimmed map and ``datt.run`` written checked (or
    refused with ``refusal``), a fresh state on the host's clock ``clock``, the app's published
    controller id."""

    def __init__(self, clock, refusal: str | None = None, controller_id: int = 6) -> None:
        import threading

        super().__init__()
        self.clock, self.refusal, self.controller_id = clock, refusal, controller_id
        self.link_lost = threading.Event()

    def set_params_checked(self, values: dict) -> None:
        from datt.errors import LinkError

        if self.refusal is not None:
            raise LinkError(self.refusal)
        self.writes.extend(values.items())

    def state(self):
        return state_at(1.0, self.clock.monotonic())

    def has_param(self, name: str) -> bool:
        return True

    def read_param(self, name: str) -> float:
        assert name == "datt.controllerId"
        return float(self.controller_id)


def test_the_host_watches_the_app_once_per_control_tick(tmp_path, monkeypatch):
    """While the app flies the host checks and logs the vehicle's state every control period
    (``1 / rate_hz``, 20 ms at 50 Hz; 10 ms at 100 Hz), on a clock that moves only when it sleeps:
    12 watched ticks one period apart, row to row, when every sleep wakes 1 ms late: each tick
    after the first is logged 1 ms behind its schedule, and the lateness does not add up (the
    schedule is absolute)."""

    for rate_hz in (50.0, 100.0):
        clock = FakeClock(overshoot_s=0.001)
        monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
        flight = watching(tmp_path, onboard.TRACK)
        flight.p.rate_hz, flight._onboard_steps = rate_hz, 500
        flight.thrust = SimpleNamespace(hover_command=47123.5, slope=1.7e-4)
        flight.link = StartingLink(clock)
        calls = []

        def verdict(now, stepping, calls=calls):
            calls.append(now)
            return OK if len(calls) > 12 else None

        flight._app_verdict = verdict
        assert flight._onboard_track(np.zeros(3)) == OK
        times = [row["t_s"] for row in flight.rows]
        assert len(times) == 12
        assert np.diff(times) == pytest.approx([1.0 / rate_hz + 0.001] + [1.0 / rate_hz] * 10)
        assert [row["jitter_ms"] for row in flight.rows] == pytest.approx([0.0] + [1.0] * 11, abs=1e-6)
        assert flight.link.writes == [("datt.hoverCmd", 47123.5), ("datt.slope", 1.7e-4), ("datt.run", 1)]


def test_an_app_start_that_is_not_confirmed_stops_the_app_and_lands_with_the_pid(tmp_path, monkeypatch):
    """The checked write of the trimmed map and ``datt.run = 1`` fails: the host writes
    ``datt.run = 0`` (the app must not start under the PID that lands it), returns LAND and says
    why in the link's own words (without its ``connect:`` prefix)."""

    clock = FakeClock()
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    flight = watching(tmp_path, None)
    flight.thrust = SimpleNamespace(hover_command=47123.5, slope=1.7e-4)
    flight.link = StartingLink(clock, refusal="connect: datt.hoverCmd reads back 45000, not 47123.5")
    assert flight._onboard_track(np.zeros(3)) == LAND
    assert flight.link.writes == [("datt.run", 0)] and flight.rows == []
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == (
        "LAND",
        "the app's start was not confirmed: datt.hoverCmd reads back 45000, not 47123.5",
    )


def test_an_app_under_another_controller_id_is_flown_with_a_warning(tmp_path):
    """The app publishes the id its firmware gives the out-of-tree controller; one that differs
    from the host's table is used (it is the vehicle's own) with a warning naming both."""
    from datt.deploy import firmware

    flight = host(tmp_path)
    flight.link = StartingLink(FakeClock(), controller_id=firmware.CONTROLLER_OOT)
    assert flight._app_controller_id() == firmware.CONTROLLER_OOT and flight.events == []
    flight.link.controller_id = 9
    assert flight._app_controller_id() == 9
    (event,) = flight.events
    assert event["kind"] == "warning"
    table = f"({firmware.FIRMWARE_VERSION})"
    assert event["text"].startswith(f"the app runs under controller 9, the host's table {table} says 6")


def test_the_host_judges_the_low_passed_battery_and_logs_the_raw_one(tmp_path):
    """A sag of one tick to 2.9 V (below the KILL limit, 3.0 V) after 4.0 V: through the 1 s
    low-pass it is ~3.98 V, so the host neither KILLs nor LANDs; the row keeps the raw 2.9 V."""
    import dataclasses
    import time

    from datt.deploy.safety import BatteryFilter

    flight = watching(tmp_path, onboard.TRACK)
    flight.battery = BatteryFilter(flight.safety.battery_filter_s)
    assert flight.safety.battery_filter_s == 1.0 and flight.safety.kill_battery_v == 3.0
    now = time.monotonic()
    assert flight._watch_step(state_at(1.0, now), now, 0.0, np.zeros(3)) is None
    sag = dataclasses.replace(state_at(1.0, now + 0.02), vbat_v=2.9)
    assert flight._watch_step(sag, now + 0.02, 0.0, np.zeros(3)) is None
    assert not flight.link.stopped and flight.link.writes == []
    assert flight.battery.value_v == pytest.approx(4.0 - 1.1 * 0.02)
    assert flight.rows[-1]["vbat"] == 2.9


def handing_over(tmp_path, monkeypatch, steps: int, link_class=None):
    """A host about to hand the flight to a tracking app (``steps`` track steps at 50 Hz) on a
    fake clock that moves only when the host sleeps; returns (flight, clock)."""

    clock = FakeClock()
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    flight = watching(tmp_path, onboard.TRACK)
    flight.p.rate_hz, flight._onboard_steps = 50.0, steps
    flight.thrust = SimpleNamespace(hover_command=47123.5, slope=1.7e-4)
    flight.link = (link_class or StartingLink)(clock)
    return flight, clock


def test_an_app_that_never_reports_landing_is_stopped_after_its_budget(tmp_path, monkeypatch):
    """The app tracks on but never reports DONE: once its budget has passed (5 steps at 50 Hz, the
    2.5 s ramp, the hold and the margin: 5.1 s on a clock that moves only when the host sleeps) the
    host, still hearing the vehicle, stops the app (``datt.run = 0``) and lands, saying so."""
    import datt.deploy.onboard_flight as module

    flight, clock = handing_over(tmp_path, monkeypatch, 5)
    flight._app_verdict = lambda now, stepping: None
    start = clock.now_s
    assert flight._onboard_track(np.zeros(3)) == LAND
    assert clock.now_s - start == pytest.approx(5.1, abs=0.021)
    assert flight.link.writes[-1] == ("datt.run", 0) and not flight.link.stopped
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == (
        "LAND",
        "the app did not report landing within 5.1 s",
    )
    assert flight.outcome is None

    lost = watching(tmp_path, onboard.TRACK)  # the same, the link lost by then: no e-stop, no LAND
    lost.p.rate_hz, lost._onboard_steps = 50.0, 5
    lost.thrust = flight.thrust
    lost.link = StartingLink(clock)
    lost.link.link_lost.set()
    lost._app_verdict = lambda now, stepping: None
    assert lost._onboard_track(np.zeros(3)) == module.LINK_LOST
    text = "during the onboard flight the app flew on by itself; the host cannot confirm it landed"
    assert lost.outcome.text.endswith(text) and (lost.events[-1]["kind"], lost.events[-1]["text"]) == (
        "warning",
        lost.outcome.text,
    )
    assert lost.link.writes == [("datt.hoverCmd", 47123.5), ("datt.slope", 1.7e-4), ("datt.run", 1)]


def test_an_app_that_stops_stepping_while_heard_is_stopped_and_the_pid_takes_over(tmp_path):
    """The app's log still arrives (the link is up) but its step has not moved for more than
    ``APP_STALL_S``: the host stops the app, selects the PID (which honours the radio's rate
    setpoints) and lands, naming the step it stopped at."""
    import time

    from datt.deploy import firmware
    from datt.deploy.onboard_flight import APP_STALL_S

    flight = host(tmp_path)
    flight._on_app_log(log_values(onboard.TRACK, 7, ref=(0.5, 0.25, 1.0)))
    t0 = time.monotonic()
    stepping = [-1, 0.0]
    assert flight._app_verdict(t0, stepping) is None and stepping == [7, t0]
    later = t0 + APP_STALL_S + 0.05
    # the log last heard 0.16 s ago, more than APP_STALL_S / 2: the link may be down, and then the
    # app flies on by itself (it is not taken over)
    flight._app["last"] = flight._app["last"][:3] + (later - 0.16,)
    assert flight._app_verdict(later, stepping) is None and flight.link.writes == []
    flight._app["last"] = flight._app["last"][:3] + (later - 0.14,)  # heard 0.14 s ago, still at step 7
    assert flight._app_verdict(later, stepping) == LAND
    assert flight.link.writes == [("datt.run", 0), ("stabilizer.controller", firmware.CONTROLLER_PID)]
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == (
        "LAND",
        "the app stopped stepping at step 7 (its state is stale: no hook)",
    )


def test_a_failed_reference_upload_refuses_the_flight_saying_why(tmp_path, monkeypatch):
    """The app channel upload gives up (``onboard.Upload.run`` raises): the flight is refused
    before arming with the upload's own reason."""
    from datt.deploy.outcome import Kind
    from datt.deploy.runner import _Abort

    class GivesUp:
        def __init__(self, send, table, clock=None) -> None:
            self.on_packet = None

        def run(self) -> None:
            raise RuntimeError("no acknowledgement for window 3 after 5 tries")

    monkeypatch.setattr(onboard, "Upload", GivesUp)
    flight = host(tmp_path)
    flight.link = SimpleNamespace(send_app_packet=None, on_app_packet=lambda callback: None)
    with pytest.raises(_Abort):
        flight._upload(np.zeros((4, 3)))
    text = "the reference upload to the app failed: no acknowledgement for window 3 after 5 tries"
    assert flight.outcome.kind == Kind.REFUSED and flight.outcome.text.endswith(text)
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == ("preflight failed", text)


def test_an_app_without_a_published_controller_id_is_refused_saying_how_to_rebuild_it(tmp_path):
    """An app built by an older ``datt export`` has no ``datt.controllerId``: the flight is refused
    before arming as a setting of the flight (exit 2), and the refusal says what to do, in full."""
    from datt.deploy.outcome import Kind
    from datt.deploy.runner import _Abort

    flight = host(tmp_path)
    flight.link = SimpleNamespace(has_param=lambda name: False)
    with pytest.raises(_Abort):
        flight._app_controller_id()
    text = (
        "deploy.onboard: the vehicle's app does not publish datt.controllerId (built by an older datt export): "
        "rebuild and flash it (datt export format=app; docs/onboard.md)"
    )
    assert flight.outcome.kind == Kind.REFUSED_SETTING and flight.outcome.text.endswith(text)
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == ("preflight failed", text)


def test_an_operator_e_stop_or_stale_mocap_while_the_app_flies_is_acted_on(tmp_path):
    """The host's checks while the app flies are the off-board flight's: the operator's e-stop
    KILLs (motors stopped), mocap older than ``max_mocap_age_s`` (0.1 s) LANDs (``datt.run = 0``)."""
    import time

    now = time.monotonic()
    stopped = watching(tmp_path, onboard.TRACK)
    stopped.estop.set()
    assert stopped._watch_step(state_at(1.0, now), now, 0.0, np.zeros(3)) == KILL
    assert stopped.link.stopped and stopped.outcome.text == "killed: operator e-stop"

    stale = watching(tmp_path, onboard.TRACK)
    stale._mocap_age = lambda: 0.25
    assert stale._watch_step(state_at(1.0, now), now, 0.0, np.zeros(3)) == LAND
    assert stale.link.writes == [("datt.run", 0)] and not stale.link.stopped
    assert (stale.events[-1]["kind"], stale.events[-1]["text"]) == ("LAND", "mocap stale (250 ms > 100 ms)")


def test_an_app_still_idle_after_the_hand_over_is_stopped_and_the_pid_takes_over(tmp_path):
    """After ``datt.run = 1`` the host sends no setpoints: an app heard still idle (its task not
    running) leaves the vehicle to the commander's watchdog. Idle for more than ``APP_STALL_S``
    while its log arrives, the host stops it, selects the PID and lands, saying so."""
    import time

    from datt.deploy import firmware
    from datt.deploy.onboard_flight import APP_STALL_S

    flight = host(tmp_path)
    flight._on_app_log(log_values(onboard.IDLE, 0))
    t0 = time.monotonic()
    stepping = [-1, t0 - 5.0]
    assert flight._app_verdict(t0, stepping) is None and stepping == [0, t0]
    just_before = t0 + APP_STALL_S - 0.005
    flight._app["last"] = flight._app["last"][:3] + (just_before - 0.01,)
    assert flight._app_verdict(just_before, stepping) is None and flight.link.writes == []
    later = t0 + APP_STALL_S + 0.05
    flight._app["last"] = flight._app["last"][:3] + (later - 0.01,)  # heard 10 ms ago, still idle
    assert flight._app_verdict(later, stepping) == LAND
    assert flight.link.writes == [("datt.run", 0), ("stabilizer.controller", firmware.CONTROLLER_PID)]
    assert (flight.events[-1]["kind"], flight.events[-1]["text"]) == (
        "LAND",
        "the app did not start within 0.3 s of datt.run = 1 (still idle)",
    )


class SilentLink(StartingLink):
    """The hand-over confirmed, then no state from the vehicle at all."""

    def state(self):
        return None


def test_a_vehicle_silent_from_the_hand_over_is_said_once_and_the_app_flies_on(tmp_path, monkeypatch):
    """No fresh state from the first watch on (the radio gone right after ``datt.run = 1``): the
    host says once that the app flies on by itself, logs no row and KILLs nothing."""
    flight, _ = handing_over(tmp_path, monkeypatch, 500, SilentLink)
    calls = []

    def verdict(now, stepping):
        calls.append(now)
        return OK if len(calls) > 10 else None

    flight._app_verdict = verdict
    assert flight._onboard_track(np.zeros(3)) == OK
    said = [(e["kind"], e["text"]) for e in flight.events if e["kind"] != "phase"]
    assert said == [("warning", "no fresh state from the vehicle: the onboard app flies on")]
    assert flight.rows == [] and not flight.link.stopped
