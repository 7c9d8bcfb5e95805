"""Policy action -> Crazyflie setpoint: thrust in m/s² to the firmware's 16-bit command, body rates
in rad/s to the legacy commander's deg/s, and back (the simulated firmware decodes with the same
model, so the round trip is tested).

Thrust model (Bitcraze system identification of the Crazyflie 2.x motors, Förster 2015): one
motor's force at command ``c`` in [0, 65535] is ``f(c) = k2 c² + k1 c + k0`` N. The vehicle's
collective acceleration is ``a = 4 s f(c) / m`` where ``s`` corrects the model with a calibrated
hover command ``c_h`` (``s = m g / (4 f(c_h))``: at ``c_h`` the vehicle hovers exactly). Inverting
the quadratic gives ``c(a)``; commands are clipped to ``[0, max_command]``.

Rate conventions (FLU body frame, as the simulator and the policy): the legacy RPYT packet in
rate mode carries roll rate ``deg(ωx)``, pitch ``deg(ωy)`` (cflib negates it on the wire and the
firmware's legacy pitch sign negates it back) and yaw ``−deg(ωz)`` (the firmware negates the
legacy yaw). This follows the firmware sources (``crtp_commander_rpyt.c``, ``controller_pid.c``);
check it on a vehicle with the ``hardware`` test before a real flight.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class ThrustParams:
    """``conf/deploy/*.yaml`` key ``thrust`` (Crazyflie 2.1 with mocap markers by default)."""

    mass_kg: float = 0.034
    gravity_mps2: float = 9.81
    k2: float = 2.130295e-11
    k1: float = 1.032633e-6
    k0: float = 5.484560e-4
    hover_command: float | None = None  # calibrated; None = the model's own hover point
    max_command: int = 60000
    max_rate_degps: list = field(default_factory=lambda: [720.0, 720.0, 400.0])

    def validate(self) -> None:
        from datt.errors import ConfigError

        if not self.mass_kg > 0:
            raise ConfigError(f"deploy.thrust.mass_kg: must be > 0, got {self.mass_kg}")
        if not 0 < self.max_command <= 65535:
            raise ConfigError(f"deploy.thrust.max_command: must be in (0, 65535], got {self.max_command}")
        if self.hover_command is not None and not 0 < self.hover_command < self.max_command:
            raise ConfigError(f"deploy.thrust.hover_command: must be in (0, max_command), got {self.hover_command}")


class ThrustMap:
    def __init__(self, p: ThrustParams | None = None) -> None:
        self.p = p or ThrustParams()
        self.p.validate()
        model_hover = self._model_command(self.p.mass_kg * self.p.gravity_mps2 / 4.0)
        hover = self.p.hover_command if self.p.hover_command is not None else model_hover
        self.scale = self.p.mass_kg * self.p.gravity_mps2 / (4.0 * self.force_n(hover))
        self.hover_command = hover

    def force_n(self, command: float) -> float:
        """Model force of one motor at ``command``."""
        return self.p.k2 * command * command + self.p.k1 * command + self.p.k0

    def _model_command(self, force_n: float) -> float:
        k2, k1, k0 = self.p.k2, self.p.k1, self.p.k0
        disc = k1 * k1 - 4 * k2 * (k0 - force_n)
        return (-k1 + math.sqrt(max(disc, 0.0))) / (2 * k2)

    def command(self, thrust_mps2: float) -> int:
        """Firmware thrust command for a mass-normalised collective thrust (clipped)."""
        if not math.isfinite(thrust_mps2) or thrust_mps2 <= 0:
            return 0
        force = self.p.mass_kg * thrust_mps2 / (4.0 * self.scale)
        if force <= self.p.k0:
            return 0
        return int(min(max(round(self._model_command(force)), 0), self.p.max_command))

    def thrust_mps2(self, command: int) -> float:
        """Inverse of :meth:`command` (the simulated firmware's motor model); 0 for command 0."""
        if command <= 0:
            return 0.0
        return 4.0 * self.scale * self.force_n(float(command)) / self.p.mass_kg

    def rates_deg(self, wx: float, wy: float, wz: float) -> tuple[float, float, float]:
        """(roll, pitch, yaw) arguments of cflib's ``send_setpoint`` for body rates in rad/s."""
        lim = self.p.max_rate_degps
        clip = lambda v, m: max(-m, min(m, v))  # noqa: E731
        return (clip(math.degrees(wx), lim[0]), clip(math.degrees(wy), lim[1]), clip(-math.degrees(wz), lim[2]))

    @staticmethod
    def body_rates_from_wire(roll: float, pitch_wire: float, yaw: float) -> tuple[float, float, float]:
        """What the firmware's rate controller tracks, in rad/s, from the packet's fields."""
        return math.radians(roll), math.radians(-pitch_wire), math.radians(-yaw)


def fit_hover_command(commands: list[float], vertical_acc_mps2: list[float]) -> float:
    """Calibration: the command at which vertical acceleration is zero, from samples flown
    around hover (least-squares line through (command, a_z); needs two distinct commands)."""
    n = len(commands)
    if n < 2 or len(vertical_acc_mps2) != n or len(set(commands)) < 2:
        raise ValueError("calibration needs at least two distinct commands with one acceleration each")
    mc, ma = sum(commands) / n, sum(vertical_acc_mps2) / n
    slope = sum((c - mc) * (a - ma) for c, a in zip(commands, vertical_acc_mps2)) / sum((c - mc) ** 2 for c in commands)
    if slope <= 0:
        raise ValueError("calibration: acceleration does not increase with the command")
    return mc - ma / slope
