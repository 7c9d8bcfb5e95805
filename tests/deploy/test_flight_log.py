"""The flight log from hand-built rows: what events.json and flight.csv say, and what the runner
reads back from the rows (the tracking error, the hover trim's window)."""

from __future__ import annotations

import csv
import json
import math
from types import SimpleNamespace

import numpy as np
import pytest

from datt.deploy.flight_log import COLUMNS, FlightLog
from tests.deploy import bookkeeping_runner


def row(k: int, phase: str, jitter_ms: float, compute_ms: float, err_m: float = 0.0) -> dict:
    return {
        "t_s": 0.02 * k,
        "sched_t_s": 0.02 * k,
        "vehicle_s": 0.02 * k,  # stamped by the vehicle, arriving 20 ms later
        "arrived_s": 0.02 * k + 0.02,
        "phase": phase,
        "pos": [err_m, 0.0, 1.0],
        "vel": [0.0, 0.0, 0.0],
        "quat": [1.0, 0.0, 0.0, 0.0],
        "ref": [0.0, 0.0, 1.0],
        "action": [9.81, 0.0, 0.0, 0.0],
        "thrust_cmd": 45000 + k,
        "d_hat": [0.0, 0.0, 0.0],
        "vbat": 4.0,
        "decision": "OK",
        "jitter_ms": jitter_ms,
        "compute_ms": compute_ms,
    }


def test_timing_summary_counts_late_ticks_strictly_and_takes_absolute_jitter(tmp_path):
    """late_ticks counts jitter > late_tick_ms (not ≥, not |jitter|); the jitter statistics are
    of |jitter| (an early tick is as far off as a late one); compute is taken as it is."""
    log = FlightLog(tmp_path, late_tick_ms=5.0)
    jitters = [0.5, -7.0, 5.0, 5.01, 12.0, -0.2, 1.0, 3.0]
    computes = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0]
    log.rows = [row(k, "TRACK" if k >= 2 else "TAKEOFF", j, c) for k, (j, c) in enumerate(zip(jitters, computes))]
    summary = log.write({"outcome": "landed"}, [r for r in log.rows if r["phase"] == "TRACK"])
    a = np.abs(jitters)
    assert summary["ticks"] == 8 and summary["late_ticks"] == 2  # 5.01 and 12.0; not 5.0, not -7.0
    assert summary["jitter_ms"] == pytest.approx(
        {"median": float(np.median(a)), "p99": float(np.percentile(a, 99)), "max": 12.0}
    )
    assert summary["compute_ms"] == pytest.approx({"median": 4.5, "p99": float(np.percentile(computes, 99))})
    assert summary["outcome"] == "landed"
    assert json.loads((tmp_path / "events.json").read_text())["late_ticks"] == 2
    with open(tmp_path / "flight.csv") as f:
        rows = list(csv.reader(f))
    assert rows[0] == COLUMNS and len(rows) == 9
    assert [r[1] for r in rows[1:]] == ["TAKEOFF", "TAKEOFF"] + ["TRACK"] * 6
    assert [int(r[COLUMNS.index("thrust_cmd")]) for r in rows[1:]] == [45000 + k for k in range(8)]
    assert float(rows[2][COLUMNS.index("jitter_ms")]) == -7.0  # the csv keeps the sign


def test_a_flight_without_ticks_still_writes_a_summary(tmp_path):
    summary = FlightLog(tmp_path).write({"outcome": "refused"}, [])
    assert summary["ticks"] == 0 and summary["late_ticks"] == 0 and summary["jitter_ms"]["max"] == 0.0
    assert (tmp_path / "events.json").exists() and not (tmp_path / "tracks_flight.png").exists()
    assert not (tmp_path / "axes_flight.png").exists()


