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
    are logged but not scored), track_steps their count."""
    from datt.deploy.outcome import Kind, Outcome
    from datt.deploy.runner import FlightRunner

    runner = FlightRunner.__new__(FlightRunner)  # the bookkeeping alone: no link, no vehicle
    runner.log = FlightLog(tmp_path)
    runner.outcome = Outcome(Kind.LANDED)
    runner.summary_extra = {"controller": "datt"}
    errors = [0.3, 0.1, 0.2, 0.4]
    runner.log.rows = [row(0, "TAKEOFF", 0.0, 1.0, 2.0)]
    runner.log.rows += [row(k + 1, "TRACK", 0.0, 1.0, e) for k, e in enumerate(errors)]
    runner.log.rows += [row(9, "LAND", 0.0, 1.0, 5.0)]
    summary = runner._write()
    assert summary["track_steps"] == 4 and summary["track_error_m"] == pytest.approx(sum(errors) / 4)
    assert summary["ticks"] == 6 and summary["controller"] == "datt"
    assert math.isclose(runner._track_errors()[1], 0.1)
