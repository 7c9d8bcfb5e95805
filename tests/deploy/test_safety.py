"""Safety decisions and the flight model, without flying (fast; in the mutation-testing selection)."""

import math

import numpy as np
import pytest

from datt.configuration import compose
from datt.deploy import safety


def test_safety_decisions_unit():
    p = safety.SafetyParams()
    from datt.deploy.link import StateSample

    ok = StateSample(t_s=10.0, pos_m=(0, 0, 1), vel_mps=(0, 0, 0), quat=(1, 0, 0, 0), vbat_v=3.9)
    check = lambda **kw: safety.check(
        p,
        **{
            "now_s": 10.01,
            "state": ok,
            "command": [9.81, 0, 0, 0],
            "estop": False,  # noqa: E731
            "link_lost": False,
            "mocap_age_s": None,
            **kw,
        },
    )
    assert check().action == safety.OK
    assert check(estop=True).reason == "operator e-stop"
    assert check(now_s=10.5).action == safety.LAND and check(now_s=10.6).action == safety.KILL
    assert check(command=[math.nan, 0, 0, 0]).action == safety.KILL
    assert check(command=[9.81, 0, 0, 5.0]).action == safety.LAND
    assert check(mocap_age_s=0.3).action == safety.LAND
    tilted = StateSample(10.0, (0, 0, 1), (0, 0, 0), (math.cos(0.7), math.sin(0.7), 0, 0), 3.9)  # 80 deg roll
    assert check(state=tilted).action == safety.KILL
    far = StateSample(10.0, (3.0, 0, 1), (0, 0, 0), (1, 0, 0, 0), 3.9)
    assert check(state=far).action == safety.KILL
    near = StateSample(10.0, (2.2, 0, 1), (0, 0, 0), (1, 0, 0, 0), 3.9)
    assert check(state=near).action == safety.LAND


def test_flight_model_records_the_commands_it_sends():
    """A policy with ``obs.action_history`` sees in flight the commands the runner sent, as in
    the sim env (the history is part of its observation)."""
    import torch

    from datt.control.pid import PidController
    from datt.deploy.runner import FlightModel
    from datt.envs.factory import make_env
    from datt.refs import Polygon

    cfg = compose("sim", ["env.obs.action_history=2", "adaptation=l1"])
    model = FlightModel(lambda family: make_env(cfg, num_envs=1, seed=0, traj=family), PidController(), Polygon())
    env = model.env
    hover = env.scaled_command(env.hover_action)
    assert torch.allclose(env.cmd_history[0], hover.expand(2, 4))
    sent = [model.act([0.1, -0.2, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0]) for _ in range(2)]
    expected = env.scaled_command(torch.as_tensor(np.stack(sent), dtype=env.dtype))
    torch.testing.assert_close(env.cmd_history[0], expected)
    assert not torch.allclose(expected[0], hover[0])


def test_flight_model_sends_and_remembers_thrust_at_the_maps_ceiling():
    """Far below the reference the PID asks for more than the map can give (it clips at
    max_command): the command sent, the history and L1's input are the ceiling, not the ask."""
    import torch

    from datt.control.pid import PidController
    from datt.deploy.runner import FlightModel
    from datt.envs.factory import make_env
    from datt.refs import Polygon

    cfg = compose("sim", ["env.obs.action_history=2", "adaptation=l1"])
    model = FlightModel(lambda family: make_env(cfg, num_envs=1, seed=0, traj=family), PidController(), Polygon(), 11.0)
    sent = model.act([0.0, 0.0, -3.0], [0.0, 0.0, -2.0], [1.0, 0.0, 0.0, 0.0])
    assert sent[0] == pytest.approx(11.0) and model.last_cmd[0, 0].item() == pytest.approx(11.0)
    assert model.env.cmd_history[0, -1, 0] == model.env.scaled_command(torch.tensor([[11.0, 0, 0, 0]]))[0, 0]