def test_the_runner_scores_only_the_track_ticks(tmp_path):
    """track_error_m is the mean |pos − ref| over the TRACK rows only (takeoff and landing rows
    are logged but not scored), track_steps their count; with a reference that stands still the
    reference when measured is the tick's own, so track_error_received_m is the same."""
    from datt.deploy.outcome import Kind, Outcome

    runner = bookkeeping_runner(
        tmp_path,
        outcome=Outcome(Kind.LANDED),
        summary_extra={"controller": "datt"},
        link=SimpleNamespace(round_trip_s=0.04),
    )
    errors = [0.3, 0.1, 0.2, 0.4]
    runner.log.rows = [row(0, "TAKEOFF", 0.0, 1.0, 2.0)]
    runner.log.rows += [row(k + 1, "TRACK", 0.0, 1.0, e) for k, e in enumerate(errors)]
    runner.log.rows += [row(9, "LAND", 0.0, 1.0, 5.0)]
    summary = runner._write()
    assert summary["track_steps"] == 4 and summary["track_error_m"] == pytest.approx(sum(errors) / 4)
    assert summary["ticks"] == 6 and summary["controller"] == "datt"
    assert math.isclose(runner._track_errors()[1], 0.1)
    assert summary["track_error_received_m"] == pytest.approx(sum(errors) / 4)
    assert [r["state_t_s"] for r in runner.log.rows] == pytest.approx([0.0, 0.02, 0.04, 0.06, 0.08, 0.18])


def test_estimates_are_placed_at_their_vehicle_stamp_on_the_hosts_clock():
    """The vehicle's clock runs 100 s behind the host's; each estimate crosses a 20 ms radio leg
    plus 0-10 ms of waiting for its log period: the least transit (20 ms) less the one way (half
    the 40 ms round trip) places every stamp exactly, whatever each one's own wait. A row without
    a stamp falls back to its arrival less the one way; one without either is NaN."""
    from datt.deploy.flight_log import measured_at

    waits = [0.004, 0.0, 0.01, 0.007]
    # the vehicle booted 5 s before its clock's first stamp here: its clock reads 5.0 at host time 100.0
    rows = [{"vehicle_s": 5.0 + 0.02 * k, "arrived_s": 100.0 + 0.02 * k + 0.02 + w} for k, w in enumerate(waits)]
    assert measured_at(rows, 0.04) == pytest.approx([100.0 + 0.02 * k for k in range(4)], abs=1e-12)
    # an unmeasured round trip: the stamps keep their spacing, placed at the least transit
    assert measured_at(rows, math.inf) == pytest.approx([100.02 + 0.02 * k for k in range(4)], abs=1e-12)
    mixed = [{"vehicle_s": None, "arrived_s": 5.0}, {"arrived_s": 6.0}, {}]
    got = measured_at(mixed, 0.04)
    assert got[:2] == pytest.approx([4.98, 5.98]) and math.isnan(got[2])


def test_the_error_takes_the_reference_at_the_time_the_estimate_was_measured():
    """A reference moving at 1 m/s along x, ticks every 20 ms; a vehicle exactly on it whose
    estimates are 30 ms old when they arrive: the error when measured is 0 (interpolated between
    ticks), the estimate against its tick's reference would read 0.03 m. Before the first tick
    the first point holds; a NaN time gives NaN."""
    from datt.deploy.flight_log import errors_when_measured

    track = []
    for k in range(10):
        t = 0.02 * k
        measured = t - 0.03
        track.append({"sched_t_s": t, "ref": [t, 0.0, 1.0], "pos": [measured, 0.0, 1.0], "state_t_s": measured})
    errors = errors_when_measured(track)
    assert errors[2:] == pytest.approx([0.0] * 8, abs=1e-12)
    assert errors[:2] == pytest.approx([0.03, 0.01], abs=1e-12)  # before tick 0: its point, held
    received = [float(np.linalg.norm(np.array(r["pos"]) - np.array(r["ref"]))) for r in track]
    assert received == pytest.approx([0.03] * 10)
    track[5]["state_t_s"] = math.nan
    with_gap = errors_when_measured(track)
    assert math.isnan(with_gap[5]) and with_gap[6:] == pytest.approx([0.0] * 4, abs=1e-12)  # the rest still scored
    assert errors_when_measured([]) == []


# -- the log's files field by field: what a reader of flight.csv and events.json gets ---------------
def distinct_row() -> dict:
    """A row whose every number is different, so a column that takes another field's value shows."""
    return {
        "t_s": 1.234567,
        "phase": "TRACK",
        "pos": [1.5, 2.5, 3.5],
        "vel": [4.5, 5.5, 6.5],
        "quat": [0.25, 0.125, 0.0625, 0.03125],
        "ref": [11.5, 12.5, 13.5],
        "action": [14.5, 15.5, 16.5, 17.5],
        "thrust_cmd": 18123,
        "d_hat": [19.5, 20.5, 21.5],
        "vbat": 3.875,
        "decision": "LAND",
        "jitter_ms": -1.23456,
        "compute_ms": 2.34567,
        "sched_t_s": 3.141592,
        "state_t_s": 2.718281,
    }


