"""The runner's preflight (``FlightRunner._preflight``) with stand-ins for the link and the mocap
source on a clock that only sleeping moves: what it waits for, and every reason it refuses,
word for word. No vehicle, no radio."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest

from datt.deploy import firmware
from datt.deploy.link import StateSample
from datt.deploy.runner import FlightRunner, _Abort
from tests.deploy import FakeClock, bookkeeping_runner

LEVEL = (1.0, 0.0, 0.0, 0.0)
TILT_11 = (math.cos(math.radians(5.5)), math.sin(math.radians(5.5)), 0.0, 0.0)  # 11° of roll


class PreflightLink:
    """The link as the preflight uses it: the estimate (re-stamped ``age_s`` before the clock's
    now at each read), the filter settling after ``settles_after`` reads, the supervisor's bits."""

    def __init__(self, clock, pos=(0.0, 0.0, 0.02), quat=LEVEL, vbat_v=4.1, age_s=0.01, settles_after=3, bits=0):
        self.clock, self.pos, self.quat, self.vbat_v, self.age_s = clock, pos, quat, vbat_v, age_s
        self.settles_after, self.bits = settles_after, bits
        self.reads = self.resets = 0

    def reset_kalman(self) -> None:
        self.resets += 1

    def state(self):
        self.reads += 1
        if self.pos is None:
            return None
        return StateSample(self.clock.now_s - self.age_s, self.pos, (0.0, 0.0, 0.0), self.quat, self.vbat_v)

    def kalman_settled(self) -> bool:
        return self.reads >= self.settles_after

    def supervisor_bits(self) -> int:
        return self.bits


class Mocap:
    name = "sim"

    def __init__(self, clock, pos=(0.0, 0.0, 0.02), after_reads: int = 0):
        self.clock, self.pos, self.after_reads, self.reads = clock, pos, after_reads, 0

    def read(self):
        self.reads += 1
        return None if self.reads <= self.after_reads else (self.pos, LEVEL, self.clock.now_s - 0.005)


def preflight(tmp_path, monkeypatch, mocap=None, clock=None, timeout_s=3.0, max_state_age_s=None, **link):
    """Run the preflight of a runner with the shipped safety settings (``max_state_age_s`` if
    given), a ``timeout_s`` timeout, a 3.7 V minimum and the hover point (0, 0, 1); returns
    (runner, clock, result or None if refused)."""
    from datt.configuration import compose
    from datt.deploy.schema import deploy_params

    clock = clock or FakeClock()
    monkeypatch.setattr(FlightRunner, "clock", clock)  # the class's: bookkeeping runners read it
    p = SimpleNamespace(preflight_timeout_s=timeout_s, min_battery_v=3.7, origin_m=[0.0, 0.0], takeoff_height_m=1.0)
    safety = deploy_params(compose("deploy").deploy)[2]
    if max_state_age_s is not None:
        safety.max_state_age_s = max_state_age_s
    runner = bookkeeping_runner(
        tmp_path,
        p=p,
        link=PreflightLink(clock, **link),
        safety=safety,
        mocap=None if mocap is None else mocap(clock),
    )
    try:
        return runner, clock, runner._preflight()
    except _Abort:
        return runner, clock, None


def test_a_ready_vehicle_passes_once_the_filter_settles(tmp_path, monkeypatch):
    """No mocap source: the preflight resets the filter, polls every 20 ms until it has settled
    (the third read), and returns the estimate's position with the battery in its event."""
    runner, clock, start = preflight(tmp_path, monkeypatch)
    assert start.tolist() == [0.0, 0.0, 0.02] and runner.link.resets == 1
    assert clock.now_s == pytest.approx(1000.04)  # two polls of 20 ms before the settled third read
    assert (runner.log.events[-1]["kind"], runner.log.events[-1]["text"]) == ("preflight ok", "battery 4.10 V")


