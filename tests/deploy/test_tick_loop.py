"""The runner's tick loop (``FlightRunner._tick_loop``) with stand-ins for the link, the model and
the controller: which estimate each tick waits for and uses, what the safety check sees, what is
sent and recorded, and when the loop ends. No vehicle, no radio."""

from __future__ import annotations

import math
import threading
from types import SimpleNamespace

import numpy as np
import pytest

from datt.deploy.link import StateSample
from datt.deploy.runner import FlightRunner
from datt.deploy.safety import KILL, LAND, OK, BatteryFilter
from tests.deploy import FakeClock, bookkeeping_runner

HOVER = (0.0, 0.0, 1.0)


def sample(t_s: float, pos=HOVER, vbat_v: float = 4.0) -> StateSample:
    return StateSample(t_s, pos, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), vbat_v, vehicle_s=t_s - 0.5)


class TickLink:
    """The link as the tick loop uses it: ``states[k]`` is the estimate the k-th tick reads (after
    its wait); the waits and the link-lost flag are recorded."""

    log_period_ms = 10.0

    def __init__(self, states):
        self.states = list(states)
        self.waits: list[tuple[float, float]] = []
        self.link_lost = threading.Event()
        self.stops = 0

    def emergency_stop(self) -> None:
        self.stops += 1

    def wait_state_after(self, t_s: float, timeout_s: float) -> None:
        self.waits.append((t_s, timeout_s))

    def state(self):
        return self.states[len(self.waits) - 1]


class Model:
    """A flight model that records the ticks it advances through."""

    d_hat = (0.0, 0.0, 0.0)

    def __init__(self):
        self.advanced = 0

    def reference(self) -> np.ndarray:
        return np.array([0.1 * self.advanced, 0.0, 0.0])

    def advance(self) -> None:
        self.advanced += 1


def tick_runner(tmp_path, states, phase: str = "HOVER", **settings):
    """A runner whose tick loop flies ``states`` (one per tick) with the shipped safety settings;
    ``_act`` returns a hover command and records its calls, ``_send_tick`` records the sends."""
    from datt.configuration import compose
    from datt.deploy.schema import deploy_params

    p = SimpleNamespace(rate_hz=50.0, late_tick_ms=10.0, **settings)
    runner = bookkeeping_runner(
        tmp_path,
        p=p,
        link=TickLink(states),
        predictor=None,
        battery=BatteryFilter(0.5),
        estop=threading.Event(),
        safety=deploy_params(compose("deploy").deploy)[2],
        acted=[],
        sent=[],
        compute_s=0.0,
        command=[9.81, 0.0, 0.0, 0.0],
    )
    # the stand-in's stamps are not the host's clock: no estimate is stale
    runner.safety.max_state_age_s = runner.safety.kill_state_age_s = math.inf
    runner.log.set_phase(phase)
    runner._mocap_age = lambda: None

    def act(model, state, now, origin, k, predict):
        runner.acted.append((state.t_s, k, predict, origin.tolist(), model, now))
        if runner.compute_s:  # the controller takes this long (on a fake clock)
            runner.clock.sleep(runner.compute_s)  # a test may have swapped in a fake clock
        return np.array(runner.command)

    def send_tick(model, action):
        runner.sent.append(action.tolist())
        return 45000 + len(runner.sent)

    runner._act, runner._send_tick = act, send_tick
    return runner


def test_each_tick_waits_for_an_estimate_newer_than_the_one_it_last_used(tmp_path):
    """The first tick takes any estimate (newer than −inf); each later one waits, at most one log
    period, for one newer than the last it flew on; when none came (the same estimate again) it
    flies on that one and the next tick waits after it again."""
    runner = tick_runner(tmp_path, [sample(1.00), sample(1.01), sample(1.01), sample(1.03)])
    model = Model()
    assert runner._tick_loop(model, 4, np.array([0.5, 0.0, 1.0])) == OK
    assert runner.link.waits == [(-math.inf, 0.01), (1.00, 0.01), (1.01, 0.01), (1.01, 0.01)]
    assert [a[:2] for a in runner.acted] == [(1.00, 0), (1.01, 1), (1.01, 2), (1.03, 3)]
    assert all(a[4] is model and a[3] == [0.5, 0.0, 1.0] for a in runner.acted)


