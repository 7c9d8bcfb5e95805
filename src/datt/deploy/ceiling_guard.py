"""Altitude first at the thrust ceiling: the off-board loop's guard on the body rates it sends.

A vehicle whose collective thrust is capped at ``ceiling_mps2`` (mass-normalised) holds its
height only while ``ceiling_mps2 · cos(tilt) ≥ g``: past ``acos(g / ceiling)`` of tilt the
vertical part of its largest thrust is less than gravity and it sinks whatever thrust it is sent.
A policy trained on a stronger vehicle (the shipped ones: 12.9 m/s², a thrust-to-weight ratio of
1.32) can keep tilting there while chasing the reference horizontally, and a heavy or weak vehicle
(the transfer test's: 10.6 m/s², 1.08) then sinks to the floor. Multirotor position controllers
give the vertical axis priority at saturation for the same reason (the horizontal thrust is cut
first); with body-rate commands the equivalent is a tilt limit that holds only at the ceiling.

:func:`keep_altitude_at_ceiling` leaves a command alone unless its thrust is at the ceiling and
the attitude is tilted past the limit ``acos((g + climb_reserve_mps2) / ceiling_mps2)``; then it
removes the part of the roll and pitch rate that tilts further and levels at ``level_gain_per_s``
times the excess angle. The rate about the tilt axis's perpendicular and the yaw rate are kept.

Frames: quaternion (w, x, y, z) body to world, world z up; rates in the body frame (rad/s).
"""

from __future__ import annotations

import math

from datt.sim.frames import world_up_floats


def tilt_limit_rad(ceiling_mps2: float, gravity_mps2: float, climb_reserve_mps2: float = 0.0) -> float:
    """The largest tilt at which ``ceiling_mps2`` still gives ``gravity + climb_reserve`` upward;
    0 when it never does (every tilt at the ceiling is then levelled)."""
    return math.acos(min(1.0, (gravity_mps2 + climb_reserve_mps2) / ceiling_mps2))


def keep_altitude_at_ceiling(
    thrust_mps2: float,
    rates_radps: tuple[float, float, float],
    quat: tuple[float, float, float, float],
    ceiling_mps2: float,
    gravity_mps2: float,
    climb_reserve_mps2: float = 0.0,
    level_gain_per_s: float = 4.0,
) -> tuple[tuple[float, float, float], bool]:
    """The body rates to send with ``thrust_mps2`` from attitude ``quat``; returns (rates, guarded).

    Unchanged below the ceiling, at or inside the tilt limit, or when already levelling at least
    ``level_gain_per_s`` × the excess (``deploy.flight.ceiling_*``); otherwise the rate along the
    levelling axis (body frame, unit vector â: rotating about it turns body z towards world up) is
    raised to that, so that d(cos tilt)/dt = sin(tilt) · ``level_gain_per_s`` · excess."""
    if not math.isfinite(ceiling_mps2) or thrust_mps2 < ceiling_mps2:
        return tuple(rates_radps), False
    up = world_up_floats(quat)
    tilt = math.atan2(math.hypot(up[0], up[1]), up[2])
    excess = tilt - tilt_limit_rad(ceiling_mps2, gravity_mps2, climb_reserve_mps2)
    if excess <= 0:
        return tuple(rates_radps), False
    s = math.hypot(up[0], up[1])
    if s == 0.0:  # upside down: no levelling axis (the safety check KILLs far before)
        return tuple(rates_radps), False
    axis = (-up[1] / s, up[0] / s)  # e_z × up, normalised: the body axis that levels (no z part)
    along = rates_radps[0] * axis[0] + rates_radps[1] * axis[1]
    wanted = level_gain_per_s * excess
    if along >= wanted:
        return tuple(rates_radps), False
    add = wanted - along
    return (rates_radps[0] + add * axis[0], rates_radps[1] + add * axis[1], rates_radps[2]), True