def _state(t_s=10.0, pos=(0.0, 0.0, 1.0), vel=(0.0, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), vbat=3.9):
    from datt.deploy.link import StateSample

    return StateSample(t_s=t_s, pos_m=pos, vel_mps=vel, quat=quat, vbat_v=vbat)


def decide(**kw):
    args = {
        "now_s": 10.01,
        "state": _state(),
        "command": [9.81, 0.0, 0.0, 0.0],
        "estop": False,
        "link_lost": False,
        "mocap_age_s": None,
    }
    params = kw.pop("params", safety.SafetyParams())
    args.update(kw)
    d = safety.check(params, **args)
    return d.action, d.reason


@pytest.mark.parametrize(
    "case, expect",
    [
        ({}, ("OK", "")),
        ({"estop": True, "link_lost": True}, ("KILL", "operator e-stop")),  # the e-stop wins
        ({"link_lost": True}, ("KILL", "link lost")),
        ({"state": None}, ("KILL", "no state estimate")),
        ({"now_s": 10.1}, ("OK", "")),  # 100 ms old: at the limit, still fresh
        ({"now_s": 10.15}, ("LAND", "state estimate stale (150 ms > 100 ms)")),  # late: land on it
        ({"now_s": 10.5}, ("LAND", "state estimate stale (500 ms > 100 ms)")),
        ({"now_s": 10.55}, ("KILL", "state estimate stale (550 ms > 500 ms)")),  # lost: motors off
        ({"state": _state(vel=(math.nan, 0.0, 0.0))}, ("KILL", "non-finite state estimate")),
        ({"state": _state(quat=(1.0, 0.0, 0.0, math.inf))}, ("KILL", "non-finite state estimate")),
        ({"state": _state(pos=(2.6, 0.0, 1.0))}, ("KILL", "geofence breached by 0.60 m (> margin 0.5 m)")),
        ({"state": _state(pos=(0.0, -2.7, 1.0))}, ("KILL", "geofence breached by 0.70 m (> margin 0.5 m)")),
        ({"state": _state(pos=(0.0, 0.0, 3.1))}, ("KILL", "geofence breached by 0.60 m (> margin 0.5 m)")),
        ({"state": _state(pos=(2.5, 0.0, 1.0))}, ("LAND", "outside geofence by 0.50 m")),  # at the margin
        ({"state": _state(pos=(0.0, 0.0, -0.3))}, ("LAND", "outside geofence by 0.20 m")),
        ({"state": _state(pos=(2.0, -2.0, 2.5))}, ("OK", "")),  # on the fence is inside
        # tilt = angle of body z from world z: 80° pitch KILLs, a pure yaw of 170° is level
        ({"state": _state(quat=(math.cos(0.7), 0.0, math.sin(0.7), 0.0))}, ("KILL", "tilt 80 deg > 75 deg")),
        ({"state": _state(quat=(math.cos(1.48), 0.0, 0.0, math.sin(1.48)))}, ("OK", "")),
        ({"command": [math.nan, 0.0, 0.0, 0.0]}, ("KILL", "non-finite command")),
        ({"command": [9.81, 0.0, math.inf, 0.0]}, ("KILL", "non-finite command")),
        ({"command": None}, ("OK", "")),
        ({"state": _state(vbat=2.95)}, ("KILL", "battery 2.95 V < 3.0 V")),
        ({"state": _state(vbat=3.0)}, ("LAND", "battery 3.00 V < 3.3 V")),
        ({"state": _state(vbat=3.3)}, ("OK", "")),
        ({"state": _state(vel=(3.0, 3.0, 0.0))}, ("LAND", "speed 4.2 m/s > 4.0 m/s")),
        ({"state": _state(vel=(0.0, 0.0, 4.0))}, ("OK", "")),
        ({"mocap_age_s": 0.3}, ("LAND", "mocap stale (300 ms > 100 ms)")),
        ({"mocap_age_s": 0.1}, ("OK", "")),
        ({"command": [39.81, 20.0, -20.0, 2.0]}, ("OK", "")),  # the limits themselves are allowed
        ({"command": [39.9, 0.0, 0.0, 0.0]}, ("LAND", "command out of range")),
        ({"command": [-0.1, 0.0, 0.0, 0.0]}, ("LAND", "command out of range")),
        ({"command": [9.81, 20.1, 0.0, 0.0]}, ("LAND", "command out of range")),
        ({"command": [9.81, 0.0, -20.1, 0.0]}, ("LAND", "command out of range")),
        ({"command": [9.81, 0.0, 0.0, -2.1]}, ("LAND", "command out of range")),
        # a KILL reason comes before any LAND reason in the same tick
        ({"state": _state(pos=(2.2, 0.0, 1.0), vbat=2.9)}, ("KILL", "battery 2.90 V < 3.0 V")),
        ({"state": _state(pos=(2.2, 0.0, 1.0), vel=(5.0, 0.0, 0.0))}, ("LAND", "outside geofence by 0.20 m")),
        ({"state": _state(vel=(5.0, 0.0, 0.0)), "mocap_age_s": 0.3}, ("LAND", "speed 5.0 m/s > 4.0 m/s")),
        ({"mocap_age_s": 0.3, "command": [50.0, 0.0, 0.0, 0.0]}, ("LAND", "mocap stale (300 ms > 100 ms)")),
        ({"command": [50.0, 0.0, 0.0, 0.0], "state": _state(vbat=3.1)}, ("LAND", "command out of range")),
        # the floor: only while tracking (takeoff and landing start and end on it), KILL (it sank)
        (
            {"state": _state(pos=(0.0, 0.0, 0.02)), "tracking": True},
            ("KILL", "on the floor while tracking (z 0.02 m < track_floor_m 0.05 m)"),
        ),  # fmt: skip
        ({"state": _state(pos=(0.0, 0.0, 0.05)), "tracking": True}, ("OK", "")),  # at the floor: still flying
        ({"state": _state(pos=(0.0, 0.0, 0.02))}, ("OK", "")),  # not tracking
        (
            {
                "state": _state(pos=(0.0, 0.0, 0.02)),
                "tracking": True,
                "params": safety.SafetyParams(track_floor_m=None),
            },
            ("OK", ""),
        ),  # fmt: skip
        (
            {"state": _state(pos=(0.0, 0.0, 0.02), vbat=2.9), "tracking": True},
            ("KILL", "on the floor while tracking (z 0.02 m < track_floor_m 0.05 m)"),
        ),  # fmt: skip
    ],
)
def test_safety_decision_table(case, expect):
    assert decide(**case) == expect