def test_the_check_sees_the_low_passed_battery_and_the_row_keeps_the_raw_one(tmp_path):
    """A sag from 4.0 V to 2.9 V (below ``kill_battery_v`` 3.0 V) for two ticks: the filter
    (τ 0.5 s, 20 ms ticks) passes 4 % of the step per tick, so the check sees ~3.96 V and ~3.91 V
    and flies on; the rows log the raw 2.9 V."""
    runner = tick_runner(tmp_path, [sample(1.00), sample(1.02, vbat_v=2.9), sample(1.04, vbat_v=2.9)])
    assert runner._tick_loop(Model(), 3, np.zeros(3)) == OK
    assert [r["vbat"] for r in runner.rows] == [4.0, 2.9, 2.9]
    assert runner.battery.value_v == pytest.approx(4.0 - 1.1 * (1 - 0.96**2))
    assert [r["decision"] for r in runner.rows] == [OK] * 3 and runner.link.stops == 0


def test_each_tick_records_what_it_flew_and_advances_the_model(tmp_path):
    """One row per tick: the estimate as measured (world frame), the model's reference moved to
    the origin, the command and the thrust sent, the decision and the phase; the model advances
    once per tick, after its row."""
    runner = tick_runner(tmp_path, [sample(1.00, pos=(0.5, 0.2, 1.1)), sample(1.02, pos=(0.6, 0.2, 1.1))])
    model = Model()
    assert runner._tick_loop(model, 2, np.array([0.5, 0.0, 1.0])) == OK
    assert model.advanced == 2 and runner.sent == [[9.81, 0.0, 0.0, 0.0]] * 2
    assert [r["pos"] for r in runner.rows] == [[0.5, 0.2, 1.1], [0.6, 0.2, 1.1]]
    assert [r["ref"] for r in runner.rows] == [pytest.approx([0.5, 0.0, 1.0]), pytest.approx([0.6, 0.0, 1.0])]
    assert [r["thrust_cmd"] for r in runner.rows] == [45001, 45002]
    assert [(r["phase"], r["decision"], r["action"]) for r in runner.rows] == [("HOVER", OK, [9.81, 0.0, 0.0, 0.0])] * 2
    assert [r["arrived_s"] + runner.log.t0 for r in runner.rows] == pytest.approx([1.00, 1.02])
    assert all(r["compute_ms"] >= 0.0 and r["sched_t_s"] <= r["t_s"] for r in runner.rows)


def test_a_decision_that_ends_the_phase_comes_before_the_tick_is_sent(tmp_path):
    """Outside the geofence (by 0.2 m, within its margin): LAND ends the loop on that tick, nothing
    sent or recorded for it. Where landing is not allowed (already landing) the tick is flown and
    the reason is a warning."""
    outside = (2.2, 0.0, 1.0)
    runner = tick_runner(tmp_path, [sample(1.00), sample(1.02, pos=outside), sample(1.04)])
    assert runner._tick_loop(Model(), 3, np.zeros(3)) == LAND
    assert len(runner.sent) == len(runner.rows) == 1
    assert runner.log.events[-1]["kind"] == "LAND" and "outside geofence" in runner.log.events[-1]["text"]

    landing = tick_runner(tmp_path, [sample(1.00), sample(1.02, pos=outside), sample(1.04)], phase="LAND")
    assert landing._tick_loop(Model(), 3, np.zeros(3), allow_land=False) == OK
    assert len(landing.sent) == len(landing.rows) == 3 and landing.rows[1]["decision"] == LAND
    assert [e["kind"] for e in landing.log.events if e["kind"] != "phase"] == ["warning"]