def test_with_mocap_the_estimate_must_agree_with_it(tmp_path, monkeypatch):
    """A mocap source whose first frame comes on its fourth read: the preflight waits for it, and
    for the estimate to sit within 5 cm of it (here 1 cm off)."""
    runner, clock, start = preflight(
        tmp_path, monkeypatch, mocap=lambda c: Mocap(c, pos=(0.01, 0.0, 0.02), after_reads=6), settles_after=1
    )
    assert start is not None and clock.now_s > 1000.04  # it waited for the frame, not only the filter
    assert clock.now_s < 1001.0  # and went on once they agreed (not at the timeout)


REFUSALS = {
    "locked": (
        dict(bits=firmware.SUPERVISOR_BIT_LOCKED),
        "vehicle locked (an emergency stop or watchdog timeout earlier): restart it",
    ),
    "crashed": (dict(bits=firmware.SUPERVISOR_BIT_CRASHED), "vehicle crashed or tumbled"),
    "tumbled": (dict(bits=firmware.SUPERVISOR_BIT_TUMBLED), "vehicle crashed or tumbled"),
    "not_settled": (
        dict(settles_after=10**9),
        "Kalman filter not settled after 3 s (position variances still changing: is the mocap stream or the "
        "positioning deck reaching the vehicle?)",
    ),
    "no_state": (dict(pos=None, settles_after=1), "no state estimate from the vehicle"),
    # never fresh: the wait runs out, 20 ms after the last read of an estimate then 100 ms old
    "stale": (dict(age_s=0.1), "no fresh state estimate (the last arrived 120 ms ago, > 100 ms)"),
    "battery": (dict(vbat_v=3.69), "battery 3.69 V < 3.7 V"),
    "tilted": (dict(quat=TILT_11), "vehicle not level"),
    "start_outside": (dict(pos=(2.1, 0.0, 0.0)), "start position outside the geofence"),
}


@pytest.mark.parametrize("case", REFUSALS)
def test_each_reason_to_refuse_is_named(tmp_path, monkeypatch, case):
    """Each check alone, its text whole (the outcome of a flight refused before arming)."""
    link, text = REFUSALS[case]
    runner, clock, start = preflight(tmp_path, monkeypatch, **link)
    assert start is None and runner.outcome.text == f"preflight failed: {text}"
    assert runner.log.events[-1]["kind"] == "preflight failed"


@pytest.mark.parametrize(
    "mocap, text",
    [
        (lambda c: Mocap(c, after_reads=10**9), "no mocap frame for the vehicle"),
        (
            lambda c: Mocap(c, pos=(0.06, 0.0, 0.02)),
            "onboard estimate 6 cm from mocap (> 5 cm; is stabilizer.estimator the Kalman filter, the mocap frame "
            "the vehicle's?)",
        ),
    ],
    ids=["no_frame", "far"],
)
def test_a_mocap_frame_that_never_comes_or_disagrees_is_refused_after_the_timeout(tmp_path, monkeypatch, mocap, text):
    runner, clock, start = preflight(tmp_path, monkeypatch, mocap=mocap, settles_after=1)
    assert start is None and runner.outcome.text == f"preflight failed: {text}"
    assert clock.now_s >= 1003.0  # it waited the whole timeout for an agreeing estimate


def test_mocap_and_hover_points_outside_the_fence_and_several_reasons_at_once(tmp_path, monkeypatch):
    """The mocap position and the hover point are checked against the fence too; all reasons go
    in one line, joined by "; ", in the order checked."""
    runner, _, start = preflight(
        tmp_path,
        monkeypatch,
        mocap=lambda c: Mocap(c, pos=(0.0, 0.0, 2.6)),
        pos=(0.0, 0.0, 2.6),
        vbat_v=3.5,
        settles_after=1,
    )
    assert start is None
    assert runner.outcome.text == (
        "preflight failed: mocap position outside the geofence; battery 3.50 V < 3.7 V; "
        "start position outside the geofence"
    )
    runner, _, start = preflight(tmp_path, monkeypatch, settles_after=1)
    runner.p.takeoff_height_m = 2.6
    with pytest.raises(_Abort):
        runner._preflight()
    assert runner.outcome.text == "preflight failed: hover point outside the geofence"


class SixtyFourthClock(FakeClock):
    """A fake clock whose every sleep moves it 1/64 s (a power of two: its sums are exact)."""

    def sleep(self, seconds: float) -> None:
        self.now_s += 1.0 / 64.0


