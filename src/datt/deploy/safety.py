"""Per-tick safety decision: OK, LAND (controlled landing) or KILL (motors off now).

Checked every control tick, in this order (the first KILL wins, then the first LAND):

KILL: operator e-stop; link lost; no state estimate or one older than ``kill_state_age_s``;
      non-finite state; outside the geofence by more than ``geofence_margin_m``; tilt above
      ``max_tilt_deg``; below ``track_floor_m`` while tracking (the vehicle sank to the floor:
      a crash, not a flight to land); non-finite command; battery below ``kill_battery_v``.
LAND: a state estimate older than ``max_state_age_s`` (a late log packet: land on the last
      estimate before giving up at ``kill_state_age_s``); outside the geofence box; speed above
      ``max_speed_mps``; external position (mocap) older than ``max_mocap_age_s`` while a mocap
      source is configured; while tracking, more than ``track_sink_m`` below the reference's
      height and not climbing (the vehicle cannot hold its height: at its thrust ceiling a policy
      that keeps turning sinks; the PID lands it before it reaches ``track_floor_m``; a vehicle
      still climbing back, as after a takeoff the thrust lock delayed, is not sinking); command out of range
      (thrust or rates beyond the policy's bounds);
      battery below ``land_battery_v``.

The runner acts on the decision (KILL sends the emergency stop before anything else) and logs
the reason. The battery voltage it is given is low-passed by the runner (:class:`BatteryFilter`):
under load the pack sags for a moment without being empty. All limits are ``conf/deploy/*.yaml``
key ``safety``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from datt.configuration import POSITION_M, Range, check_ranges, ranged
from datt.deploy.firmware import fact

OK, LAND, KILL = "OK", "LAND", "KILL"


# The ranges say what a limit can mean, so that no finite value switches its check off: a value
# outside them is refused in one line (datt.configuration.check_ranges). Each with its reason.
# The LAND band beyond the fence before a breach KILLs: at most 2 m (and less than the fence's
# smallest side, validate()), or a far breach would only LAND.
MARGIN = Range(0.0, 2.0)
# An estimate or a mocap frame older than 2 s is no estimate: limits on ages stay below it.
AGE = Range(0.0, 2.0, low_open=True)
# A Crazyflie 2.x's cell: the firmware's critical voltage (it cuts off below) to a full cell (4.2 V,
# the LiPo chemistry's charge end); a battery limit outside it never fires.
CELL = Range(float(fact("battery_critical_v")), 4.2)
# body rates within the gyro's full scale (beyond it the estimate saturates: a limit there never fires)
GYRO = Range(0.0, math.radians(float(fact("gyro_full_scale_dps"))), low_open=True)


@dataclass
class SafetyParams:
    geofence_min_m: list = ranged([-2.0, -2.0, -0.1], POSITION_M)  # a fence beyond 20 m is no fence for a room
    geofence_max_m: list = ranged([2.0, 2.0, 2.5], POSITION_M)
    geofence_margin_m: float = ranged(0.5, MARGIN)
    # beyond 90 deg the vehicle is upside down: a tilt limit there never fires before the floor
    max_tilt_deg: float = ranged(75.0, Range(0.0, 90.0, low_open=True))
    # a Crazyflie tracks references of 1-3 m/s; 10 m/s in a room is already a crash
    max_speed_mps: float = ranged(4.0, Range(0.0, 10.0, low_open=True))
    max_state_age_s: float = ranged(0.1, AGE)
    kill_state_age_s: float = ranged(0.5, AGE)
    max_mocap_age_s: float = ranged(0.1, AGE)
    land_battery_v: float = ranged(3.3, CELL)
    kill_battery_v: float = ranged(3.0, CELL)
    # the policy's command bound (g + 30 m/s²); the vehicle's own ceiling is lower and the thrust map clips there
    max_thrust_mps2: float = ranged(39.81, Range(0.0, 40.0, low_open=True))
    max_rate_radps: list = ranged([20.0, 20.0, 2.0], GYRO)
    battery_filter_s: float = ranged(1.0, Range(0.0, 10.0))  # time constant of the battery voltage low-pass
    # preflight: the onboard estimate must agree with mocap (beyond 0.5 m they disagree about the room)
    max_estimate_mocap_m: float = ranged(0.05, Range(0.0, 0.5, low_open=True))
    # TRACK below this height: KILL (null: off). A Crazyflie resting on the floor reads its centre
    # ~15 mm up, so a floor below 2 cm never fires; above 1 m it would fire in a normal flight
    track_floor_m: float | None = ranged(0.05, Range(0.02, 1.0, optional=True))
    # TRACK this far below the reference: LAND (null: off); at most 2 m, a room's height
    track_sink_m: float | None = ranged(0.4, Range(0.0, 2.0, low_open=True, optional=True))

    def validate(self) -> None:
        from datt.errors import ConfigError

        check_ranges(self, "deploy.safety")
        if any(lo >= hi for lo, hi in zip(self.geofence_min_m, self.geofence_max_m)) or len(self.geofence_min_m) != 3:
            raise ConfigError("deploy.safety.geofence_min_m/max_m: need 3 values each with min < max")
        if len(self.geofence_max_m) != 3 or len(self.max_rate_radps) != 3:
            raise ConfigError("deploy.safety.geofence_max_m / max_rate_radps: need 3 values each")
        side_m = min(hi - lo for lo, hi in zip(self.geofence_min_m, self.geofence_max_m))
        if not self.geofence_margin_m < side_m:
            raise ConfigError(
                f"deploy.safety.geofence_margin_m: must be less than the fence's smallest side ({side_m:g} m), "
                f"got {self.geofence_margin_m}"
            )
        if not self.kill_battery_v <= self.land_battery_v:
            raise ConfigError("deploy.safety.kill_battery_v: must be <= land_battery_v")
        if not self.max_state_age_s <= self.kill_state_age_s:
            raise ConfigError(
                f"deploy.safety.kill_state_age_s: must be >= max_state_age_s ({self.max_state_age_s}), "
                f"got {self.kill_state_age_s}"
            )


@dataclass
class Decision:
    action: str
    reason: str = ""


def tilt_deg(quat) -> float:
    """Angle between body z and world z for a (w, x, y, z) quaternion."""
    w, x, y, z = quat
    cos_tilt = 1.0 - 2.0 * (x * x + y * y)
    return math.degrees(math.acos(max(-1.0, min(1.0, cos_tilt))))


def check(
    p: SafetyParams,
    *,
    now_s: float,
    state,
    command,
    estop: bool,
    link_lost: bool,
    mocap_age_s: float | None,
    tracking: bool = False,
    reference_z_m: float | None = None,
) -> Decision:
    """``state``: a :class:`~datt.deploy.link.StateSample` or None; ``command``: the action about
    to be sent ``[thrust_mps2, wx, wy, wz]`` (or None before one exists); ``mocap_age_s``: None
    when no mocap source is configured; ``tracking``: the flight is in TRACK (the floor applies);
    ``reference_z_m``: the reference's height now (world frame; None: not known, no sink check)."""
    if estop:
        return Decision(KILL, "operator e-stop")
    if link_lost:
        return Decision(KILL, "link lost")
    if state is None:
        return Decision(KILL, "no state estimate")
    age = now_s - state.t_s
    if age > p.kill_state_age_s:
        return Decision(KILL, f"state estimate stale ({age * 1e3:.0f} ms > {p.kill_state_age_s * 1e3:.0f} ms)")
    values = [*state.pos_m, *state.vel_mps, *state.quat]
    if not all(math.isfinite(v) for v in values):
        return Decision(KILL, "non-finite state estimate")
    lo, hi, margin = p.geofence_min_m, p.geofence_max_m, p.geofence_margin_m
    outside = [max(lo[i] - state.pos_m[i], state.pos_m[i] - hi[i], 0.0) for i in range(3)]
    if max(outside) > margin:
        return Decision(KILL, f"geofence breached by {max(outside):.2f} m (> margin {margin} m)")
    tilt = tilt_deg(state.quat)
    if tilt > p.max_tilt_deg:
        return Decision(KILL, f"tilt {tilt:.0f} deg > {p.max_tilt_deg:.0f} deg")
    floor = p.track_floor_m
    if tracking and floor is not None and state.pos_m[2] < floor:
        return Decision(KILL, f"on the floor while tracking (z {state.pos_m[2]:.2f} m < track_floor_m {floor} m)")
    if command is not None and not all(math.isfinite(float(c)) for c in command):
        return Decision(KILL, "non-finite command")
    if state.vbat_v < p.kill_battery_v:
        return Decision(KILL, f"battery {state.vbat_v:.2f} V < {p.kill_battery_v} V")
    if age > p.max_state_age_s:
        return Decision(LAND, f"state estimate stale ({age * 1e3:.0f} ms > {p.max_state_age_s * 1e3:.0f} ms)")
    if max(outside) > 0:
        return Decision(LAND, f"outside geofence by {max(outside):.2f} m")
    speed = math.sqrt(sum(v * v for v in state.vel_mps))
    if speed > p.max_speed_mps:
        return Decision(LAND, f"speed {speed:.1f} m/s > {p.max_speed_mps} m/s")
    if tracking and (sinking := _sinking(p, state.pos_m[2], state.vel_mps[2], reference_z_m)) is not None:
        return sinking
    if mocap_age_s is not None and mocap_age_s > p.max_mocap_age_s:
        return Decision(LAND, f"mocap stale ({mocap_age_s * 1e3:.0f} ms > {p.max_mocap_age_s * 1e3:.0f} ms)")
    if command is not None:
        thrust, rates = float(command[0]), [abs(float(c)) for c in command[1:]]
        if not 0.0 <= thrust <= p.max_thrust_mps2 or any(r > m + 1e-6 for r, m in zip(rates, p.max_rate_radps)):
            return Decision(LAND, "command out of range")
    if state.vbat_v < p.land_battery_v:
        return Decision(LAND, f"battery {state.vbat_v:.2f} V < {p.land_battery_v} V")
    return Decision(OK)