@pytest.mark.parametrize("phase, killed", [("TRACK", True), ("HOVER", False)])
def test_the_floor_limit_applies_while_tracking_only(tmp_path, phase, killed):
    """2 cm up (below ``track_floor_m`` 5 cm): a KILL (motors stopped, nothing sent) in TRACK; in
    HOVER (the takeoff, the landing) the vehicle is meant to be near the floor."""
    runner = tick_runner(tmp_path, [sample(1.00, pos=(0.0, 0.0, 0.02))], phase=phase)
    assert runner._tick_loop(Model(), 1, np.zeros(3)) == (KILL if killed else OK)
    assert (runner.link.stops, len(runner.sent)) == ((1, 0) if killed else (0, 1))


@pytest.mark.parametrize("source", ["estop", "link_lost"])
def test_an_e_stop_or_a_lost_link_kills_on_the_next_tick(tmp_path, source):
    """The operator's e-stop and the link's lost flag are read each tick: set, the tick KILLs."""
    runner = tick_runner(tmp_path, [sample(1.00)])
    (runner.estop if source == "estop" else runner.link.link_lost).set()
    assert runner._tick_loop(Model(), 1, np.zeros(3)) == KILL
    assert runner.link.stops == 1 and runner.sent == []
    assert runner.outcome.text == {"estop": "killed: operator e-stop", "link_lost": "killed: link lost"}[source]


def test_stale_mocap_lands(tmp_path):
    """The mocap's age is the configured source's, read each tick: 0.3 s (> 0.1 s) lands."""
    runner = tick_runner(tmp_path, [sample(1.00), sample(1.02)])
    ages = iter([0.01, 0.3])
    runner._mocap_age = lambda: next(ages)
    assert runner._tick_loop(Model(), 2, np.zeros(3)) == LAND
    assert runner.log.events[-1]["text"] == "mocap stale (300 ms > 100 ms)"


@pytest.mark.parametrize("phase, with_predictor", [("TRACK", True), ("HOVER", True), ("TRACK", False)])
def test_the_predictor_serves_the_tracking_phase_and_sets_the_send_slot_once(tmp_path, phase, with_predictor):
    """With a latency predictor, the TRACK ticks act on its prediction, and after the first tick the
    schedule moves to the predictor's send slot (asked for the point half a tick before the next
    tick); the PID's phases fly the raw loop and keep the schedule."""
    import time

    slots = []

    def send_slot(t_s: float) -> float:
        slots.append(t_s)
        return t_s

    runner = tick_runner(tmp_path, [sample(1.00), sample(1.02), sample(1.04)], phase=phase)
    runner.predictor = SimpleNamespace(send_slot=send_slot) if with_predictor else None
    start = time.monotonic()
    assert runner._tick_loop(Model(), 3, np.zeros(3)) == OK
    predicted = phase == "TRACK" and with_predictor
    assert [a[2] for a in runner.acted] == [predicted] * 3
    assert len(slots) == (1 if predicted else 0)
    if predicted:  # tick 0 scheduled at the start: the slot asked for is 10 ms after it
        assert slots[0] - 0.01 == pytest.approx(runner.rows[0]["sched_t_s"] + runner.log.t0, abs=1e-9)
        assert slots[0] - 0.01 >= start


def test_each_tick_is_timed_against_an_absolute_schedule(tmp_path, monkeypatch):
    """On a clock that only sleeping moves, each sleep waking 1 ms late: every tick after the first
    runs 1 ms behind its schedule (the lateness does not add up), the schedule is one period
    apart, and a tick that takes no time has no compute time."""

    clock = FakeClock(overshoot_s=0.001)
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    runner = tick_runner(tmp_path, [sample(1.00), sample(1.02), sample(1.04)])
    assert runner._tick_loop(Model(), 3, np.zeros(3)) == OK
    assert [a[5] for a in runner.acted] == pytest.approx([1000.0, 1000.021, 1000.041])  # each tick's now
    assert [r["jitter_ms"] for r in runner.rows] == pytest.approx([0.0, 1.0, 1.0], rel=1e-6, abs=1e-9)
    assert np.diff([r["sched_t_s"] for r in runner.rows]) == pytest.approx([0.02, 0.02], rel=1e-9)
    assert [r["compute_ms"] for r in runner.rows] == [0.0] * 3
    assert clock.now_s == pytest.approx(1000.0 + 3 * 0.02 + 0.001)  # slept to the last slot, 1 ms late