def test_every_csv_column_holds_its_own_field(tmp_path):
    """Each column of flight.csv under its header: times to 0.1 ms, jitter and compute to 1 µs,
    vectors in x, y, z (w, x, y, z for the quaternion) order; a row without the scheduled or
    measured time says nan there."""
    log = FlightLog(tmp_path)
    bare = {k: v for k, v in distinct_row().items() if k not in ("sched_t_s", "state_t_s")}
    log.rows = [distinct_row(), bare]
    log.write({}, [])
    with open(tmp_path / "flight.csv") as f:
        first, second = list(csv.DictReader(f))
    expected = {
        "t_s": "1.2346", "phase": "TRACK", "x": 1.5, "y": 2.5, "z": 3.5, "vx": 4.5, "vy": 5.5, "vz": 6.5,
        "qw": 0.25, "qx": 0.125, "qy": 0.0625, "qz": 0.03125, "ref_x": 11.5, "ref_y": 12.5, "ref_z": 13.5,
        "thrust_mps2": 14.5, "wx": 15.5, "wy": 16.5, "wz": 17.5, "thrust_cmd": "18123", "dhat_x": 19.5,
        "dhat_y": 20.5, "dhat_z": 21.5, "vbat_v": 3.875, "decision": "LAND", "jitter_ms": "-1.235",
        "compute_ms": "2.346", "sched_t_s": "3.1416", "state_t_s": "2.7183",
    }  # fmt: skip
    assert list(first) == COLUMNS == list(expected)
    got = {k: (float(v) if isinstance(expected[k], float) else v) for k, v in first.items()}
    assert got == expected
    assert second["sched_t_s"] == "nan" and second["state_t_s"] == "nan" and second["t_s"] == "1.2346"


class Clock:
    """A monotonic clock the test sets."""

    def __init__(self, now: float) -> None:
        self.now = now

    def monotonic(self) -> float:
        return self.now


class Console:
    def __init__(self) -> None:
        self.lines: list[str] = []

    def print(self, line: str) -> None:
        self.lines.append(line)


def test_events_carry_their_time_since_the_start_their_phase_and_go_to_the_console(tmp_path, monkeypatch):
    """An event is stamped with the seconds since the log began (to 0.1 ms) and the phase it
    happened in; extra fields are kept; the console gets one aligned line per event. A phase
    change is itself an event of the new phase. The log starts in CONNECT."""

    clock = Clock(1000.0)
    console = Console()
    log = FlightLog(tmp_path, console=console, clock=clock)
    assert log.phase == "CONNECT" and log.events == [] and log.rows == []
    clock.now = 1001.234567
    log.event("link", "radio up", round_trip_ms=12.5)
    clock.now = 1002.5
    log.set_phase("TAKEOFF")
    clock.now = 1012.75
    log.event("safety", "LAND: mocap stale")
    assert log.events == [
        {"t_s": 1.2346, "phase": "CONNECT", "kind": "link", "text": "radio up", "round_trip_ms": 12.5},
        {"t_s": 2.5, "phase": "TAKEOFF", "kind": "phase", "text": "TAKEOFF"},
        {"t_s": 12.75, "phase": "TAKEOFF", "kind": "safety", "text": "LAND: mocap stale"},
    ]
    assert console.lines == [
        "[   1.23 s] CONNECT  link: radio up",
        "[   2.50 s] TAKEOFF  phase: TAKEOFF",
        "[  12.75 s] TAKEOFF  safety: LAND: mocap stale",
    ]
    silent = FlightLog(tmp_path)  # no console: events are still kept
    silent.event("x", "y")
    silent.event("armed")  # an event without a text has an empty one
    assert [(e["kind"], e["text"]) for e in silent.events] == [("x", "y"), ("armed", "")]