def test_safety_params_are_the_deploy_config_defaults():
    from dataclasses import asdict

    from datt.deploy.schema import deploy_params

    _, _, from_yaml, _ = deploy_params(compose("deploy", []).deploy)
    assert asdict(from_yaml) == asdict(safety.SafetyParams())


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"geofence_min_m": [0.0, -2.0, -0.1]}, None),
        (
            {"geofence_min_m": [2.0, -2.0, -0.1]},
            "deploy.safety.geofence_min_m/max_m: need 3 values each with min < max",
        ),
        ({"geofence_min_m": [-2.0, -2.0]}, "deploy.safety.geofence_min_m/max_m: need 3 values each with min < max"),
        ({"kill_battery_v": 3.3}, None),
        ({"kill_battery_v": 3.4}, "deploy.safety.kill_battery_v: must be <= land_battery_v"),
        ({"kill_state_age_s": 0.1}, None),
        ({"kill_state_age_s": 0.05}, "deploy.safety.kill_state_age_s: must be >= max_state_age_s (0.1), got 0.05"),
        ({"battery_filter_s": -1.0}, "deploy.safety.battery_filter_s: must be a finite number in [0, 10], got -1.0"),
        ({"battery_filter_s": 0.0}, None),  # 0 = no filter
        ({"battery_filter_s": 0.5}, None),
        ({"max_state_age_s": 0.0}, "deploy.safety.max_state_age_s: must be a finite number in (0, 2], got 0.0"),
        ({"track_floor_m": None}, None),
        ({"track_floor_m": 0.0}, "deploy.safety.track_floor_m: must be a finite number in [0.02, 1] or null, got 0.0"),
        # values that would disable a check (NaN compares false, inf never breached): refused
        ({"max_tilt_deg": math.nan}, "deploy.safety.max_tilt_deg: must be a finite number in (0, 90], got nan"),
        ({"max_tilt_deg": 91.0}, "deploy.safety.max_tilt_deg: must be a finite number in (0, 90], got 91.0"),
        (
            {"geofence_margin_m": math.nan},
            "deploy.safety.geofence_margin_m: must be a finite number in [0, 2], got nan",
        ),
        (
            {"geofence_max_m": [math.inf, math.inf, math.inf]},
            "deploy.safety.geofence_max_m: must be a list, each a finite number in [-20, 20], got [inf, inf, inf]",
        ),
        ({"max_speed_mps": math.inf}, "deploy.safety.max_speed_mps: must be a finite number in (0, 10], got inf"),
        ({"kill_battery_v": math.nan}, "deploy.safety.kill_battery_v: must be a finite number in [3, 4.2], got nan"),
        (
            {"max_rate_radps": [20.0, math.nan, 2.0]},
            "deploy.safety.max_rate_radps: must be a list, each a finite number in (0, 34.9066], got [20.0, nan, 2.0]",
        ),
        # finite values that would switch a check off (issue: a range that only says "finite"):
        # refused by the range that says what the limit can mean
        (
            {"geofence_min_m": [-1e30, -2.0, -0.1]},
            "deploy.safety.geofence_min_m: must be a list, each a finite number in [-20, 20], got [-1e+30, -2.0, -0.1]",
        ),
        ({"geofence_margin_m": 1e30}, "deploy.safety.geofence_margin_m: must be a finite number in [0, 2], got 1e+30"),
        (
            {"geofence_margin_m": 1.5, "geofence_min_m": [-2.0, -2.0, 0.0], "geofence_max_m": [2.0, 2.0, 1.5]},
            "deploy.safety.geofence_margin_m: must be less than the fence's smallest side (1.5 m), got 1.5",
        ),
        ({"max_speed_mps": 1e30}, "deploy.safety.max_speed_mps: must be a finite number in (0, 10], got 1e+30"),
        ({"kill_state_age_s": 1e30}, "deploy.safety.kill_state_age_s: must be a finite number in (0, 2], got 1e+30"),
        ({"max_mocap_age_s": 1e30}, "deploy.safety.max_mocap_age_s: must be a finite number in (0, 2], got 1e+30"),
        ({"kill_battery_v": 0.0}, "deploy.safety.kill_battery_v: must be a finite number in [3, 4.2], got 0.0"),
        (
            {"max_rate_radps": [1e30, 20.0, 2.0]},
            "deploy.safety.max_rate_radps: must be a list, each a finite number in (0, 34.9066], "
            "got [1e+30, 20.0, 2.0]",
        ),
        ({"kill_battery_v": 3.0, "land_battery_v": 4.2, "max_tilt_deg": 90.0}, None),  # the ranges' edges
    ],
)
def test_safety_params_validation(kwargs, message):
    from datt.errors import ConfigError

    params = safety.SafetyParams(**kwargs)
    if message is None:
        params.validate()
        return
    with pytest.raises(ConfigError) as info:
        params.validate()
    assert str(info.value) == message