def test_a_tick_without_an_estimate_kills(tmp_path):
    """No estimate at all (none has arrived): the tick KILLs ("no state estimate") and sends
    nothing; the controller is not asked."""
    runner = tick_runner(tmp_path, [None])
    assert runner._tick_loop(Model(), 1, np.zeros(3)) == KILL
    assert runner.outcome.text == "killed: no state estimate"
    assert (runner.link.stops, runner.sent, runner.acted) == (1, [], [])


def test_a_row_holds_every_column_of_the_tick(tmp_path, monkeypatch):
    """The row of a tick, whole, on a fake clock: flight-log times (the tick, its schedule, the
    estimate's arrival) from the log's start, the vehicle's own stamp, the estimate as measured,
    the reference in the world frame, the action as floats, the thrust sent, the model's
    disturbance estimate, the raw battery, the decision and the timing."""

    clock = FakeClock()
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    quat = (0.9950042, 0.0998334, 0.0, 0.0)  # 11.5° of roll
    estimate = StateSample(999.99, (0.3, -0.2, 1.1), (0.1, 0.2, -0.3), quat, 3.9, vehicle_s=12.5)
    runner = tick_runner(tmp_path, [estimate], phase="TRACK")
    model = Model()
    model.d_hat = (0.01, -0.02, 0.03)
    assert runner._tick_loop(model, 1, np.array([0.5, 0.0, 1.0])) == OK
    (row,) = runner.rows
    t0 = runner.log.t0
    assert row == {
        "t_s": pytest.approx(1000.0 - t0),
        "sched_t_s": pytest.approx(1000.0 - t0),
        "arrived_s": pytest.approx(999.99 - t0),
        "vehicle_s": 12.5,
        "phase": "TRACK",
        "pos": [0.3, -0.2, 1.1],
        "vel": [0.1, 0.2, -0.3],
        "quat": list(quat),
        "ref": pytest.approx([0.5, 0.0, 1.0]),
        "action": [9.81, 0.0, 0.0, 0.0],
        "thrust_cmd": 45001,
        "d_hat": [0.01, -0.02, 0.03],
        "vbat": 3.9,
        "decision": OK,
        "jitter_ms": 0.0,
        "compute_ms": 0.0,
    }
    assert all(type(a) is float for a in row["action"])


class ActingModel:
    """A model that records what ``act`` is given and returns a fixed command."""

    d_hat = (0.01, 0.0, -0.02)

    def __init__(self):
        self.given = []
        self.last_state_t = None  # no estimate answered yet

    def act(self, pos, vel, quat, predicted, lead_steps):
        self.given.append((np.asarray(pos).tolist(), vel, quat, predicted, lead_steps))
        return np.array([9.0, 0.1, -0.1, 0.0])


