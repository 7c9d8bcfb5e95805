"""The onboard app's checks (datt_onboard.c), written from what each must decide, not from its lines:
the tilt abort against a rotation matrix built independently of the app's quaternion arithmetic, at
each axis alone, with yaw, in combination and at its edge; every state component non-finite; the
quaternion's norm at its bounds; the position uncertainty with NaN and inf; each rate limit alone;
the upload protocol and the start's parameters exactly at their bounds and one past them."""

from __future__ import annotations

import math
import shutil

import numpy as np
import pytest

from datt.deploy import onboard
from datt.deploy.sim.onboard_app import OnboardApp

from .test_onboard import LEVEL, built, loaded  # noqa: F401 (the module's built app is a fixture)

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc: the onboard app cannot be built here")
HOVER = [0.0, 0.0, 1.0]


# -- an independent attitude: elementary rotation matrices and Hamilton products ---------------
def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _hamilton(a, b):
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return [
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ]


def _axis_quat(axis: int, angle: float) -> list[float]:
    q = [math.cos(angle / 2), 0.0, 0.0, 0.0]
    q[1 + axis] = math.sin(angle / 2)
    return q


def attitude(yaw_deg=0.0, pitch_deg=0.0, roll_deg=0.0):
    """(quaternion [w, x, y, z], rotation matrix) of yaw about z, then pitch about the new y, then
    roll about the newest x (body-to-world, R = Rz Ry Rx)."""
    y, p, r = (math.radians(v) for v in (yaw_deg, pitch_deg, roll_deg))
    q = _hamilton(_hamilton(_axis_quat(2, y), _axis_quat(1, p)), _axis_quat(0, r))
    return q, _rz(y) @ _ry(p) @ _rx(r)


def tilt_deg(matrix) -> float:
    """The angle between the body's z axis and the world's."""
    return math.degrees(math.acos(max(-1.0, min(1.0, matrix[2, 2]))))


def test_the_independent_attitude_is_one_rotation():
    q, m = attitude(30.0, -20.0, 50.0)
    w, x, y, z = q
    from_q = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )
    np.testing.assert_allclose(from_q, m, atol=1e-12)


def _flying(built, **params) -> OnboardApp:  # noqa: F811
    app = loaded(built, **params)
    app.run_request = 1
    sp, _ = app.tick(HOVER, [0, 0, 0], LEVEL)
    assert app.phase == onboard.TRACK and sp.stop == 0
    return app


def _aborts(app: OnboardApp, quat, pos=HOVER, vel=(0.0, 0.0, 0.0)) -> bool:
    sp, _ = app.tick(list(pos), list(vel), list(quat))
    if app.phase == onboard.ABORTED:
        assert sp is not None and sp.stop == 1 and sp.thrust == 0  # the abort stops the motors at once
        return True
    assert app.phase == onboard.TRACK and sp is not None and sp.stop == 0
    return False


# yaw first, then a tilt of `tilt` about one body axis: the tilt is the same whatever the yaw
CASES = [(yaw, axis, sign) for yaw in (0.0, 90.0, 180.0, -135.0) for axis in ("roll", "pitch") for sign in (1.0, -1.0)]


@pytest.mark.parametrize("max_tilt", [30.0, 75.0, 89.0])
@pytest.mark.parametrize("yaw, axis, sign", CASES, ids=[f"yaw{y:g}-{a}{'+' if s > 0 else '-'}" for y, a, s in CASES])
def test_the_tilt_abort_is_the_angle_of_the_body_z_axis_at_each_axis_and_yaw(built, max_tilt, yaw, axis, sign):  # noqa: F811
    for margin, expect in ((-0.05, False), (0.05, True)):
        app = _flying(built, maxTiltDeg=max_tilt)
        angle = sign * (max_tilt + margin)
        q, m = attitude(yaw, angle if axis == "pitch" else 0.0, angle if axis == "roll" else 0.0)
        assert tilt_deg(m) == pytest.approx(max_tilt + margin, abs=1e-9)
        assert _aborts(app, q) is expect, (yaw, axis, angle)


