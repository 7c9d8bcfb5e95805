"""The simulated Crazyflie's own motors: what the firmware does with a thrust command, and what the
vehicle then gets. Never the controller's :class:`~datt.deploy.thrust.ThrustMap`: a calibration
or a wrong mass on the controller side must show up as a tracking error, not cancel out.

Firmware (``motors.c``, battery-compensated build; ``platform_defaults_cf2.h``, the preset's propellers):
per motor the command ``c`` asks for ``F = c / 65535 * THRUST_MAX`` N; below ``THRUST_MIN`` the
motor is off; otherwise the firmware solves the cubic ``F(v) = p0 + p1 v + p2 v² + p3 v³`` for the
motor voltage ``v`` and sets the PWM ratio ``v / v_battery``, which cannot exceed 1: with a low
battery the largest force is ``F(v_battery)``. The vehicle's real motors deliver ``thrust_gain``
times what the firmware's fit says (worn propellers, another propeller type: the fit is not
exact), and the vehicle has its own mass.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

from datt.configuration import MASS_KG, MOTOR_THRUST_N, Range, check_ranges, ranged
from datt.errors import ConfigError
from datt.sim.vehicles import DEFAULT_VEHICLE, VEHICLES, Vehicle, vehicle

UINT16_MAX = 65535


@dataclass
class MotorParams:
    """``deploy.server`` motor keys: the simulated vehicle and the firmware it runs."""

    vehicle: str = ranged(DEFAULT_VEHICLE, Range(choices=tuple(VEHICLES)))  # the preset (deploy.vehicle)
    mass_kg: float | None = ranged(None, replace(MASS_KG, optional=True))  # None: the preset's flying mass
    # the firmware's THRUST_MAX; None: the preset's
    thrust_max_n: float | None = ranged(None, replace(MOTOR_THRUST_N, optional=True))
    thrust_min_n: float | None = ranged(None, Range(0.0, 10.0, optional=True))  # THRUST_MIN; None: the preset's
    thrust_gain: float = ranged(1.0, Range(0.0, 10.0, low_open=True))  # real motor force / the firmware's fit

    def validate(self) -> None:
        check_ranges(self, "deploy.server")
        preset = vehicle(self.vehicle)
        self.mass_kg = preset.mass_kg if self.mass_kg is None else self.mass_kg
        self.thrust_max_n = preset.thrust_max_n if self.thrust_max_n is None else self.thrust_max_n
        self.thrust_min_n = preset.thrust_min_n if self.thrust_min_n is None else self.thrust_min_n
        if not self.thrust_min_n < self.thrust_max_n:
            raise ConfigError(
                f"deploy.server.thrust_min_n: must be below thrust_max_n ({self.thrust_max_n}), got {self.thrust_min_n}"
            )


class FirmwareMotors:
    def __init__(self, p: MotorParams | None = None) -> None:
        self.p = p or MotorParams()
        self.p.validate()
        self.vehicle: Vehicle = vehicle(self.p.vehicle)

    def fit_force_n(self, volts: float) -> float:
        """The firmware's motor fit (the preset's VMOTOR2THRUST0..3): N per motor at ``volts``."""
        p0, p1, p2, p3 = self.vehicle.vmotor2thrust
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