def test_events_json_is_the_summary_with_the_timing_and_every_event(tmp_path):
    """events.json holds what the caller summarised, the tick count and timing, and the events in
    order (values json cannot write, such as a path, as text); it is created with its directory."""
    run_dir = tmp_path / "a" / "b"
    log = FlightLog(run_dir)
    log.event("upload", "done", path=tmp_path / "ref.csv")
    log.set_phase("TRACK")
    log.rows = [row(k, "TRACK", 1.0, 2.0) for k in range(3)]
    summary = log.write({"outcome": "landed", "ticks": -1}, [])
    on_disk = json.loads((run_dir / "events.json").read_text())
    assert on_disk == json.loads(json.dumps(summary, default=str))
    assert on_disk["outcome"] == "landed" and on_disk["ticks"] == 3  # the count, not the caller's
    assert [(e["kind"], e["text"]) for e in on_disk["events"]] == [("upload", "done"), ("phase", "TRACK")]
    assert on_disk["events"][0]["path"] == str(tmp_path / "ref.csv")
    # indented by two, one value per line, so that two flights' files read side by side in a diff
    assert (run_dir / "events.json").read_text() == json.dumps(summary, indent=2, default=str) + "\n"


def test_the_default_late_tick_is_five_milliseconds_and_an_empty_flight_times_zero(tmp_path):
    log = FlightLog(tmp_path)
    assert (log.rate_hz, log.late_tick_ms, log.run_dir) == (50.0, 5.0, tmp_path)
    log.rows = [row(k, "TRACK", j, 1.0) for k, j in enumerate([5.0, 5.001, 4.0])]
    assert log.write({}, [])["late_ticks"] == 1
    empty = FlightLog(tmp_path / "empty").write({}, [])
    assert empty["jitter_ms"] == {"median": 0.0, "p99": 0.0, "max": 0.0}
    assert empty["compute_ms"] == {"median": 0.0, "p99": 0.0}