@pytest.mark.parametrize("yaw", [45.0, 90.0, 179.0, -90.0])
def test_yaw_alone_never_aborts(built, yaw):  # noqa: F811
    app = _flying(built, maxTiltDeg=30.0)
    q, m = attitude(yaw)
    assert tilt_deg(m) == pytest.approx(0.0, abs=1e-6)
    assert not _aborts(app, q)


@pytest.mark.parametrize("yaw", [0.0, 60.0])
def test_roll_and_pitch_together_abort_on_the_combined_tilt_not_on_either_alone(built, yaw):  # noqa: F811
    """Roll 60 and pitch 60 each stay inside a 75 deg limit; together the body z axis is 75.5 deg
    from the vertical."""
    q, m = attitude(yaw, 60.0, 60.0)
    assert tilt_deg(m) == pytest.approx(math.degrees(math.acos(0.25)), abs=1e-9)  # cos = cos 60 cos 60
    assert _aborts(_flying(built), q)
    q, m = attitude(yaw, 55.0, 55.0)
    assert tilt_deg(m) < 75.0 and not _aborts(_flying(built), q)


@pytest.mark.parametrize("part, index", [("pos", i) for i in range(3)] + [("vel", i) for i in range(3)]
                         + [("quat", i) for i in range(4)])  # fmt: skip
@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf], ids=["nan", "inf", "-inf"])
def test_every_state_component_that_is_not_a_number_aborts_and_refuses_a_start(built, part, index, bad):  # noqa: F811
    state = {"pos": list(HOVER), "vel": [0.0, 0.0, 0.0], "quat": list(LEVEL)}
    state[part][index] = bad
    app = _flying(built)
    sp, _ = app.tick(state["pos"], state["vel"], state["quat"])
    assert app.phase == onboard.ABORTED and sp.stop == 1 and sp.thrust == 0
    app = loaded(built)
    app.run_request = 1
    sp, _ = app.tick(state["pos"], state["vel"], state["quat"])
    assert app.phase == onboard.REFUSED and sp is None


@pytest.mark.parametrize("norm2, sane", [(0.97, False), (0.981, True), (1.019, True), (1.03, False)])
def test_the_quaternion_must_be_near_unit_length(built, norm2, sane):  # noqa: F811
    q, _ = attitude(20.0, 10.0, -5.0)
    scaled = [c * math.sqrt(norm2) for c in q]
    assert _aborts(_flying(built), scaled) is not sane


@pytest.mark.parametrize(
    "var, lands",
    [(0.01, False), (0.0100001, True), (math.nan, True), (math.inf, True), (0.0, False)],
    ids=["at the limit", "just over", "nan", "inf", "zero"],
)
def test_an_uncertain_or_unknown_position_lands(built, var, lands):  # noqa: F811
    app = _flying(built, maxPosStdM=0.1)
    app.tick(HOVER, [0, 0, 0], LEVEL, pos_var_m2=var)
    assert (app.phase == onboard.LAND) is lands and app.phase != onboard.ABORTED
    assert app.status().landed_early == int(lands)


def test_with_the_uncertainty_limit_off_even_an_unknown_position_tracks(built):  # noqa: F811
    app = _flying(built, maxPosStdM=0.0)
    app.tick(HOVER, [0, 0, 0], LEVEL, pos_var_m2=math.nan)
    assert app.phase == onboard.TRACK


@pytest.mark.parametrize("axis", [0, 1, 2], ids=["roll", "pitch", "yaw"])
def test_each_rate_limit_clips_its_own_axis_only(built, axis):  # noqa: F811
    """A state far from the reference makes the policy ask for rates on every axis; a tiny limit on
    one axis clips that axis to it and leaves the other two as the policy asked (deg/s, pitch
    inverted as the legacy setpoint wants)."""
    names = ("maxRateRoll", "maxRatePitch", "maxRateYaw")
    limits = {name: (0.5 if k == axis else 1e6) for k, name in enumerate(names)}
    app = loaded(built, **limits)
    app.run_request = 1
    q, _ = attitude(30.0, 20.0, -25.0)
    sp, _ = app.tick([0.4, -0.3, 0.6], [0.8, -0.5, 0.3], q)
    action = list(app.status().action)
    asked = [math.degrees(action[1]), -math.degrees(action[2]), math.degrees(action[3])]
    sent = [sp.roll_degps, sp.pitch_degps, sp.yaw_degps]
    for k in range(3):
        if k == axis:
            assert abs(asked[k]) > 0.5 and sent[k] == pytest.approx(math.copysign(0.5, asked[k]))
        else:
            assert sent[k] == pytest.approx(asked[k], rel=1e-5)


