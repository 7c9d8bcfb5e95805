"""Policy action -> Crazyflie setpoint: thrust in m/s² to the firmware's 16-bit command, body rates
in rad/s to the legacy commander's deg/s, and back.

Thrust map: the firmware (``motors.c`` with ``CONFIG_ENABLE_THRUST_BAT_COMPENSATED``, the default)
turns the command ``c`` in [0, 65535] into a per-motor force ``c / 65535 * THRUST_MAX`` and finds
the motor voltage for it from a cubic fit, compensating the battery voltage: thrust is *linear* in
the command. ``THRUST_MAX`` depends on the firmware (``platform_defaults_cf2.h``): 0.12 N per motor
since 2025-11 (commit b6127943), 0.1125 N before; 0.18 N (0.1625 before) with the thrust upgrade
kit. So a vehicle of mass ``m`` gets ``a = k c`` with ``k = 4 THRUST_MAX / (65535 m)`` m/s² per
command unit, hovers at ``g / k`` and tops out at ``k * max_command`` (34 g, 0.12 N, 60000: 12.9
m/s²). A calibration flight (:func:`fit_hover`) measures the real vehicle's hover command and
slope; the map then runs through the measured hover point with the measured slope:
``c(a) = c_h + (a - g) / k``. Commands are clipped to ``[0, max_command]``; ``max_command`` is at
most the legacy commander's ``MAX_THRUST`` (60000, ``crtp_commander_rpyt.c``), to which the
firmware itself clamps every off-board setpoint. The onboard app's setpoints do not pass that
clamp (``commanderSetSetpoint``: ``controller_pid.c`` flies the setpoint's thrust as given), so the
app clips at ``app_max_command`` instead, at most ``UINT16_MAX``: there the power distribution
(``power_distribution_quadrotor.c``) lowers all four motors by the highest one's excess, keeping
the attitude torques and giving up collective thrust.

Rate conventions (FLU body frame, as the simulator and the policy): the legacy RPYT packet in
rate mode carries roll rate ``deg(ωx)``, pitch ``deg(ωy)`` (cflib negates it on the wire and the
firmware's legacy pitch sign negates it back) and yaw ``−deg(ωz)`` (the firmware negates the
legacy yaw). This follows the firmware sources (``crtp_commander_rpyt.c``, ``controller_pid.c``);
check it on a vehicle with the ``hardware`` test before a real flight. The firmware does not
limit rate setpoints; ``max_rate_degps`` is this project's limit on what it sends.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from datt.configuration import GRAVITY_MPS2, MASS_KG, MOTOR_THRUST_N, Range, check_ranges, ranged
from datt.deploy.firmware import FIRMWARE_VERSION, fact
from datt.sim.vehicles import CF21

UINT16_MAX = 65535


@dataclass
class ThrustParams:
    """``conf/deploy/*.yaml`` key ``thrust`` (the ``cf21`` preset's numbers by default)."""

    mass_kg: float = ranged(CF21.mass_kg, MASS_KG)  # null in the YAML = the preset's (deploy.vehicle)
    gravity_mps2: float = ranged(9.81, GRAVITY_MPS2)
    # the firmware's THRUST_MAX per motor (datt.sim.vehicles; null in the YAML = the preset's)
    thrust_max_n: float = ranged(CF21.thrust_max_n, MOTOR_THRUST_N)
    hover_command: float | None = ranged(
        None, Range(0.0, 65535.0, low_open=True, optional=True)
    )  # calibrated; None = the firmware map's own (g / k)
    # calibrated k; None = 4 THRUST_MAX / (65535 m)
    slope_mps2_per_command: float | None = ranged(None, Range(0.0, 0.01, low_open=True, optional=True))
    max_command: int = 60000
    # the onboard app's ceiling: its setpoints skip the legacy clamp (docs/deploy.md)
    app_max_command: int = 65535
    max_rate_degps: list = ranged([720.0, 720.0, 400.0], Range(0.0, 2000.0, low_open=True))

    def validate(self) -> None:
        from datt.errors import ConfigError

        check_ranges(self, "deploy.thrust")  # mass, gravity, THRUST_MAX, hover, slope, rate limits
        top = int(fact("rpyt_max_thrust"))
        if not 0 < self.max_command <= top:
            raise ConfigError(
                f"deploy.thrust.max_command: must be in (0, {top}], got {self.max_command} (the firmware clamps "
                f"a legacy setpoint's thrust to MAX_THRUST {top}: crtp_commander_rpyt.c, {FIRMWARE_VERSION})"
            )
        app_top = UINT16_MAX  # fact("power_cap_max_thrust"): the power distribution's cap per motor
        if not 0 < self.app_max_command <= app_top:
            raise ConfigError(
                f"deploy.thrust.app_max_command: must be in (0, {app_top}], got {self.app_max_command} (the "
                f"onboard app's setpoint thrust is a uint16; the power distribution caps each motor at "
                f"{fact('power_cap_max_thrust')}: power_distribution_quadrotor.c, {FIRMWARE_VERSION})"
            )
        if self.hover_command is not None and not 0 < self.hover_command < self.max_command:
            raise ConfigError(f"deploy.thrust.hover_command: must be in (0, max_command), got {self.hover_command}")


class ThrustMap:
    def __init__(self, p: ThrustParams | None = None) -> None:
        self.p = p or ThrustParams()
        self.p.validate()
        self.firmware_slope = 4.0 * self.p.thrust_max_n / (UINT16_MAX * self.p.mass_kg)
        self.slope = self.p.slope_mps2_per_command or self.firmware_slope
        g = self.p.gravity_mps2
        self.hover_command = self.p.hover_command if self.p.hover_command is not None else g / self.firmware_slope
        for key in ("max_command", "app_max_command"):
            if self.hover_command >= getattr(self.p, key):
                from datt.errors import ConfigError

                raise ConfigError(
                    f"deploy.thrust: a {self.p.mass_kg * 1000:.1f} g vehicle needs command {self.hover_command:.0f} to "
                    f"hover with thrust_max_n={self.p.thrust_max_n} N, above {key}={getattr(self.p, key)}"
                )

    @property
    def ceiling_mps2(self) -> float:
        """The most collective thrust the map will command (at ``max_command``)."""
        return self.thrust_mps2(self.p.max_command)

    def rescale(self, scale: float) -> None:
        """The vehicle needs ``scale`` times the commands the map gives (a heavier vehicle, weaker
        motors, an emptier battery: thrust is linear in the command, so each of these scales it):
        hover command times ``scale``, slope divided by it."""
        if not (math.isfinite(scale) and scale > 0):
            raise ValueError(f"thrust map: the scale must be finite and positive, got {scale}")
        self.hover_command *= scale
        self.slope /= scale

    def command(self, thrust_mps2: float) -> int:
        """Firmware thrust command for a mass-normalised collective thrust (clipped)."""
        if not math.isfinite(thrust_mps2) or thrust_mps2 <= 0:
            return 0
        c = self.hover_command + (thrust_mps2 - self.p.gravity_mps2) / self.slope
        return int(min(max(round(c), 0), self.p.max_command))

    def thrust_mps2(self, command: int) -> float:
        """What the map expects ``command`` to give (0 for command 0)."""
        if command <= 0:
            return 0.0
        return max(0.0, self.p.gravity_mps2 + self.slope * (float(command) - self.hover_command))

    def rates_deg(self, wx: float, wy: float, wz: float) -> tuple[float, float, float]:
        """(roll, pitch, yaw) arguments of cflib's ``send_setpoint`` for body rates in rad/s."""
        lim = self.p.max_rate_degps
        clip = lambda v, m: max(-m, min(m, v))  # noqa: E731
        return (clip(math.degrees(wx), lim[0]), clip(math.degrees(wy), lim[1]), clip(-math.degrees(wz), lim[2]))

    def as_sent(self, thrust_mps2: float, wx: float, wy: float, wz: float) -> list[float]:
        """What the vehicle is asked for when (thrust m/s², body rates rad/s) is sent: the thrust
        the map expects of the clipped command, the rates clipped to ``max_rate_degps``."""
        roll, pitch, yaw = self.rates_deg(wx, wy, wz)
        thrust = self.thrust_mps2(self.command(thrust_mps2))
        return [thrust, math.radians(roll), math.radians(pitch), -math.radians(yaw)]

    @staticmethod
    def body_rates_from_wire(roll: float, pitch_wire: float, yaw: float) -> tuple[float, float, float]:
        """What the firmware's rate controller tracks, in rad/s, from the packet's fields."""
        return math.radians(roll), math.radians(-pitch_wire), math.radians(-yaw)


def fit_hover(commands: list[float], vertical_acc_mps2: list[float]) -> tuple[float, float]:
    """Calibration: (hover command, slope in m/s² per command unit) from samples flown around
    hover: the least-squares line through (command, a_z); the hover command is its zero (needs
    two distinct commands and an acceleration that rises with the command)."""
    n = len(commands)
    if n < 2 or len(vertical_acc_mps2) != n or len(set(commands)) < 2:
        raise ValueError("calibration needs at least two distinct commands with one acceleration each")
    mc, ma = sum(commands) / n, sum(vertical_acc_mps2) / n
    slope = sum((c - mc) * (a - ma) for c, a in zip(commands, vertical_acc_mps2)) / sum((c - mc) ** 2 for c in commands)
    if slope <= 0:
        raise ValueError("calibration: acceleration does not increase with the command")
    return mc - ma / slope, slope


def hover_command_from_hover(
    t_s: list[float], vel_z_mps: list[float], commands: list[float], g_mps2: float = 9.81
) -> float:
    """The command that holds the vehicle's height, from a stretch of hover: with thrust linear
    in the command through zero (``a + g = k c``, the firmware's battery-compensated map, whatever
    the vehicle's mass and motors), the mean command ``c̄`` over the stretch (``commands[i]`` acting
    from ``t_s[i]`` to ``t_s[i + 1]``, weighted by that time; the last one acts after the stretch)
    and the mean vertical acceleration ``ā`` (first and last velocity) give ``k = (ā + g) / c̄``
    and the hover command ``g / k = c̄ g / (ā + g)`` (NaN for ``ā <= -g``). Needs two samples over
    a positive time. The commands are the ones acting on the logged velocities
    (:func:`commands_acting`), not the ones sent at the same ticks."""
    if len(t_s) < 2 or not len(t_s) == len(vel_z_mps) == len(commands) or not t_s[-1] > t_s[0]:
        raise ValueError("hover trim: needs at least two samples over a positive time")
    span = t_s[-1] - t_s[0]
    acc = (vel_z_mps[-1] - vel_z_mps[0]) / span
    if not acc + g_mps2 > 0:  # falling at g or faster: no command explains it
        return math.nan
    mean_command = sum(c * (t1 - t0) for c, t0, t1 in zip(commands, t_s[:-1], t_s[1:])) / span
    return mean_command * g_mps2 / (acc + g_mps2)


def commands_acting(t_s: list[float], sent_t_s: list[float], sent_commands: list[float], lag_s: float) -> list[float]:
    """The command acting at each time of ``t_s``: the one sent ``lag_s`` earlier (``sent_t_s``
    increasing, the same clock), linearly interpolated between sends; before the first send, the
    first. What :func:`hover_command_from_hover` pairs with a stretch of logged velocities, whose
    changes show the commands sent one latency before them."""
    if not sent_t_s or len(sent_t_s) != len(sent_commands):
        raise ValueError("commands_acting: needs the commands sent, each with its time")
    return [float(c) for c in np.interp(np.asarray(t_s, dtype=float) - lag_s, sent_t_s, sent_commands)]


def response_lag_ticks(excitation: list[float], vertical_acc_mps2: list[float], window: int = 10) -> float:
    """Ticks from a step of the thrust excitation to the acceleration reaching half of its jump in
    the logged state, median over the excitation's steps (dead time plus half the rise; linear
    interpolation between ticks). ``excitation[k]`` is what was added to the command sent at tick
    ``k``; ``vertical_acc_mps2[k]`` the acceleration between the states read at ticks ``k`` and
    ``k + 1``. The jump is the largest change within ``window`` ticks of the step, against the
    mean of the 3 samples before it."""
    n = min(len(excitation), len(vertical_acc_mps2))
    lags = []
    for k in range(3, n - window):
        step = excitation[k] - excitation[k - 1]
        if step == 0:
            continue
        sign = 1.0 if step > 0 else -1.0
        base = sum(vertical_acc_mps2[k - 3 : k]) / 3.0
        rise = [sign * (vertical_acc_mps2[j] - base) for j in range(k - 1, k + window)]
        half = 0.5 * max(rise)
        for j in range(1, len(rise)):
            if rise[j] >= half > rise[j - 1]:
                lags.append(j - 1 + (half - rise[j - 1]) / (rise[j] - rise[j - 1]) - 1.0)
                break
    if not lags:
        raise ValueError("latency: needs an excitation with steps and the samples after them")
    lags.sort()
    mid = len(lags) // 2
    return lags[mid] if len(lags) % 2 else 0.5 * (lags[mid - 1] + lags[mid])
