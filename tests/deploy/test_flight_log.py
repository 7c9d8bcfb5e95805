"""The flight log's bookkeeping from hand-built rows: what events.json and flight.csv say."""

from __future__ import annotations

import csv
import json
import math

import numpy as np
import pytest

from datt.deploy.flight_log import COLUMNS, FlightLog


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
    assert (tmp_path / "events.json").exists() and not (tmp_path / "track.png").exists()


def test_the_runner_scores_only_the_track_ticks(tmp_path):
    """track_error_m is the mean |pos − ref| over the TRACK rows only (takeoff and landing rows
    are logged but not scored), track_steps their count; with a reference that stands still the
    reference when measured is the tick's own, so track_error_received_m is the same."""
    from types import SimpleNamespace

    from datt.deploy.outcome import Kind, Outcome
    from datt.deploy.runner import FlightRunner

    runner = FlightRunner.__new__(FlightRunner)  # the bookkeeping alone: no link, no vehicle
    runner.log = FlightLog(tmp_path)
    runner.outcome = Outcome(Kind.LANDED)
    runner.summary_extra = {"controller": "datt"}
    runner.link = SimpleNamespace(round_trip_s=0.04)
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