# -- the upload protocol and the start's parameters at their bounds ---------------------------
def _ack(app: OnboardApp, packet: bytes) -> tuple[int, int]:
    return onboard.parse_ack(app.receive(packet))


def test_a_points_packet_holds_one_or_two_points_and_exactly_their_bytes(built):  # noqa: F811
    app = OnboardApp(built[4], controller_id=6)
    one, two = onboard.points_packet(0, [(1.0, 2.0, 3.0)]), onboard.points_packet(2, [(1.0, 2.0, 3.0)] * 2)
    assert _ack(app, one) == (0, onboard.ACK_OK) and _ack(app, two) == (2, onboard.ACK_OK)
    assert _ack(app, one[:-1]) == (0, onboard.ACK_MALFORMED)  # one byte short
    assert _ack(app, two[:-1]) == (2, onboard.ACK_MALFORMED)  # a refusal names the index it read
    assert _ack(app, one[:3] + bytes([0]) + one[4:]) == (0, onboard.ACK_MALFORMED)  # count 0
    three = two[:3] + bytes([3]) + two[4:] + bytes(12)
    assert _ack(app, three) == (2, onboard.ACK_MALFORMED)  # count 3, all its bytes there
    assert app.status().n_received == 3


def test_the_table_takes_points_up_to_its_last_index_and_refuses_one_past(built):  # noqa: F811
    app = OnboardApp(built[4], controller_id=6)
    last = onboard.TABLE_MAX - 1
    assert _ack(app, onboard.points_packet(last, [(0.0, 0.0, 0.0)])) == (last, onboard.ACK_OK)
    assert _ack(app, onboard.points_packet(last - 1, [(0.0, 0.0, 0.0)] * 2)) == (last - 1, onboard.ACK_OK)
    assert _ack(app, onboard.points_packet(last, [(0.0, 0.0, 0.0)] * 2)) == (last, onboard.ACK_RANGE)
    past = onboard.TABLE_MAX
    assert _ack(app, onboard.points_packet(past, [(0.0, 0.0, 0.0)])) == (past, onboard.ACK_RANGE)
    assert app.status().n_received == 2


def test_a_full_table_starts_and_one_point_more_is_refused(built):  # noqa: F811
    app = loaded(built, n_points=onboard.TABLE_MAX, track_steps=onboard.TABLE_MAX - 1)
    app.run_request = 1
    app.tick(HOVER, [0, 0, 0], LEVEL)
    assert app.phase == onboard.TRACK
    app = loaded(built, n_points=onboard.TABLE_MAX, track_steps=onboard.TABLE_MAX - 1)
    app.set("nPoints", onboard.TABLE_MAX + 1)
    app.run_request = 1
    app.tick(HOVER, [0, 0, 0], LEVEL)
    assert app.phase == onboard.REFUSED


@pytest.mark.parametrize(
    "params, starts",
    [
        ({"trackSteps": 39}, True),  # the last point of 40 is the landing's start
        ({"trackSteps": 40}, False),
        ({"hoverCmd": 59999.0}, True),
        ({"hoverCmd": 60000.0}, False),  # the hover command at the ceiling leaves nothing to fly with
        ({"maxTiltDeg": 179.0}, True),
        ({"maxTiltDeg": 180.0}, False),
        ({"maxTiltDeg": 0.0}, False),
        ({"landS": 0.0}, False),
        ({"landHoldS": 0.0}, True),
        ({"landHoldS": -0.01}, False),
        ({"maxPosStdM": -0.01}, False),
        ({"slope": 0.0}, False),
    ],
    ids=lambda v: str(v) if not isinstance(v, dict) else ",".join(f"{k}={x}" for k, x in v.items()),
)
def test_each_start_parameter_at_its_bound_and_past_it(built, params, starts):  # noqa: F811
    app = loaded(built, n_points=40, track_steps=20, **params)
    app.run_request = 1
    app.tick(HOVER, [0, 0, 0], LEVEL)
    assert app.phase == (onboard.TRACK if starts else onboard.REFUSED)
