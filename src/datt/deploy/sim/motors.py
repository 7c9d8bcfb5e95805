"""The simulated Crazyflie's own motors: what the firmware does with a thrust command, and what the
vehicle then gets. Never the controller's :class:`~datt.deploy.thrust.ThrustMap`: a calibration
or a wrong mass on the controller side must show up as a tracking error, not cancel out.

Firmware (``motors.c``, battery-compensated build; ``platform_defaults_cf2.h``, 2.1+ propellers):
per motor the command ``c`` asks for ``F = c / 65535 * THRUST_MAX`` N; below ``THRUST_MIN`` the
motor is off; otherwise the firmware solves the cubic ``F(v) = p0 + p1 v + p2 v² + p3 v³`` for the
motor voltage ``v`` and sets the PWM ratio ``v / v_battery``, which cannot exceed 1: with a low
battery the largest force is ``F(v_battery)``. The vehicle's real motors deliver ``thrust_gain``
times what the firmware's fit says (worn propellers, another propeller type: the fit is not
exact), and the vehicle has its own mass.
"""

from __future__ import annotations

from dataclasses import dataclass

from datt.configuration import NON_NEGATIVE, POSITIVE, POSITIVE_OR_NONE, check_ranges, ranged
from datt.errors import ConfigError

UINT16_MAX = 65535
# VMOTOR2THRUST0..3 of the firmware for 2.1+ propellers (N per motor against motor volts)
VMOTOR2THRUST_21_PLUS = (-0.02476537915958403, 0.06523793527519485, -0.026792504967750107, 0.006776789303971145)


@dataclass
class MotorParams:
    """``deploy.server`` motor keys: the simulated vehicle and the firmware it runs."""

    mass_kg: float | None = ranged(0.034, POSITIVE_OR_NONE)  # null in the config: deploy.thrust.mass_kg
    thrust_max_n: float = ranged(0.12, POSITIVE)  # the simulated firmware's THRUST_MAX (0.1125 before 2025-11)
    thrust_min_n: float = ranged(0.012817578393224994, NON_NEGATIVE)  # THRUST_MIN: below it the motor stops
    thrust_gain: float = ranged(1.0, POSITIVE)  # real motor force / the firmware's fit

    def validate(self) -> None:
        check_ranges(self, "deploy.server")
        if self.mass_kg is None:
            raise ConfigError("deploy.server.mass_kg: the simulated vehicle needs a mass")


class FirmwareMotors:
    def __init__(self, p: MotorParams | None = None) -> None:
        self.p = p or MotorParams()
        self.p.validate()

    @staticmethod
    def fit_force_n(volts: float) -> float:
        p0, p1, p2, p3 = VMOTOR2THRUST_21_PLUS
        return p0 + volts * (p1 + volts * (p2 + volts * p3))

    def motor_force_n(self, command: int, battery_v: float) -> float:
        """One motor's force for ``command`` at ``battery_v``."""
        if battery_v < 2.0:  # the firmware's sanity floor: motors off
            return 0.0
        asked = min(max(command, 0), UINT16_MAX) / UINT16_MAX * self.p.thrust_max_n
        if asked < self.p.thrust_min_n:
            return 0.0
        available = self.fit_force_n(battery_v)  # PWM ratio capped at 1
        return self.p.thrust_gain * min(asked, available)

    def command_for_mps2(self, thrust_mps2: float) -> int:
        """The command at which all four of this vehicle's motors give ``thrust_mps2`` on its mass:
        what a height controller on the vehicle settles to (its integral finds the motors' true
        gain, which the firmware's map does not know)."""
        per_motor_n = max(0.0, thrust_mps2) * self.p.mass_kg / 4.0 / self.p.thrust_gain
        return int(min(UINT16_MAX, per_motor_n / self.p.thrust_max_n * UINT16_MAX))

    def thrust_mps2(self, command: int, battery_v: float) -> float:
        """Collective mass-normalised thrust with all four motors at ``command``."""
        return 4.0 * self.motor_force_n(command, battery_v) / self.p.mass_kg