def test_tilt_of_rolls_pitches_and_yaws():
    half = [math.radians(a) / 2 for a in (30.0, 80.0, 179.0)]
    assert safety.tilt_deg((math.cos(half[0]), math.sin(half[0]), 0.0, 0.0)) == pytest.approx(30.0)
    assert safety.tilt_deg((math.cos(half[1]), 0.0, math.sin(half[1]), 0.0)) == pytest.approx(80.0)
    assert safety.tilt_deg((math.cos(half[2]), 0.0, 0.0, math.sin(half[2]))) == pytest.approx(0.0, abs=1e-9)
    assert safety.tilt_deg((0.0, 1.0, 0.0, 0.0)) == pytest.approx(180.0)  # upside down
    assert safety.tilt_deg((0.0, 1.0000001, 0.0, 0.0)) == pytest.approx(180.0)  # rounding beyond -1 is clamped


def test_safety_limits_are_strict_inequalities():
    """Exactly at a limit is allowed: state age, tilt, thrust 0, rate limit (+1e-6 tolerance)."""
    at_age = safety.SafetyParams(max_state_age_s=0.125)
    assert decide(params=at_age, now_s=0.125, state=_state(t_s=0.0)) == ("OK", "")
    q = (math.cos(0.6), math.sin(0.6), 0.0, 0.0)
    at_tilt = safety.SafetyParams(max_tilt_deg=safety.tilt_deg(q))
    assert decide(params=at_tilt, state=_state(quat=q)) == ("OK", "")
    assert decide(command=[0.0, 0.0, 0.0, 0.0]) == ("OK", "")
    assert decide(command=[0.5, 0.0, 0.0, 0.0]) == ("OK", "")
    assert decide(command=[9.81, 20.0 + 1e-6, 0.0, 0.0]) == ("OK", "")