@pytest.mark.parametrize("rate_hz", [50.0, 25.0])
def test_the_plots_show_the_track_flown_against_its_reference(tmp_path, monkeypatch, rate_hz):
    """The two plots of a flight get the track rows' positions and references as one trace of
    [1, ticks, 3], all of it drawn (the last index as its end) at the log's tick period; without
    track rows there is no plot. Then the real plots are drawn: two PNG files."""
    from datt.eval import plots

    calls = []
    monkeypatch.setattr(plots, "plot_tracks", lambda *a, **k: calls.append(("tracks", a, k)))
    monkeypatch.setattr(plots, "plot_group_axes", lambda *a, **k: calls.append(("axes", a, k)))
    track = [
        {**row(k, "TRACK", 0.0, 1.0), "pos": [0.1 * k, -0.2 * k, 1.0 + k], "ref": [k, 2.0 * k, 1.5]} for k in range(5)
    ]
    FlightLog(tmp_path, rate_hz=rate_hz).write({}, track)
    (kind_t, a_t, k_t), (kind_a, a_a, k_a) = calls
    assert (kind_t, kind_a) == ("tracks", "axes")
    for trace in (a_t[0], a_a[0]):
        assert trace.pos_m.shape == trace.ref_m.shape == (1, 5, 3)
        assert trace.pos_m[0, :, 2].tolist() == pytest.approx([1.0, 2.0, 3.0, 4.0, 5.0])
        assert trace.ref_m[0, :, 1].tolist() == pytest.approx([0.0, 2.0, 4.0, 6.0, 8.0])
        assert trace.crashed_at.tolist() == [4]
    assert a_t[1:] == (["track"], [1], tmp_path / "tracks_flight.png")
    assert k_t == {"title": "flight: reference vs flown", "per_group": 1}
    assert a_a[1:] == (["track"], [1], pytest.approx(1.0 / rate_hz), tmp_path / "axes_flight.png")
    assert k_a == {"title": "flight"}
    calls.clear()
    FlightLog(tmp_path / "none").write({}, [])
    assert calls == []
    monkeypatch.undo()
    FlightLog(tmp_path / "real", rate_hz=rate_hz).write({}, track)
    for name in ("tracks_flight.png", "axes_flight.png"):
        assert (tmp_path / "real" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


@pytest.mark.parametrize("window_s, rate_hz", [(0.5, 50.0), (0.2, 50.0), (0.5, 25.0)], ids=["default", "short", "slow"])
def test_the_hover_trim_reads_the_last_window_of_its_phase(tmp_path, window_s, rate_hz):
    """The trim measures the hover command over the last ``hover_trim_window_s`` of the phase
    (window × rate ticks): the command ramps through the hover while the vehicle holds its height,
    so the time-weighted mean the trim reports is that of exactly those ticks (fewer or more
    ticks give another mean); the TAKEOFF rows before it are not read."""
    from datt.deploy.outcome import Kind, Outcome
    from datt.deploy.safety import OK
    from datt.deploy.thrust import ThrustMap, ThrustParams, commands_acting, hover_command_from_hover

    runner = bookkeeping_runner(
        tmp_path,
        outcome=Outcome(Kind.LANDED),
        link=SimpleNamespace(round_trip_s=0.04),
        p=SimpleNamespace(hover_trim_window_s=window_s, rate_hz=rate_hz, hover_trim_lag_s=0.0, hover_trim_max=0.3),
    )
    runner.thrust = ThrustMap(ThrustParams(hover_command=50000.0))
    runner.configured_hover_command = 50000.0
    dt = 1.0 / rate_hz
    rows = [{**row(k, "TAKEOFF", 0.0, 1.0), "t_s": k * dt, "thrust_cmd": 60000} for k in range(10)]
    rows += [{**row(k, "HOVER", 0.0, 1.0), "t_s": k * dt, "thrust_cmd": 45000 + 200 * (k - 10)} for k in range(10, 60)]
    runner.log.rows = rows
    assert runner._trim("HOVER", [], final=True) == OK
    n = round(window_s * rate_hz)
    window = rows[-n:]
    t = [r["t_s"] for r in window]
    expected = hover_command_from_hover(
        t,
        [0.0] * n,
        commands_acting(t, [r["t_s"] for r in rows], [r["thrust_cmd"] for r in rows], 0.0),
    )
    trim = [e for e in runner.log.events if e["kind"] == "trim"]
    assert len(trim) == 1 and trim[0]["hover_command"] == pytest.approx(expected, rel=1e-9)
    assert runner.thrust.hover_command == pytest.approx(expected, rel=1e-9)


def test_the_hover_trim_uses_the_maps_gravity_the_configured_lag_and_a_two_tick_window(tmp_path):
    """Settings away from their defaults: a 40 ms window at 50 Hz is two ticks (the fewest the
    trim reads), the thrust map's gravity 9.0 m/s² (a vehicle whose map says so) weighs the
    vertical acceleration, and a 0.6 s ``hover_trim_lag_s`` pairs each velocity with the command
    sent 30 ticks earlier; the event says the lag in ms."""
    from datt.deploy.outcome import Kind, Outcome
    from datt.deploy.safety import OK
    from datt.deploy.thrust import ThrustMap, ThrustParams, commands_acting, hover_command_from_hover

    runner = bookkeeping_runner(
        tmp_path,
        outcome=Outcome(Kind.LANDED),
        link=SimpleNamespace(round_trip_s=0.04),
        p=SimpleNamespace(hover_trim_window_s=0.04, rate_hz=50.0, hover_trim_lag_s=0.6, hover_trim_max=0.3),
    )
    runner.thrust = ThrustMap(ThrustParams(hover_command=50000.0, gravity_mps2=9.0))
    runner.configured_hover_command = 50000.0
    rows = [{**row(k, "TAKEOFF", 0.0, 1.0), "t_s": k * 0.02, "thrust_cmd": 60000} for k in range(10)]
    for k in range(10, 60):  # climbing ever faster: 0.5 m/s² up
        hover = {**row(k, "HOVER", 0.0, 1.0), "t_s": k * 0.02, "thrust_cmd": 45000 + 200 * (k - 10)}
        rows.append({**hover, "vel": [0.0, 0.0, 0.01 * (k - 10)]})
    runner.log.rows = rows
    assert runner._trim("HOVER", [], final=True) == OK
    window = rows[-2:]
    t = [r["t_s"] for r in window]
    acting = commands_acting(t, [r["t_s"] for r in rows], [r["thrust_cmd"] for r in rows], 0.6)
    expected = hover_command_from_hover(t, [r["vel"][2] for r in window], acting, 9.0)
    (trim,) = [e for e in runner.log.events if e["kind"] == "trim"]
    assert trim["hover_command"] == pytest.approx(expected, rel=1e-9)
    assert trim["text"].startswith(
        f"the hover needed command {expected:.0f} (commands 600 ms before the velocities), the thrust map 50000"
    )


def test_a_trim_beyond_its_limit_is_clamped_on_the_first_pass_and_lands_on_the_final_one(tmp_path):
    """The hover measures 60 % above the configured map, more than ``hover_trim_max`` (25 %, then
    55 %). The takeoff's trim (not the final one) rescales the map by the limit and HOVER measures
    again; the final trim (the map TRACK would fly) does not fly it: LAND. Each event says what was
    measured, by how much, and what was done."""
    from datt.deploy.outcome import Kind, Outcome
    from datt.deploy.safety import LAND, OK
    from datt.deploy.thrust import ThrustMap, ThrustParams

    def trimming(limit):
        runner = bookkeeping_runner(
            tmp_path,
            outcome=Outcome(Kind.LANDED),
            link=SimpleNamespace(round_trip_s=0.04),
            p=SimpleNamespace(hover_trim_window_s=0.5, rate_hz=50.0, hover_trim_lag_s=0.0, hover_trim_max=limit),
        )
        runner.thrust = ThrustMap(ThrustParams(hover_command=50000.0))
        runner.configured_hover_command = 50000.0
        runner.log.rows = [{**row(k, "TAKEOFF", 0.0, 1.0), "thrust_cmd": 80000} for k in range(40)]
        return runner

    measured = "the hover needed command 80000 (commands 0 ms before the velocities), the thrust map 50000"
    first = trimming(0.25)
    assert first._trim("TAKEOFF", [], final=False) == OK
    (trim,) = [(e["text"], e["hover_command"]) for e in first.log.events if e["kind"] == "trim"]
    assert trim == (
        f"{measured} (+60 % from deploy.thrust, clamped to +25 %: HOVER measures again): map rescaled by +25.0 %",
        pytest.approx(62500.0),
    )
    assert first.thrust.hover_command == pytest.approx(62500.0)

    final = trimming(0.55)
    assert final._trim("TAKEOFF", [], final=True) == LAND
    assert [(e["kind"], e["text"]) for e in final.log.events] == [
        (
            "LAND",
            f"{measured} (+60 % from deploy.thrust), beyond deploy.flight.hover_trim_max (55 %); check "
            "deploy.thrust.mass_kg and the battery, or calibrate",
        )
    ]
    assert final.thrust.hover_command == 50000.0  # not rescaled


@pytest.mark.parametrize(
    "configured_s, round_trip_s, lag_s",
    [(None, 0.03, 0.05), (None, math.inf, 0.02), (None, math.nan, 0.02), (0.6, 0.03, 0.6)],
    ids=["measured", "not_measured", "nan", "configured"],
)
def test_the_trim_lag_is_the_round_trip_and_a_tick_unless_configured(tmp_path, configured_s, round_trip_s, lag_s):
    """``hover_trim_lag_s: null``: the round trip measured at connect + one tick at 50 Hz; a round
    trip never measured (inf, nan) counts as none; a configured lag is taken as it is."""
    runner = bookkeeping_runner(
        tmp_path,
        link=SimpleNamespace(round_trip_s=round_trip_s),
        p=SimpleNamespace(hover_trim_lag_s=configured_s, rate_hz=50.0),
    )
    assert runner._trim_lag_s() == pytest.approx(lag_s)


@pytest.mark.parametrize("end_z, lifted", [(0.25, True), (0.2499, False), (-0.004, False), (0.9, True), (None, False)])
def test_a_takeoff_has_lifted_off_when_it_ends_at_least_half_its_height_up(tmp_path, end_z, lifted):
    """``_lifted_off``: the takeoff phase's last estimate at least half of ``takeoff_height_m``
    (0.5 m here: 0.25 m) above the ground; the rows of other phases are not read. Below it, one
    LAND event with the height (no "-0.00"), the hover height and the largest command of the phase."""

    runner = bookkeeping_runner(tmp_path, p=SimpleNamespace(takeoff_height_m=0.5))
    rows = [{**row(k, "TAKEOFF", 0.0, 1.0), "thrust_cmd": 50000 + 100 * k} for k in range(5)]
    rows[-1]["pos"] = [0.0, 0.0, end_z]
    if end_z is None:  # a takeoff that logged no tick: on the ground, no command sent
        rows, end_z = [], 0.0
    rows += [{**row(k, "HOVER", 0.0, 1.0), "pos": [0.0, 0.0, 0.5], "thrust_cmd": 65000} for k in range(5, 8)]
    runner.log.rows = rows
    assert runner._lifted_off("TAKEOFF") is lifted
    events = [(e["kind"], e["text"]) for e in runner.log.events]
    if lifted:
        assert events == []
    else:
        shown = f"{end_z:.2f}".replace("-0.00", "0.00")
        top = 50400 if any(r["phase"] == "TAKEOFF" for r in rows) else 0
        assert events == [
            (
                "LAND",
                f"the vehicle did not lift off: the takeoff ended at z {shown} m (hover at 0.5 m) with commands "
                f"up to {top}; the firmware's thrust lock (no setpoint with thrust 0 arrived after arming), "
                "or motors and propellers",
            )
        ]


def test_a_link_lost_while_waiting_for_arming_disarms_and_flies_nothing(tmp_path):
    """``_arm``: the supervisor's armed bit never read because the link failed while waiting:
    not armed, the disarm request sent, the outcome ARMING_FAILED with the link's own words, and
    the flight aborted before any zero-thrust (unlocking) setpoint."""
    from datt.deploy.link import LinkError
    from datt.deploy.outcome import Kind
    from datt.deploy.runner import _Abort

    sent = []

    def wait_armed(timeout_s):
        raise LinkError("link lost: no answer from the vehicle")

    link = SimpleNamespace(
        arm=lambda on: sent.append(("arm", on)),
        wait_armed=wait_armed,
        send_rates=lambda *a: sent.append(("rates", a)),
    )
    runner = bookkeeping_runner(tmp_path, p=SimpleNamespace(arm_timeout_s=1.0, rate_hz=50.0), link=link)
    with pytest.raises(_Abort):
        runner._arm()
    assert sent == [("arm", True), ("arm", False)]
    assert runner.outcome.kind is Kind.ARMING_FAILED
    assert runner.outcome.text == "arming failed: link lost: no answer from the vehicle (supervisor.info); nothing flew"
    events = [(e["kind"], e["text"]) for e in runner.log.events]
    assert events == [("phase", "ARM"), ("arming failed", runner.outcome.text)]


@pytest.mark.parametrize(
    "pos, start", [((1.0, -0.5, 1.2), (0.8, -0.8, 0.2)), (None, (0.0, 0.0, 0.0))], ids=["from_the_vehicle", "no_state"]
)
def test_the_landing_ramps_from_where_the_vehicle_is_to_the_floor_below_it(tmp_path, pos, start):
    """``_land`` from the hover point (0.2, 0.3, 1.0): the PID's ramp starts where the estimate is
    (controller frame: relative to the hover point; the hover point itself without an estimate)
    and ends 5 cm above the floor below that, over ``land_s`` with 0.5 s more of ticks; landed, the
    motors get zero thrust and the outcome is the first LAND event's reason."""
    from datt.deploy.link import StateSample
    from datt.deploy.outcome import Kind
    from datt.deploy.safety import OK

    sent, built = [], {}
    state = None if pos is None else StateSample(0.0, pos, (0.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0), 4.0)
    link = SimpleNamespace(state=lambda: state, send_rates=lambda *a: sent.append(a))
    runner = bookkeeping_runner(
        tmp_path, p=SimpleNamespace(land_s=2.0, rate_hz=50.0), link=link, pid_factory=lambda: "pid"
    )
    runner._model = lambda controller, family: built.update(controller=controller, family=family) or "model"

    def tick_loop(model, steps, origin, allow_land):
        built.update(model=model, steps=steps, origin=origin.tolist(), allow_land=allow_land)
        return OK

    runner._tick_loop = tick_loop
    runner.log.event("LAND", "speed 5.0 m/s > 4.0 m/s")
    runner.log.event("LAND", "a later reason")
    runner._land(np.array([0.2, 0.3, 1.0]))
    ramp = built.pop("family")
    assert ramp.start.tolist() == pytest.approx(start) and ramp.duration_s == 2.0
    assert ramp.end.tolist() == pytest.approx([start[0], start[1], -0.95])
    assert built == {
        "controller": "pid",
        "model": "model",
        "steps": 125,
        "origin": [0.2, 0.3, 1.0],
        "allow_land": False,
    }
    assert sent == [(0.0, 0.0, 0.0, 0)] and runner.log.phase == "LAND"
    assert runner.outcome.kind is Kind.LANDED_EARLY and runner.outcome.text == "landed early: speed 5.0 m/s > 4.0 m/s"


def test_a_hover_that_sank_to_the_floor_lands_before_its_trim(tmp_path):
    """A vehicle too heavy for its ceiling sinks during HOVER: its trim would read a hover command
    off the floor and TRACK would start there (a floor KILL). Below half the hover height at the
    end of HOVER it lands, naming the height and the commands, and no trim is taken."""
    from datt.deploy.safety import LAND, OK

    runner = bookkeeping_runner(tmp_path, p=SimpleNamespace(hover_trim=True, takeoff_height_m=1.0))
    trims = []
    runner._trim = lambda phase, models, final: trims.append(phase) or OK
    runner._land = lambda origin: trims.append("landed")

    def fly_phase(model, duration, origin):
        z = 1.0 if runner.log.phase == "TAKEOFF" else 0.003
        runner.log.rows.append(
            {**row(len(runner.log.rows), runner.log.phase, 0.0, 1.0), "pos": [0.0, 0.0, z], "thrust_cmd": 60000}
        )
        return OK

    runner._fly_phase = fly_phase
    takeoff, hover = ("TAKEOFF", "takeoff model", 2.0), ("HOVER", "hover model", 2.0)
    assert runner._climb(np.zeros(3), takeoff, hover, ["track model"]) == LAND
    assert trims == ["TAKEOFF", "landed"]
    assert runner.log.events[-1] == {
        **runner.log.events[-1],
        "kind": "LAND",
        "text": "the vehicle could not hold its hover: the hover ended at z 0.00 m (hover at 1 m) with commands up "
        "to 60000; it needs more thrust than it has (deploy.thrust.mass_kg, the battery, the motors)",
    }


def test_each_trim_reaches_the_models_still_to_fly(tmp_path):
    """``_climb``: TAKEOFF, its trim (a first pass: the HOVER model and the later ones get the new
    ceiling), HOVER, the final trim (the later ones); without HOVER the takeoff's trim is final."""
    from datt.deploy.safety import OK

    def climbing():
        runner = bookkeeping_runner(tmp_path, p=SimpleNamespace(hover_trim=True))
        calls = []
        runner._fly_phase = lambda model, duration, origin: calls.append(("fly", runner.log.phase, model)) or OK
        runner._lifted_off = lambda phase: True
        runner._trim = lambda phase, models, final: calls.append(("trim", phase, list(models), final)) or OK
        return runner, calls

    runner, calls = climbing()
    takeoff, hover = ("TAKEOFF", "takeoff model", 2.0), ("HOVER", "hover model", 2.0)
    assert runner._climb(np.zeros(3), takeoff, hover, ["track model"]) == OK
    assert calls == [
        ("fly", "TAKEOFF", "takeoff model"),
        ("trim", "TAKEOFF", ["track model", "hover model"], False),
        ("fly", "HOVER", "hover model"),
        ("trim", "HOVER", ["track model"], True),
    ]
    runner, calls = climbing()
    assert runner._climb(np.zeros(3), takeoff, None, ["track model"]) == OK
    assert calls == [("fly", "TAKEOFF", "takeoff model"), ("trim", "TAKEOFF", ["track model"], True)]


@pytest.mark.parametrize(
    "action, allow_land, jitter_ms, returned, events",
    [
        ("OK", True, 30.0, None, []),  # on course: a late tick alone is the timing summary's business
        ("LAND", True, 2.0, "LAND", [("LAND", "why")]),
        ("LAND", False, 2.0, None, [("warning", "why")]),  # already landing: noted, the landing goes on
        ("LAND", False, 30.0, None, [("warning", "this tick ran 30 ms behind schedule (the host stalled)"),
                                     ("warning", "why")]),
        ("KILL", False, 2.0, "KILL", [("KILL", "why")]),
        ("KILL", True, 10.0, "KILL", [("KILL", "why")]),  # exactly late_tick_ms: not behind schedule
    ],
)  # fmt: skip
def test_each_safety_decision_has_its_effect_on_the_tick(tmp_path, action, allow_land, jitter_ms, returned, events):
    """``_act_on``: KILL stops the motors and ends the phase; LAND ends it where landing is allowed
    and is a warning with its reason while already landing; OK does nothing. A decision taken on a
    tick more than ``late_tick_ms`` behind schedule is preceded by a warning saying so."""
    from datt.deploy.safety import Decision

    stops = []
    runner = bookkeeping_runner(
        tmp_path, p=SimpleNamespace(late_tick_ms=10.0), link=SimpleNamespace(emergency_stop=lambda: stops.append(1))
    )
    reason = "" if action == "OK" else "why"
    assert runner._act_on(Decision(action, reason), jitter_ms, allow_land) == returned
    assert [(e["kind"], e["text"]) for e in runner.log.events] == events
    assert stops == ([1] if action == "KILL" else [])
