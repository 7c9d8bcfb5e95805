"""No accepted value switches a safety check off (issue: "a range that cannot switch a check
off"). For every limit of :class:`~datt.deploy.safety.SafetyParams`, set at the edge of its range
that loosens it most (a ``max_*`` at its top, a battery or floor limit at its bottom), the config
is accepted and a state just beyond that limit still gets LAND or KILL from
:func:`~datt.deploy.safety.check`. A new limit without a case here fails
``test_every_limit_has_an_edge_case``."""

from __future__ import annotations

import math
from dataclasses import fields

import pytest

from datt.deploy.link import StateSample
from datt.deploy.safety import KILL, LAND, OK, BatteryFilter, SafetyParams, check

NOW_S = 100.0
LEVEL = (1.0, 0.0, 0.0, 0.0)


def _tilted(deg: float) -> tuple:
    """A (w, x, y, z) quaternion rolled by ``deg`` about body x."""
    half = math.radians(deg) / 2
    return (math.cos(half), math.sin(half), 0.0, 0.0)


def state(pos=(0.0, 0.0, 1.0), vel=(0.0, 0.0, 0.0), quat=LEVEL, vbat=4.0, age_s=0.0) -> StateSample:
    return StateSample(NOW_S - age_s, tuple(pos), tuple(vel), tuple(quat), vbat)


def edge(key: str, high: bool) -> float:
    """The range's bound of ``key`` (an open bound: just inside it)."""
    rng = next(f for f in fields(SafetyParams) if f.name == key).metadata["range"]
    if high:
        return rng.high * (1 - 1e-9) if rng.high_open else rng.high
    return rng.low + 1e-9 if rng.low_open else rng.low


def decide(params: SafetyParams, **kw) -> str:
    args = {"now_s": NOW_S, "state": state(), "command": None, "estop": False, "link_lost": False, "mocap_age_s": None}
    args.update(kw)
    return check(params, **args).action


# key -> (the loosening edge is the range's top?, the other limits it needs, the check's call
# just beyond the limit ``v``, what it must decide)
CASES = {
    "geofence_min_m": (False, {}, lambda v: {"state": state(pos=(v - 0.01, 0.0, 1.0))}, (LAND, KILL)),
    "geofence_max_m": (True, {}, lambda v: {"state": state(pos=(v + 0.01, 0.0, 1.0))}, (LAND, KILL)),
    "geofence_margin_m": (True, {}, lambda v: {"state": state(pos=(2.0 + v + 0.01, 0.0, 1.0))}, (KILL,)),
    "max_tilt_deg": (True, {}, lambda v: {"state": state(quat=_tilted(v + 0.5))}, (KILL,)),
    "max_speed_mps": (True, {}, lambda v: {"state": state(vel=(v + 0.01, 0.0, 0.0))}, (LAND,)),
    "max_state_age_s": (True, {"kill_state_age_s": 2.0}, lambda v: {"state": state(age_s=v + 1e-3)}, (LAND, KILL)),
    "kill_state_age_s": (True, {"max_state_age_s": 0.1}, lambda v: {"state": state(age_s=v + 1e-3)}, (KILL,)),
    "max_mocap_age_s": (True, {}, lambda v: {"mocap_age_s": v + 1e-3}, (LAND,)),
    "land_battery_v": (False, {"kill_battery_v": 3.0}, lambda v: {"state": state(vbat=v - 0.01)}, (LAND, KILL)),
    "kill_battery_v": (False, {"land_battery_v": 3.3}, lambda v: {"state": state(vbat=v - 0.01)}, (KILL,)),
    "max_thrust_mps2": (True, {}, lambda v: {"command": [v + 0.01, 0.0, 0.0, 0.0]}, (LAND,)),
    "max_rate_radps": (True, {}, lambda v: {"command": [9.81, v + 0.01, 0.0, 0.0]}, (LAND,)),
    # a vehicle resting on the floor: its centre (where mocap puts the body) ~15 mm up
    "track_floor_m": (False, {}, lambda v: {"state": state(pos=(0.0, 0.0, 0.015)), "tracking": True}, (KILL,)),
    "track_sink_m": (
        True,
        {},
        lambda v: {
            "state": state(pos=(0.0, 0.0, 2.4 - v - 0.01), vel=(0.0, 0.0, -0.1)),
            "tracking": True,
            "reference_z_m": 2.4,
        },
        (LAND,),
    ),  # fmt: skip
}
# limits that are not decided per tick by check(): where their edge is tested
ELSEWHERE = {
    "battery_filter_s": "test_the_slowest_battery_filter_still_lets_the_battery_check_fire (below)",
    "max_estimate_mocap_m": "tests/deploy/test_preflight.py (the preflight's agreement with mocap)",
}


def test_every_limit_has_an_edge_case():
    assert {f.name for f in fields(SafetyParams)} == set(CASES) | set(ELSEWHERE)


@pytest.mark.parametrize("key", sorted(CASES))
def test_a_limit_at_its_loosest_accepted_value_still_fires(key):
    high, others, beyond, expected = CASES[key]
    value = edge(key, high)
    default = getattr(SafetyParams(), key)
    setting = [value] * len(default) if isinstance(default, list) else value
    params = SafetyParams(**{key: setting, **others})
    params.validate()  # accepted: the edge is inside the range
    assert decide(params, **beyond(value)) in expected
    assert decide(SafetyParams(**{key: setting, **others})) == OK  # and a state within it flies on


def test_the_slowest_battery_filter_still_lets_the_battery_check_fire():
    """``battery_filter_s`` at its top (10 s): a pack that drops from 4.0 V to 2.9 V (below
    ``kill_battery_v`` 3.0 V) is KILLed within 5 time constants of 50 Hz ticks."""
    params = SafetyParams(battery_filter_s=edge("battery_filter_s", True))
    params.validate()
    battery = BatteryFilter(params.battery_filter_s)
    battery.update(4.0, 0.02)
    ticks = 0
    while decide(params, state=state(vbat=battery.update(2.9, 0.02))) != KILL:
        ticks += 1
        assert ticks * 0.02 < 5 * params.battery_filter_s