def test_stale_messages_in_milliseconds():
    params = safety.SafetyParams(max_state_age_s=0.7, kill_state_age_s=0.8, max_mocap_age_s=0.7)
    assert decide(params=params, now_s=10.75) == ("LAND", "state estimate stale (750 ms > 700 ms)")
    assert decide(params=params, now_s=10.9) == ("KILL", "state estimate stale (900 ms > 800 ms)")
    assert decide(params=params, mocap_age_s=0.9) == ("LAND", "mocap stale (900 ms > 700 ms)")


def test_battery_filter_rides_out_a_sag_and_follows_a_drop():
    """A 0.2 s sag to 3.1 V under load does not LAND (the filtered voltage stays above 3.3 V); a
    lasting drop to 3.2 V does, once the 1 s low-pass has followed it."""
    dt = 0.02
    sag = safety.BatteryFilter(1.0)
    seen = [sag.update(4.0, dt)] + [sag.update(3.1, dt) for _ in range(10)] + [sag.update(4.0, dt) for _ in range(10)]
    assert min(seen) > 3.3 and seen[0] == 4.0
    drop = safety.BatteryFilter(1.0)
    drop.update(4.0, dt)
    values = [drop.update(3.2, dt) for _ in range(200)]
    below = next(k for k, v in enumerate(values) if v < 3.3)
    assert 1.5 < below * dt < 2.5  # ln((4.0 - 3.2) / (3.3 - 3.2)) = 2.08 time constants
    assert values[-1] == pytest.approx(3.2, abs=0.02)
    assert safety.BatteryFilter(0.0).update(3.1, dt) == 3.1  # 0 = no filter


def test_battery_filter_step_response_by_hand():
    """tau 2 s: a 1 V drop seen 0.5 s later moves the filter by 0.5 / 2 of it; a reading after a gap
    longer than tau lands on the reading (no overshoot); tau 0 follows every reading."""
    f = safety.BatteryFilter(2.0)
    assert f.update(4.0, 0.02) == 4.0  # the first reading starts the filter
    assert f.update(3.0, 0.5) == pytest.approx(3.75)
    assert f.update(3.0, 6.0) == pytest.approx(3.0)
    unfiltered = safety.BatteryFilter(0.0)
    assert [unfiltered.update(v, 0.02) for v in (4.0, 3.1, 3.9)] == [4.0, 3.1, 3.9]


def _sinking(z_m, reference_z_m, tracking=True, sink=0.3, vz_mps=0.0):
    from datt.deploy.link import StateSample

    p = safety.SafetyParams(track_sink_m=sink)
    level = [1.0, 0.0, 0.0, 0.0]
    state = StateSample(t_s=10.0, pos_m=[0.0, 0.0, z_m], vel_mps=[0.0, 0.0, vz_mps], quat=level, vbat_v=4.0)
    return safety.check(
        p,
        now_s=10.0,
        state=state,
        command=None,
        estop=False,
        link_lost=False,
        mocap_age_s=None,
        tracking=tracking,
        reference_z_m=reference_z_m,
    )