@pytest.mark.parametrize("predict", [False, True])
def test_the_controller_flies_relative_to_the_origin_on_the_estimate_or_its_prediction(tmp_path, predict):
    """``_act``: the model gets the estimate moved to the controller frame (minus ``origin``); with
    the predictor, also the prediction (its position moved likewise) for the estimate's stamps and
    the model's disturbance estimate, and the lead in ticks (lead 30 ms at 50 Hz: 1.5). The
    calibration's excitation at tick ``k`` adds to the thrust only."""
    seen = []

    def predict_state(now, t_s, pos, vel, quat, d_hat, vehicle_s):
        seen.append((now, t_s, pos, vel, quat, d_hat, vehicle_s))
        return (1.6, 0.1, 1.2), (0.5, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0)

    runner = tick_runner(tmp_path, [])
    del runner._act  # the runner's own
    runner.predictor = SimpleNamespace(predict=predict_state, lead_at=lambda now: 0.03 if now == 7.0 else None)
    runner._excitation = None
    model, origin = ActingModel(), np.array([1.5, 0.0, 1.0])
    estimate = sample(6.98, pos=(1.55, 0.05, 1.1))
    action = runner._act(model, estimate, 7.0, origin, 3, predict)
    assert action.tolist() == [9.0, 0.1, -0.1, 0.0]
    ((pos, vel, quat, predicted, lead_steps),) = model.given
    assert pos == pytest.approx([0.05, 0.05, 0.1]) and (vel, quat) == (estimate.vel_mps, estimate.quat)
    if predict:
        assert seen == [(7.0, 6.98, estimate.pos_m, estimate.vel_mps, estimate.quat, model.d_hat, 6.48)]
        assert predicted[0].tolist() == pytest.approx([0.1, 0.1, 0.2]) and predicted[1:] == (
            (0.5, 0.0, 0.0),
            (1.0, 0.0, 0.0, 0.0),
        )
        assert lead_steps == pytest.approx(1.5)
    else:
        assert (seen, predicted, lead_steps) == ([], None, 0.0)
    runner._excitation = lambda k: 0.25 * k
    assert runner._act(ActingModel(), estimate, 7.0, origin, 3, predict).tolist() == [9.75, 0.1, -0.1, 0.0]


@pytest.mark.parametrize("result, landed", [(LAND, True), (OK, False), (KILL, False)])
def test_a_phase_that_ends_in_land_is_followed_by_the_landing(tmp_path, result, landed):
    """``_fly_phase``: the phase's ticks for its duration (1.23 s at 50 Hz: 62 ticks), then the
    landing from the same origin if (and only if) the phase ended in LAND; its result returned."""
    runner = tick_runner(tmp_path, [])
    calls = []
    runner._tick_loop = lambda model, steps, origin: calls.append(("ticks", model, steps, origin.tolist())) or result
    runner._land = lambda origin: calls.append(("land", origin.tolist()))
    assert runner._fly_phase("model", 1.23, np.array([0.0, 0.5, 1.0])) == result
    assert calls == [("ticks", "model", 62, [0.0, 0.5, 1.0])] + ([("land", [0.0, 0.5, 1.0])] if landed else [])


@pytest.mark.parametrize("duration_s, rate_hz, steps", [(None, 50.0, 250), (None, 100.0, 500), (1.23, 50.0, 62)])
def test_a_phase_lasts_its_duration_or_the_references_episode(tmp_path, duration_s, rate_hz, steps):
    """``_steps``: the reference's episode (250 env steps of 20 ms: 5 s) or the given duration, in
    ticks of the flight's rate, rounded to the nearest."""
    runner = tick_runner(tmp_path, [])
    runner.p.rate_hz = rate_hz
    model = SimpleNamespace(env=SimpleNamespace(params=SimpleNamespace(episode_steps=250), dt_s=0.02))
    assert runner._steps(model, duration_s) == steps


def test_a_ticks_compute_time_is_from_its_estimate_to_its_row(tmp_path, monkeypatch):
    """A controller that takes 3 ms (on a fake clock): the row's compute time is 3 ms, in ms."""

    monkeypatch.setattr(FlightRunner, "clock", FakeClock())
    runner = tick_runner(tmp_path, [sample(1.00), sample(1.02)])
    runner.compute_s = 0.003
    assert runner._tick_loop(Model(), 2, np.zeros(3)) == OK
    assert [r["compute_ms"] for r in runner.rows] == pytest.approx([3.0, 3.0], rel=1e-6)


def test_the_check_sees_the_command_about_to_be_sent(tmp_path):
    """A command beyond the thrust limit (50 > 39.81 m/s²): the check lands before it is sent."""
    runner = tick_runner(tmp_path, [sample(1.00)])
    runner.command = [50.0, 0.0, 0.0, 0.0]
    assert runner._tick_loop(Model(), 1, np.zeros(3)) == LAND
    assert runner.sent == [] and runner.log.events[-1]["text"] == "command out of range"
