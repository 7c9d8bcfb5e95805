"""The host's per-tick safety checks from their definitions, as the onboard app's are checked in
test_onboard_definitions.py: the tilt against a rotation matrix built in the test, at each axis
alone, after a yaw, combined and at its edge; every state and command component not a number; the
geofence per axis and side at its edge and margin; each rate limit alone."""

from __future__ import annotations

import math

import pytest

from datt.deploy import safety

from .test_onboard_definitions import CASES, attitude, tilt_deg
from .test_safety import _state, decide


@pytest.mark.parametrize("max_tilt", [30.0, 75.0, 89.0])
@pytest.mark.parametrize("yaw, axis, sign", CASES, ids=[f"yaw{y:g}-{a}{'+' if s > 0 else '-'}" for y, a, s in CASES])
def test_the_tilt_kill_is_the_angle_of_the_body_z_axis_at_each_axis_and_yaw(max_tilt, yaw, axis, sign):
    params = safety.SafetyParams(max_tilt_deg=max_tilt)
    for margin, expect in ((-0.05, "OK"), (0.05, "KILL")):
        angle = sign * (max_tilt + margin)
        q, m = attitude(yaw, angle if axis == "pitch" else 0.0, angle if axis == "roll" else 0.0)
        assert tilt_deg(m) == pytest.approx(max_tilt + margin, abs=1e-9)
        action, reason = decide(params=params, state=_state(quat=tuple(q)))
        assert action == expect, (yaw, axis, angle, reason)


@pytest.mark.parametrize("yaw", [45.0, 90.0, 179.0, -90.0])
def test_yaw_alone_is_level(yaw):
    q, _ = attitude(yaw)
    assert decide(params=safety.SafetyParams(max_tilt_deg=30.0), state=_state(quat=tuple(q)))[0] == "OK"


def test_roll_and_pitch_together_kill_on_the_combined_tilt():
    q, _ = attitude(0.0, 60.0, 60.0)  # 75.5 deg: each axis alone is inside 75
    assert decide(state=_state(quat=tuple(q)))[0] == "KILL"
    q, _ = attitude(0.0, 55.0, 55.0)
    assert decide(state=_state(quat=tuple(q)))[0] == "OK"


@pytest.mark.parametrize("part, index", [("pos", i) for i in range(3)] + [("vel", i) for i in range(3)]
                         + [("quat", i) for i in range(4)])  # fmt: skip
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_every_state_component_that_is_not_a_number_kills(part, index, bad):
    values = {"pos": [0.0, 0.0, 1.0], "vel": [0.0, 0.0, 0.0], "quat": [1.0, 0.0, 0.0, 0.0]}
    values[part][index] = bad
    state = _state(pos=tuple(values["pos"]), vel=tuple(values["vel"]), quat=tuple(values["quat"]))
    assert decide(state=state) == ("KILL", "non-finite state estimate")


@pytest.mark.parametrize("index", range(4))
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_every_command_component_that_is_not_a_number_kills(index, bad):
    command = [9.81, 0.0, 0.0, 0.0]
    command[index] = bad
    assert decide(command=command) == ("KILL", "non-finite command")


@pytest.mark.parametrize("axis", range(3))
@pytest.mark.parametrize("side", ["min", "max"])
def test_the_geofence_per_axis_and_side_lands_past_the_fence_and_kills_past_the_margin(axis, side):
    params = safety.SafetyParams()
    fence = (params.geofence_min_m if side == "min" else params.geofence_max_m)[axis]
    outward = -1.0 if side == "min" else 1.0
    for beyond, expect in ((0.0, "OK"), (0.01, "LAND"), (params.geofence_margin_m, "LAND"),
                           (params.geofence_margin_m + 0.01, "KILL")):  # fmt: skip
        pos = [0.0, 0.0, 1.0]
        pos[axis] = fence + outward * beyond
        assert decide(state=_state(pos=tuple(pos)))[0] == expect, (axis, side, beyond)


@pytest.mark.parametrize("axis", range(3), ids=["roll", "pitch", "yaw"])
def test_each_rate_limit_lands_on_its_own_axis_only(axis):
    limits = [20.0, 20.0, 2.0]
    params = safety.SafetyParams(max_rate_radps=list(limits))
    for k in range(3):
        command = [9.81, 0.0, 0.0, 0.0]
        command[1 + k] = -(limits[axis] + 0.01)  # the other axes' limits are no smaller than this one's
        expect = "LAND" if k == axis or limits[k] < limits[axis] + 0.01 else "OK"
        assert decide(params=params, command=command)[0] == expect, (axis, k)
    command = [9.81, 0.0, 0.0, 0.0]
    command[1 + axis] = limits[axis]  # at the limit: flies
    assert decide(params=params, command=command)[0] == "OK"