@pytest.mark.parametrize(
    "z_m, reference_z_m, tracking, sink, vz_mps, action",
    [
        (0.8, 1.0, True, 0.25, 0.0, "OK"),  # 0.2 below
        (0.75, 1.0, True, 0.25, 0.0, "OK"),  # at the edge (exact in binary): 0.25 below is still flown
        (0.74, 1.0, True, 0.25, 0.0, "LAND"),  # below and level
        (0.74, 1.0, True, 0.25, -0.2, "LAND"),  # below and falling
        (0.74, 1.0, True, 0.25, 0.05, "OK"),  # below but climbing back (a takeoff the thrust lock delayed)
        (0.69, 1.0, False, 0.3, 0.0, "OK"),  # takeoff and hover: the PID's own business
        (0.69, None, True, 0.3, 0.0, "OK"),  # no reference known: no sink check
        (0.69, 1.0, True, None, 0.0, "OK"),  # off
        (1.40, 1.0, True, 0.3, 0.0, "OK"),  # above the reference: not sinking
        (0.9, float("nan"), True, 0.3, 0.0, "LAND"),  # a reference that is not a number is not "close enough"
    ],
)
def test_sinking_below_the_reference_while_tracking_lands(z_m, reference_z_m, tracking, sink, vz_mps, action):
    decision = _sinking(z_m, reference_z_m, tracking, sink, vz_mps)
    assert decision.action == action
    if action == safety.LAND:
        assert decision.reason.startswith("sinking while tracking") and "track_sink_m" in decision.reason


def test_the_estimate_already_answered_gets_the_last_command_again_without_adapting():
    """A tick whose estimate is the one the last command answered (its log packet lost): the
    command is repeated, L1's d-hat stays, and the history records it as sent; a fresh estimate
    is answered as before."""
    import torch

    from datt.control.pid import PidController
    from datt.deploy.runner import FlightModel
    from datt.envs.factory import make_env
    from datt.refs import Polygon

    cfg = compose("sim", ["env.obs.action_history=3", "adaptation=l1"])
    model = FlightModel(lambda family: make_env(cfg, num_envs=1, seed=0, traj=family), PidController(), Polygon())
    first = model.act([0.1, -0.2, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    model.act([0.12, -0.2, 0.0], [0.9, 0.3, 0.0], [1.0, 0.0, 0.0, 0.0])
    d_hat, last = model.d_hat.copy(), model.last_cmd.clone()
    held = model.hold()
    assert held.tolist() == pytest.approx(last[0].tolist()) and not np.allclose(held, first)
    np.testing.assert_array_equal(model.d_hat, d_hat)
    torch.testing.assert_close(model.env.cmd_history[0, -1], model.env.scaled_command(last)[0])
    torch.testing.assert_close(model.env.cmd_history[0, -2], model.env.scaled_command(last)[0])


def test_the_runner_holds_on_an_estimate_it_already_answered_and_answers_a_fresh_one(tmp_path):
    from types import SimpleNamespace

    from tests.deploy import bookkeeping_runner

    class Model:
        last_state_t = None

        def hold(self):
            return np.array([1.0, 0.0, 0.0, 0.0])

    runner = bookkeeping_runner(tmp_path, _excitation=lambda k: 0.5 * k)
    answered = []
    runner._answer = lambda model, state, now, origin, predict: answered.append(state.t_s) or np.array([9.0, 0, 0, 0])
    model, origin = Model(), np.zeros(3)
    samples = [SimpleNamespace(t_s=t) for t in (1.00, 1.00, 1.02, 1.02, 1.02, 1.04)]
    sent = [runner._act(model, s, 0.0, origin, k, False)[0] for k, s in enumerate(samples)]
    assert answered == [1.00, 1.02, 1.04]
    assert sent == [9.0, 1.5, 10.0, 2.5, 3.0, 11.5]  # the excitation is added either way (calibration)
