"""Motion-capture sources: the motioncapture library's own mock system through
:class:`MotionCaptureMocap`, and the simulated source's latency, dropouts and noise against their
definitions (real time: a few tenths of a second each)."""

from __future__ import annotations

import statistics
import sys
import time

import pytest

from datt.deploy.mocap import MotionCaptureMocap, SimulatedMocap
from datt.errors import ConfigError


def _collect(source, seconds: float) -> list[tuple[tuple, float]]:
    """(sample, the time it was delivered) for every frame ``source`` publishes in ``seconds``."""
    got = []
    source.subscribe(lambda sample: got.append((sample, time.monotonic())))
    source.start()
    time.sleep(seconds)
    source.stop()
    time.sleep(0.05)  # the loop sees the stop
    return got


def test_the_motioncapture_source_publishes_only_its_body_with_the_quaternion_w_first():
    pytest.importorskip("motioncapture")
    bodies = "cf1(1.0,2.0,3.0,0.5,0.5,0.5,0.5);other(9.0,9.0,9.0,1.0,0.0,0.0,0.0)"
    source = MotionCaptureMocap("mock", "localhost", "cf1", {"rigid_bodies": bodies})
    got = _collect(source, 0.3)
    assert got, "the mock system delivered no frame"
    for (pos, quat, _measured), _ in got:
        assert pos == pytest.approx((1.0, 2.0, 3.0)) and quat == pytest.approx((0.5, 0.5, 0.5, 0.5))
    assert source.read() == got[-1][0]
    n = len(got)
    time.sleep(0.1)
    assert len(got) == n  # stopped: no more frames


@pytest.mark.parametrize("system", ["vicon", "optitrack"])
def test_an_unreachable_mocap_host_ends_in_one_line_at_the_deadline_and_leaves_no_client(system):
    """The vendor SDKs block without returning to the interpreter on a host that does not answer
    (Vicon's frame wait, OptiTrack's connect; in the flying process this ignored SIGINT and
    SIGTERM): the client runs in a process of its own, which the deadline kills."""
    pytest.importorskip("motioncapture")
    import subprocess

    with pytest.raises(ConfigError) as info:
        MotionCaptureMocap(system, "10.255.255.1", "cf1", connect_timeout_s=1.0)
    message = str(info.value)
    assert message.startswith("deploy.mocap: ") and "\n" not in message
    assert "deploy.mocap.connect_timeout_s (1 s)" in message or "library refused" in message, message
    ps = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    assert "datt.deploy.mocap_stream" not in ps


def test_frames_without_the_body_are_refused_naming_the_bodies_seen():
    pytest.importorskip("motioncapture")
    bodies = "other(9.0,9.0,9.0,1.0,0.0,0.0,0.0)"
    with pytest.raises(ConfigError) as info:
        MotionCaptureMocap("mock", "localhost", "cf1", {"rigid_bodies": bodies}, connect_timeout_s=1.0)
    assert str(info.value) == (
        "deploy.mocap: frames from mock at localhost hold no rigid body 'cf1' (bodies seen: other) within "
        "deploy.mocap.connect_timeout_s (1 s); check the host, that the system streams, and deploy.mocap.body"
    )


def test_the_motioncapture_source_without_its_library_is_one_line(monkeypatch):
    monkeypatch.setitem(sys.modules, "motioncapture", None)  # import motioncapture raises ImportError
    with pytest.raises(
        ConfigError, match=r"^deploy.mocap: the motioncapture source needs `pip install motioncapture`$"
    ):
        MotionCaptureMocap("vicon", "localhost", "cf1")


class _Vehicle:
    """The simulated Crazyflie's ``true_state`` at a fixed pose."""

    def true_state(self) -> dict:
        return {"pos_m": (0.5, -0.25, 1.0), "quat": (1.0, 0.0, 0.0, 0.0)}


def test_simulated_frames_arrive_after_the_latency_at_the_rate_with_the_set_noise():
    source = SimulatedMocap(_Vehicle(), latency_s=0.03, rate_hz=100.0, noise_std_m=0.01, seed=3)
    got = _collect(source, 0.8)
    assert len(got) > 20
    delays = [delivered - sample[-1] for sample, delivered in got]
    # held the latency, then released within a loop period or two (a loaded machine sleeps longer)
    assert min(delays) >= 0.03 and statistics.median(delays) < 0.03 + 0.03
    gaps = [b[0][-1] - a[0][-1] for a, b in zip(got, got[1:])]
    assert 0.0095 < statistics.median(gaps) < 0.02  # 100 Hz: a period of sleep plus the loop's own time
    for axis, true in enumerate((0.5, -0.25, 1.0)):
        values = [sample[0][axis] for sample, _ in got]
        assert statistics.fmean(values) == pytest.approx(true, abs=0.006)  # unbiased
        assert 0.006 < statistics.stdev(values) < 0.015  # spread of the set std, 0.01 m
    assert all(sample[1] == (1.0, 0.0, 0.0, 0.0) for sample, _ in got)  # the attitude is exact


def test_simulated_dropouts_lose_every_frame_or_all_after_the_cut():
    assert _collect(SimulatedMocap(_Vehicle(), latency_s=0.0, dropout_prob=1.0), 0.2) == []
    source = SimulatedMocap(_Vehicle(), latency_s=0.0, dropout_after_s=0.1)
    got = _collect(source, 0.4)
    assert got and all(sample[-1] - source._t0 <= 0.1 + 0.011 for sample, _ in got)
    exact = _collect(SimulatedMocap(_Vehicle(), latency_s=0.0), 0.1)
    assert exact and all(sample[0] == (0.5, -0.25, 1.0) for sample, _ in exact)  # no noise unless set


