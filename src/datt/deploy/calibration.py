"""The calibration flight (``deploy.mode=calibrate``): take off with the PID, hover with a thrust
square wave, land; fit the thrust map (hover command, slope) and measure the loop's
command-to-response latency (docs/deploy.md, first flight step 7)."""

from __future__ import annotations

import numpy as np

from datt.deploy.runner import FlightRunner, Ramp
from datt.deploy.safety import KILL, OK


class CalibrationFlight(FlightRunner):
    def __init__(self, *args, hover_s: float = 4.0, excitation_mps2: float = 1.0, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.hover_s, self.excitation_mps2 = float(hover_s), float(excitation_mps2)

    def fly(self) -> dict:
        """Hover calibration flight: takeoff, then hold the hover point with the PID while a slow
        square wave of ±``excitation_mps2`` is added to its thrust. From the logged velocity:
        the loop's response latency (ticks from a command to the state showing its effect,
        :func:`~datt.deploy.thrust.response_lag_ticks`), then, with the commands shifted by it,
        the command at which the vertical acceleration is zero and the slope of acceleration
        against command (:func:`~datt.deploy.thrust.fit_hover`); then land. Returns the summary
        with ``calibration`` = ``{hover_command, slope_mps2_per_command, response_latency_ms}``
        (set the first two as ``deploy.thrust.*``)."""
        from datt.deploy.thrust import fit_hover, response_lag_ticks

        fitted = {}

        def build(start_rel):
            return self._takeoff(start_rel), self._model(self.pid_factory(), Ramp([0.0] * 3, [0.0] * 3, 1.0))

        def airborne(origin, built):
            (name, takeoff, duration), hold = built
            self._set_phase(name)
            if self._fly_phase(takeoff, duration, origin) != OK:
                return
            self._set_phase("CALIBRATE")
            half_period = int(self.p.rate_hz / 2)
            self._excitation = lambda k: self.excitation_mps2 * self._square(k, half_period)
            first = len(self.rows)
            result = self._tick_loop(hold, int(self.hover_s * self.p.rate_hz), origin)
            self._excitation = None
            if result == OK:
                rows = self.rows[first:]
                acc = list(np.diff([r["vel"][2] for r in rows]) * self.p.rate_hz)
                lag = response_lag_ticks([self._square(k, half_period) for k in range(len(acc))], acc)
                shift = int(round(lag))
                cmds = [float(r["thrust_cmd"]) for r in rows[: len(acc) - shift]]
                hover, slope = fit_hover(cmds, acc[shift:])
                latency_ms = lag / self.p.rate_hz * 1000.0
                fitted.update(hover_command=hover, slope_mps2_per_command=slope, response_latency_ms=latency_ms)
                self._event(
                    "calibrated",
                    f"hover command {hover:.0f}, slope {slope:.3e} m/s² per unit, "
                    f"command-to-response latency {latency_ms:.0f} ms",
                )
            if result != KILL:
                self._land(origin)

        summary = self._flight(build, airborne)
        summary["calibration"] = fitted or None
        return summary

    @staticmethod
    def _square(k: int, half_period: int) -> float:
        return 1.0 if (k // half_period) % 2 else -1.0
