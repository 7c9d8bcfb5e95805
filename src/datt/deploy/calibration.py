"""The calibration flight (``deploy.mode=calibrate``): take off with the PID, hover with a thrust
square wave, land; fit the thrust map (hover command, slope) and measure the loop's
command-to-response latency (docs/deploy.md, first flight step 7)."""

from __future__ import annotations

import numpy as np

from datt.deploy.runner import FlightRunner, Ramp
from datt.deploy.safety import KILL, OK
from datt.deploy.thrust import fit_hover, response_lag_ticks

CALIBRATION_KEYS = ("hover_command", "slope_mps2_per_command", "response_latency_ms")
EXCITATION_MPS2 = 1.0  # the square wave's amplitude added to the PID's thrust (m/s²)


def excitation_half_period(rate_hz: float) -> int:
    """Ticks per half period of the calibration's square wave: half a second (a 1 Hz wave)."""
    return int(rate_hz / 2)


def square_wave(k: int, half_period: int) -> float:
    """The excitation's sign at tick ``k``: −1 for the first ``half_period`` ticks, then +1, ..."""
    return 1.0 if (k // half_period) % 2 else -1.0


def fit_calibration(vel_z_mps: list[float], thrust_cmds: list[float], rate_hz: float) -> dict[str, float]:
    """The calibration's fit from the hover stretch: ``vel_z_mps[k]`` is the vertical velocity
    (world z, m/s) in the state read at tick ``k``, ``thrust_cmds[k]`` the thrust command sent at
    tick ``k`` (uint16 units; the square wave of :func:`square_wave` from tick 0 is in it).
    The vertical acceleration between consecutive states gives the loop's response latency
    (:func:`~datt.deploy.thrust.response_lag_ticks`, in ms at ``rate_hz``); with the commands
    shifted by it (rounded to ticks), the least-squares line of acceleration against command
    gives the hover command and the slope (:func:`~datt.deploy.thrust.fit_hover`). Returns
    ``{hover_command, slope_mps2_per_command, response_latency_ms}``; raises ValueError when the
    samples cannot give them."""
    if len(vel_z_mps) != len(thrust_cmds):
        raise ValueError("calibration: one vertical velocity per thrust command is needed")
    half_period = excitation_half_period(rate_hz)
    acc = list(np.diff(vel_z_mps) * rate_hz)
    lag = response_lag_ticks([square_wave(k, half_period) for k in range(len(acc))], acc)
    shift = int(round(lag))
    cmds = [float(c) for c in thrust_cmds[: len(acc) - shift]]
    hover, slope = fit_hover(cmds, acc[shift:])
    return dict(zip(CALIBRATION_KEYS, (hover, slope, lag / rate_hz * 1000.0)))


class CalibrationFlight(FlightRunner):
    def __init__(self, *args, hover_s: float, excitation_mps2: float = EXCITATION_MPS2, **kwargs) -> None:
        """``hover_s``: the hover's length under the square wave (``deploy.calibrate_hover_s``);
        the rest as :class:`~datt.deploy.runner.FlightRunner`."""
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
        fitted = {}

        def build(start_rel):
            return self._takeoff(start_rel), self._model(self.pid_factory(), Ramp([0.0] * 3, [0.0] * 3, 1.0))

        def airborne(origin, built):
            (name, takeoff, duration), hold = built
            self._set_phase(name)
            if self._fly_phase(takeoff, duration, origin) != OK:
                return
            if not self._lifted_off(name):
                self._land(origin)
                return
            self._set_phase("CALIBRATE")
            half_period = excitation_half_period(self.p.rate_hz)
            self._excitation = lambda k: self.excitation_mps2 * square_wave(k, half_period)
            first = len(self.rows)
            result = self._tick_loop(hold, int(self.hover_s * self.p.rate_hz), origin)
            self._excitation = None
            if result == OK:
                rows = self.rows[first:]
                fitted.update(
                    fit_calibration([r["vel"][2] for r in rows], [r["thrust_cmd"] for r in rows], self.p.rate_hz)
                )
                hover, slope, latency_ms = (fitted[k] for k in CALIBRATION_KEYS)
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
