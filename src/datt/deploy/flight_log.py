"""The flight log: one row per control tick (``flight.csv``), the phases and safety events with
the summary (``events.json``, written once when the flight ends) and the track plots."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import torch

from datt.deploy.clock import WALL
from datt.runs import write_json

COLUMNS = [
    "t_s", "phase", "x", "y", "z", "vx", "vy", "vz", "qw", "qx", "qy", "qz", "ref_x", "ref_y", "ref_z",
    "thrust_mps2", "wx", "wy", "wz", "thrust_cmd", "dhat_x", "dhat_y", "dhat_z", "vbat_v", "decision",
    "jitter_ms", "compute_ms", "sched_t_s", "state_t_s",
]  # fmt: skip


def measured_at(rows: list[dict], round_trip_s: float) -> list[float]:
    """Flight-log time (s from ``t0``) at which the vehicle measured each row's estimate: its stamp
    (``vehicle_s``, the vehicle's clock) on the host's clock, placed by the least transit over the
    flight (``arrived_s − vehicle_s``: the radio's fixed part, jitter only adds) less the radio's
    one way (half ``round_trip_s``, measured at connect; 0 if unknown). A row without a stamp:
    its arrival less the one way; without either (the onboard app's rows): NaN."""
    one_way = round_trip_s / 2 if math.isfinite(round_trip_s) else 0.0

    def stamped(r: dict) -> bool:
        return r.get("vehicle_s") is not None and "arrived_s" in r

    offset = min((r["arrived_s"] - r["vehicle_s"] for r in rows if stamped(r)), default=math.nan) - one_way
    return [r["vehicle_s"] + offset if stamped(r) else r.get("arrived_s", math.nan) - one_way for r in rows]


def errors_when_measured(track: list[dict]) -> list[float]:
    """‖estimate − reference‖ per TRACK row, the reference taken at the time the estimate was
    measured (``state_t_s``), not when it arrived: tick k shows reference point k at its scheduled
    time ``sched_t_s``, interpolated between ticks (held before the first, after the last). An
    estimate arrives an up-link later than the vehicle was there (a radio leg, the log period's
    phase); paired with the tick's reference, a vehicle exactly on a reference moving at v reads
    v × that age of error. This is ``eval.py``'s error (the state at t against p_d(t))."""
    if not track:
        return []
    sched = np.array([r["sched_t_s"] for r in track])
    ref = np.array([r["ref"] for r in track], dtype=float)
    measured = np.array([r["state_t_s"] for r in track], dtype=float)  # NaN (no time) interpolates to NaN
    at = np.stack([np.interp(measured, sched, ref[:, i]) for i in range(3)], axis=-1)
    pos = np.array([r["pos"] for r in track], dtype=float)
    return [float(e) for e in np.linalg.norm(pos - at, axis=-1)]


class FlightLog:
    """Rows and events of one flight, with the phase they happened in (times from ``t0``)."""

    def __init__(
        self, run_dir: Path, console=None, rate_hz: float = 50.0, late_tick_ms: float = 5.0, clock=WALL
    ) -> None:
        self.run_dir = Path(run_dir)
        self.clock = clock  # the flight's (datt.deploy.clock)
        self.console = console
        self.rate_hz, self.late_tick_ms = float(rate_hz), float(late_tick_ms)
        self.rows: list[dict] = []
        self.events: list[dict] = []
        self.phase = "CONNECT"
        self.t0 = self.clock.monotonic()

    def event(self, kind: str, text: str = "", **extra) -> None:
        item = {
            "t_s": round(self.clock.monotonic() - self.t0, 4),
            "phase": self.phase,
            "kind": kind,
            "text": text,
            **extra,
        }
        self.events.append(item)
        if self.console is not None:
            self.console.print(f"[{item['t_s']:7.2f} s] {self.phase:8s} {kind}: {text}")

    def set_phase(self, phase: str) -> None:
        self.phase = phase
        self.event("phase", phase)

    def write(self, summary: dict, track: list[dict]) -> dict:
        """``flight.csv``, ``events.json`` (``summary`` with the timing and the events) and the
        plots of ``track`` (the rows flown against the reference); returns the whole summary."""
        self.run_dir.mkdir(parents=True, exist_ok=True)
        with open(self.run_dir / "flight.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(COLUMNS)
            for r in self.rows:
                w.writerow(
                    [
                        f"{r['t_s']:.4f}", r["phase"], *r["pos"], *r["vel"], *r["quat"], *r["ref"], *r["action"],
                        r["thrust_cmd"], *r["d_hat"], r["vbat"], r["decision"], f"{r['jitter_ms']:.3f}",
                        f"{r['compute_ms']:.3f}", f"{r.get('sched_t_s', math.nan):.4f}",
                        f"{r.get('state_t_s', math.nan):.4f}",
                    ]
                )  # fmt: skip
        jitter = np.array([r["jitter_ms"] for r in self.rows]) if self.rows else np.zeros(1)
        compute = np.array([r["compute_ms"] for r in self.rows]) if self.rows else np.zeros(1)
        summary = {
            **summary,
            "ticks": len(self.rows),
            "jitter_ms": {
                "median": float(np.median(np.abs(jitter))),
                "p99": float(np.percentile(np.abs(jitter), 99)),
                "max": float(np.max(np.abs(jitter))),
            },
            "late_ticks": int(np.sum(jitter > self.late_tick_ms)),
            "compute_ms": {"median": float(np.median(compute)), "p99": float(np.percentile(compute, 99))},
            "events": self.events,
        }
        write_json(self.run_dir / "events.json", summary, default=str)  # strict and atomic, as every run record
        if track:
            self._plot(track)
        return summary

    def _plot(self, track: list[dict]) -> None:
        from types import SimpleNamespace

        from datt.eval.plots import plot_group_axes, plot_tracks

        pos = torch.tensor([r["pos"] for r in track]).unsqueeze(0)
        ref = torch.tensor([r["ref"] for r in track]).unsqueeze(0)
        trace = SimpleNamespace(pos_m=pos, ref_m=ref, crashed_at=torch.tensor([len(track) - 1]))
        plot_tracks(
            trace, ["track"], [1], self.run_dir / "tracks_flight.png", title="flight: reference vs flown", per_group=1
        )
        plot_group_axes(trace, ["track"], [1], 1.0 / self.rate_hz, self.run_dir / "axes_flight.png", title="flight")