def _sinking(p: SafetyParams, z_m: float, vz_mps: float, reference_z_m: float | None) -> Decision | None:
    """LAND when the vehicle is more than ``track_sink_m`` below the reference's height (a
    reference that is not a number counts as too far) and not climbing (``vz_mps`` <= 0, world z
    up), else None (also with no reference or the check off)."""
    sink = p.track_sink_m
    if sink is None or reference_z_m is None or reference_z_m - z_m <= sink or vz_mps > 0.0:
        return None
    return Decision(
        LAND,
        f"sinking while tracking (z {z_m:.2f} m, {reference_z_m - z_m:.2f} m below the "
        f"reference > track_sink_m {sink} m: the thrust cannot hold the height)",
    )


class BatteryFilter:
    """First-order low-pass of the battery voltage with time constant ``tau_s`` (0 = no filter);
    starts at the first reading."""

    def __init__(self, tau_s: float) -> None:
        self.tau_s = float(tau_s)
        self.value_v: float | None = None

    def update(self, vbat_v: float, dt_s: float) -> float:
        if self.value_v is None or self.tau_s <= 0 or not math.isfinite(vbat_v):
            self.value_v = vbat_v
        else:
            self.value_v += (vbat_v - self.value_v) * min(1.0, dt_s / self.tau_s)
        return self.value_v