def test_the_wait_ends_at_the_timeout(tmp_path, monkeypatch):
    """A filter that never settles: the preflight polls while the clock is before the deadline
    (a 1/16 s timeout polled every 1/64 s: four reads, none at the deadline itself)."""
    clock = SixtyFourthClock()
    runner, _, start = preflight(tmp_path, monkeypatch, clock=clock, settles_after=10**9)
    assert start is None and runner.link.reads == 4 * 48  # the shipped 3 s: 192 polls of 1/64 s
    runner.p.preflight_timeout_s = 1.0 / 16.0
    runner.link.reads = 0
    with pytest.raises(_Abort):
        runner._preflight()
    assert runner.link.reads == 4


def test_an_estimate_exactly_max_state_age_old_is_stale_and_named_in_ms(tmp_path, monkeypatch):
    """The last estimate read 3/64 s old, checked 1/64 s later: 62.5 ms old against a limit of
    62.5 ms is stale (the limit is not fresh), shown rounded in ms (62)."""
    runner, _, start = preflight(
        tmp_path, monkeypatch, clock=SixtyFourthClock(), timeout_s=0.25, max_state_age_s=4.0 / 64.0,
        age_s=3.0 / 64.0, settles_after=10**9,
    )  # fmt: skip
    assert start is None
    assert "; no fresh state estimate (the last arrived 62 ms ago, > 62 ms)" in runner.outcome.text


@pytest.mark.parametrize(
    "offset_m, text",
    [
        (0.0496, None),  # 4.96 cm: within 5 cm
        (0.05, "onboard estimate 5 cm from mocap (> 5 cm; "),  # 5 cm exactly is too far
        (0.0645, "onboard estimate 6 cm from mocap (> 5 cm; "),  # 6.45 cm, shown rounded
    ],
    ids=["within", "at_the_limit", "rounded"],
)
def test_the_estimate_must_be_closer_to_mocap_than_the_limit(tmp_path, monkeypatch, offset_m, text):
    """``max_estimate_mocap_m`` (5 cm) is a strict limit: at 5 cm the preflight waits out its
    timeout for a closer estimate and refuses, naming the distance in whole cm."""
    runner, clock, start = preflight(
        tmp_path, monkeypatch, mocap=lambda c: Mocap(c, pos=(offset_m, 0.0, 0.02)), settles_after=1
    )
    if text is None:
        assert start is not None and clock.now_s < 1000.1
    else:
        assert start is None and runner.outcome.text.startswith(f"preflight failed: {text}")
        assert clock.now_s >= 1003.0


def test_positions_on_the_fence_and_a_battery_at_its_minimum_pass(tmp_path, monkeypatch):
    """The fence's bounds are inside: a vehicle, its mocap frame and the hover point exactly on
    them (x = −2, y = 2, z = 2.5) pass; so does a battery exactly at ``min_battery_v``."""
    corner = (-2.0, 2.0, 2.5)
    runner, _, _ = preflight(tmp_path, monkeypatch, mocap=lambda c: Mocap(c, pos=corner), pos=corner, vbat_v=3.7)
    runner.p.origin_m, runner.p.takeoff_height_m = [-2.0, 2.0], 2.5
    runner.link.settles_after = 1
    assert runner._preflight().tolist() == list(corner)
    runner.p.origin_m, runner.p.takeoff_height_m = [2.0, -2.0], 2.5
    assert runner._preflight().tolist() == list(corner)


def test_an_estimate_exactly_max_state_age_old_does_not_end_the_wait(tmp_path, monkeypatch):
    """Fresh means younger than ``max_state_age_s``: an estimate exactly that old (4/64 s) with
    a settled filter does not end the wait; the preflight waits out its timeout and refuses."""
    runner, clock, start = preflight(
        tmp_path, monkeypatch, clock=SixtyFourthClock(), timeout_s=0.25, max_state_age_s=4.0 / 64.0,
        age_s=4.0 / 64.0, settles_after=1,
    )  # fmt: skip
    assert start is None
    assert clock.now_s == 1000.25 and "no fresh state estimate (the last arrived 78 ms ago" in runner.outcome.text