def test_sources_read_nothing_before_a_frame_and_run_on_daemon_threads(monkeypatch):
    """A flight that ends without stopping its source must not keep the process alive."""
    import threading

    pytest.importorskip("motioncapture")
    bodies = {"rigid_bodies": "cf1(0.0,0.0,0.0,1.0,0.0,0.0,0.0)"}
    before = set(threading.enumerate())
    sources = [SimulatedMocap(_Vehicle(), latency_s=0.0), MotionCaptureMocap("mock", "localhost", "cf1", bodies)]
    for source in sources:
        assert source.read() is None  # no frame published before start
        source.start()
    started = set(threading.enumerate()) - before
    for source in sources:
        source.stop()
    assert len(started) >= 2 and all(t.daemon for t in started)
    assert sources[1]._proc.poll() is not None  # the motion-capture client process is gone


def test_the_host_and_options_reach_the_library_as_its_settings():
    """The client process gets the system and the settings (every value a string), and the library
    takes them: the mock system's bodies come from its ``rigid_bodies`` setting."""
    import json

    pytest.importorskip("motioncapture")
    options = {"port": 22223, "rigid_bodies": "cf1(1.0,2.0,3.0,1.0,0.0,0.0,0.0)"}
    source = MotionCaptureMocap("mock", "10.0.0.5", "cf1", options)
    try:
        system, settings, body = source._proc.args[-3:]
        assert (system, body) == ("mock", "cf1")
        assert json.loads(settings) == {
            "hostname": "10.0.0.5",
            "port": "22223",
            "rigid_bodies": options["rigid_bodies"],
        }
    finally:
        source.stop()


def test_the_simulated_source_s_defaults_are_the_deploy_settings_defaults():
    """``SimulatedMocap(vehicle)`` in a notebook is ``deploy.mocap`` left at its defaults: perfect."""
    import dataclasses
    import inspect

    from datt.deploy.schema import MocapParams

    schema = {f.name: f.default for f in dataclasses.fields(MocapParams)}
    params = inspect.signature(SimulatedMocap).parameters
    for key in ("latency_s", "dropout_prob", "dropout_after_s", "noise_std_m"):
        assert params[key].default == schema[key], key


def test_the_same_seed_draws_the_same_noise():
    def first_positions(seed: int) -> list[tuple]:
        got = _collect(SimulatedMocap(_Vehicle(), noise_std_m=0.01, seed=seed), 0.25)
        return [sample[0] for sample, _ in got[:5]]

    a, b, c = first_positions(7), first_positions(7), first_positions(8)
    assert len(a) == 5 and a == b[: len(a)] and a != c[: len(a)]


# -- the lead of the forwarded positions (deploy.mocap.lead_s) -------------------------------------
def test_a_lead_moves_a_steadily_moving_position_ahead_by_its_velocity_times_the_lead():
    from datt.deploy.mocap import FrameLead

    lead = FrameLead(0.03, 0.04)
    velocity = (1.0, -0.5, 0.2)
    for k in range(20):
        t = 0.01 * k
        out = lead(tuple(v * t for v in velocity), t)
        if k:  # from the second frame on: the position 30 ms ahead
            assert out == pytest.approx(tuple(v * (t + 0.03) for v in velocity), abs=1e-12)


def test_no_lead_returns_each_position_as_it_is_and_the_first_frame_is_never_moved():
    from datt.deploy.mocap import FrameLead

    assert FrameLead(0.0, 0.04)((1.0, 2.0, 3.0), 0.5) == (1.0, 2.0, 3.0)
    lead = FrameLead(0.05, 0.04)
    assert lead((1.0, 2.0, 3.0), 0.5) == (1.0, 2.0, 3.0)
    assert lead((1.0, 2.0, 3.0), 0.5) == (1.0, 2.0, 3.0)  # a repeated stamp: no velocity from it


def test_the_velocity_is_taken_over_the_window_not_between_neighbouring_frames():
    """A 1 mm step in one frame moves the led position by 1 mm x lead / window, not lead / 10 ms."""
    from datt.deploy.mocap import FrameLead

    lead = FrameLead(0.03, 0.04)
    for k in range(10):
        lead((0.0, 0.0, 1.0), 0.01 * k)
    out = lead((0.001, 0.0, 1.0), 0.10)
    assert out[0] == pytest.approx(0.001 + 0.001 * 0.03 / 0.04, abs=1e-12)


class _Link:
    def __init__(self, round_trip_s):
        self.round_trip_s = round_trip_s


@pytest.mark.parametrize(
    "kind, lead_s, round_trip_s, want",
    [
        ("offboard", None, 0.06, None),  # the predictor's job there
        ("onboard", None, 0.06, 0.03),
        ("onboard", None, float("inf"), None),  # no round trip measured: nothing to lead by
        ("offboard", 0.02, 0.06, 0.02),
        ("onboard", 0.0, 0.06, None),
    ],
)
def test_the_flight_leads_by_the_setting_or_by_its_own_rule(kind, lead_s, round_trip_s, want):
    from datt.deploy.mocap import NoMocap
    from datt.deploy.onboard_flight import OnboardFlight
    from datt.deploy.runner import FlightRunner

    flight = object.__new__(OnboardFlight if kind == "onboard" else FlightRunner)
    flight.mocap = NoMocap().with_lead(lead_s, 0.04)
    flight.link = _Link(round_trip_s)
    events = []
    flight._event = lambda what, text="", **extra: events.append((what, text))
    got = flight._mocap_lead()
    if want is None:
        assert got is None and events == []
    else:
        assert got.lead_s == pytest.approx(want) and got.window_s == 0.04
        assert events == [("mocap lead", f"each forwarded mocap position led {want * 1000:.0f} ms along its velocity")]
