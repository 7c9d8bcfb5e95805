"""The off-board loop's altitude-first guard at the thrust ceiling (datt.deploy.ceiling_guard),
against the geometry of a tilted thrust vector."""

from __future__ import annotations

import functools
import math

import numpy as np
import pytest
import torch

from datt.configuration import compose
from datt.deploy.ceiling_guard import keep_altitude_at_ceiling, tilt_limit_rad
from datt.sim.frames import body_z_floats, quat_turned_floats

G = 9.81
CEILING = 10.6  # the transfer test's vehicle at max_command: a thrust-to-weight ratio of 1.08


def tilted(angle_rad: float, axis=(1.0, 0.0, 0.0), yaw_rad: float = 0.0) -> list[float]:
    """A quaternion yawed by ``yaw_rad`` then tilted by ``angle_rad`` about the body ``axis``."""
    q = quat_turned_floats([1.0, 0.0, 0.0, 0.0], [0.0, 0.0, yaw_rad])
    n = math.sqrt(sum(a * a for a in axis))
    return quat_turned_floats(q, [angle_rad * a / n for a in axis])


def tilt_of(q) -> float:
    return math.acos(max(-1.0, min(1.0, body_z_floats(q)[2])))


def test_the_tilt_limit_is_where_the_ceiling_just_holds_height():
    limit = tilt_limit_rad(CEILING, G)
    assert CEILING * math.cos(limit) == pytest.approx(G)
    assert math.degrees(limit) == pytest.approx(22.3, abs=0.1)
    reserve = tilt_limit_rad(CEILING, G, climb_reserve_mps2=0.5)
    assert CEILING * math.cos(reserve) == pytest.approx(G + 0.5) and reserve < limit
    assert tilt_limit_rad(9.0, G) == 0.0  # a ceiling under gravity: no tilt holds height
    assert tilt_limit_rad(G, G) == 0.0


@pytest.mark.parametrize("thrust", [CEILING - 0.01, 5.0])
def test_below_the_ceiling_every_command_goes_as_the_policy_sent_it(thrust):
    rates = (3.0, -2.0, 0.5)
    out, guarded = keep_altitude_at_ceiling(thrust, rates, tilted(math.radians(60)), CEILING, G)
    assert out == rates and not guarded


def test_at_the_ceiling_inside_the_tilt_limit_nothing_changes():
    rates = (3.0, -2.0, 0.5)
    q = tilted(tilt_limit_rad(CEILING, G) - 0.01, axis=(1.0, 1.0, 0.0))
    out, guarded = keep_altitude_at_ceiling(CEILING, rates, q, CEILING, G)
    assert out == rates and not guarded
    # an unknown ceiling (no thrust map yet) never guards
    assert keep_altitude_at_ceiling(1e9, rates, tilted(1.0), math.inf, G) == (rates, False)


@pytest.mark.parametrize("axis", [(1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (1.0, -2.0, 0.0)])
@pytest.mark.parametrize("yaw_deg", [0.0, 135.0])
def test_past_the_limit_the_vehicle_levels_at_the_gain_times_the_excess(axis, yaw_deg):
    """Tilted 35 deg (past 22.3) and rolling further: the rate along the levelling axis becomes
    gain x excess, so cos(tilt) grows at sin(tilt) x that; the rate across it and the yaw stay."""
    tilt = math.radians(35.0)
    q = tilted(tilt, axis, math.radians(yaw_deg))
    n = math.hypot(axis[0], axis[1])
    further = (2.0 * axis[0] / n, 2.0 * axis[1] / n)  # 2 rad/s about the tilt axis: tilts further
    across = (-axis[1] / n * 0.7, axis[0] / n * 0.7)  # some rate across it
    rates = (further[0] + across[0], further[1] + across[1], 0.8)
    gain = 4.0
    out, guarded = keep_altitude_at_ceiling(CEILING, rates, q, CEILING, G, level_gain_per_s=gain)
    assert guarded
    excess = tilt - tilt_limit_rad(CEILING, G)
    h = 1e-5
    after = quat_turned_floats(q, [r * h for r in out])
    dcos = (math.cos(tilt_of(after)) - math.cos(tilt)) / h
    assert dcos == pytest.approx(math.sin(tilt) * gain * excess, rel=1e-3)
    # the part across the levelling axis and the yaw rate are the policy's
    lev = np.cross([0, 0, 1], body_z_world_in_body(q))
    lev = lev / np.linalg.norm(lev)
    diff = np.array(out) - np.array(rates)
    assert np.allclose(np.cross(diff, lev), 0.0, atol=1e-12)  # only the levelling component changed
    assert out[2] == rates[2]


def body_z_world_in_body(q) -> np.ndarray:
    """World up in the body frame (the tensor rotation, not the guard's float form)."""
    import torch

    from datt.sim.frames import quat_rotate_inverse

    q_t = torch.tensor([q], dtype=torch.float64)
    return quat_rotate_inverse(q_t, torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))[0].numpy()


def test_a_command_already_levelling_fast_enough_is_left_alone():
    tilt = math.radians(30.0)
    q = tilted(tilt)  # tilted about +x: rolling about -x levels
    excess = tilt - tilt_limit_rad(CEILING, G)
    fast = (-(4.0 * excess + 0.1), 0.3, 0.0)
    assert keep_altitude_at_ceiling(CEILING, fast, q, CEILING, G) == (fast, False)
    slow = (-(4.0 * excess - 0.1), 0.3, 0.0)
    out, guarded = keep_altitude_at_ceiling(CEILING, slow, q, CEILING, G)
    assert guarded and out[0] == pytest.approx(-4.0 * excess) and out[1] == 0.3


def test_a_climb_reserve_guards_from_a_smaller_tilt():
    """With 0.5 m/s² kept in hand the limit is acos((g + 0.5) / ceiling) = 13.5 deg: at 18 deg
    the guard levels, without the reserve (limit 22.3 deg) it does not."""
    q = tilted(math.radians(18.0))
    rates = (1.0, 0.0, 0.0)  # tilting further about +x
    assert keep_altitude_at_ceiling(CEILING, rates, q, CEILING, G) == (rates, False)
    out, guarded = keep_altitude_at_ceiling(CEILING, rates, q, CEILING, G, climb_reserve_mps2=0.5)
    excess = math.radians(18.0) - tilt_limit_rad(CEILING, G, 0.5)
    assert guarded and out == pytest.approx((-4.0 * excess, 0.0, 0.0))


def test_upside_down_there_is_no_levelling_axis_and_the_command_goes_as_sent():
    rates = (1.0, -1.0, 0.2)
    assert keep_altitude_at_ceiling(CEILING, rates, (0.0, 1.0, 0.0, 0.0), CEILING, G) == (rates, False)


def fly_saturated(guard: bool, seconds: float = 5.0, dt: float = 0.002) -> tuple[float, float]:
    """A vehicle at its ceiling whose controller keeps rolling at 1 rad/s (chasing a target
    sideways): returns (final tilt deg, final vertical speed m/s)."""
    q, vz = [1.0, 0.0, 0.0, 0.0], 0.0
    for _ in range(int(seconds / dt)):
        rates = (1.0, 0.0, 0.0)
        if guard:
            rates, _ = keep_altitude_at_ceiling(CEILING, rates, q, CEILING, G)
        q = quat_turned_floats(q, [r * dt for r in rates])
        vz += (CEILING * body_z_floats(q)[2] - G) * dt
    return math.degrees(tilt_of(q)), vz


def test_a_vehicle_rolling_at_its_ceiling_sinks_without_the_guard_and_holds_with_it():
    tilt, vz = fly_saturated(guard=False)
    assert vz < -10.0  # rolled over: it falls
    tilt, vz = fly_saturated(guard=True)
    limit = math.degrees(tilt_limit_rad(CEILING, G))
    # past the limit the rate along the levelling axis is the guard's alone: the tilt comes back to
    # the limit, where the ceiling just holds the height, and stays there
    assert tilt == pytest.approx(limit, abs=0.2)
    assert 0.0 < vz < 0.5  # what it climbed while inside the limit, kept


class RollingFlatOut:
    """A controller that always asks for 20 m/s² and a roll rate of +2 rad/s (a policy chasing a
    target sideways at full thrust)."""

    builds_observation = True

    def reset(self, env) -> None:
        pass

    def act(self, env, td):
        import torch

        return torch.tensor([[20.0, 2.0, -0.5, 0.3]], dtype=env.dtype)


def _model(ceiling: float, guard, *overrides: str):
    from datt.deploy.runner import FlightModel
    from datt.envs.factory import make_env
    from datt.refs import Polygon

    cfg = compose("sim", ["env.obs.action_history=2", "adaptation=l1", *overrides])
    return FlightModel(
        lambda family: make_env(cfg, num_envs=1, seed=0, traj=family), RollingFlatOut(), Polygon(), ceiling, guard
    )


def test_the_flight_model_sends_remembers_and_counts_the_guarded_command():
    """Tilted 40 deg about x, a controller rolling further at full thrust: with the guard the
    roll rate sent is the levelling one, and the history and L1 get it."""
    import torch

    tilt = math.radians(40.0)
    q = tilted(tilt)
    state = ([0.0, 0.0, -3.0], [0.0, 0.0, -2.0], q)
    plain = _model(11.0, None).act(*state)
    model = _model(11.0, functools.partial(keep_altitude_at_ceiling, gravity_mps2=G))
    sent = model.act(*state)
    assert plain[0] == sent[0] == pytest.approx(11.0)
    wanted = -4.0 * (tilt - tilt_limit_rad(11.0, G))
    assert plain[1:] == pytest.approx([2.0, -0.5, 0.3])
    assert sent[1] == pytest.approx(wanted, rel=1e-5)
    assert sent[2:] == pytest.approx([-0.5, 0.3])
    assert model.guarded == 1
    assert torch.allclose(model.last_cmd[0].double(), torch.tensor(sent, dtype=torch.float64), atol=1e-6)
    # the attitude judged is the one the controller saw: a level predicted state is not guarded
    level = model.act(*state, predicted=(state[0], state[1], [1.0, 0.0, 0.0, 0.0]))
    assert model.guarded == 1 and level[0] == pytest.approx(11.0)


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["tilted_right", "tilted_left"])
def test_a_levelling_rate_beyond_the_rate_bounds_is_sent_at_the_bound_and_every_guarded_command_counts(sign):
    """A gain of 200/s asks ~46 rad/s of levelling at 40 deg: sent at the policy's rate bound
    (±20 rad/s), on the side that levels; each of three guarded commands is counted."""
    q = tilted(sign * math.radians(40.0))
    state = ([0.0, 0.0, -3.0], [0.0, 0.0, -2.0], q)
    model = _model(11.0, functools.partial(keep_altitude_at_ceiling, gravity_mps2=G, level_gain_per_s=200.0))
    assert model.env.action_low[1:4].tolist() == [-20.0, -20.0, -2.0]
    assert model.command_high[1:4].tolist() == [20.0, 20.0, 2.0]
    for _ in range(3):
        sent = model.act(*state)
        assert sent[1] == -sign * 20.0 and sent[2:] == pytest.approx([-0.5, 0.3])
    assert model.guarded == 3


def test_in_a_float64_env_the_guarded_rate_is_sent_as_the_guard_computed_it():
    """``env.dtype=float64``: the levelling rate reaches the command in double precision, not
    rounded through float32 on the way."""
    q = tilted(math.radians(40.0))
    model = _model(11.0, functools.partial(keep_altitude_at_ceiling, gravity_mps2=G), "env.dtype=float64")
    sent = model.act([0.0, 0.0, -3.0], [0.0, 0.0, -2.0], q)
    wanted, guarded = keep_altitude_at_ceiling(11.0, (2.0, -0.5, 0.3), model.env.sim.state.quat[0].tolist(), 11.0, G)
    assert guarded and model.last_cmd.dtype == torch.float64
    assert sent[1] == wanted[0] and float(model.last_cmd[0, 1]) == wanted[0]


def test_the_guard_is_off_by_default_and_its_settings_are_checked():
    from datt.deploy.schema import deploy_params
    from datt.errors import ConfigError

    _, flight, _, _ = deploy_params(compose("deploy").deploy)
    assert flight.ceiling_guard is False
    _, on, _, _ = deploy_params(compose("deploy", ["deploy.flight.ceiling_guard=true"]).deploy)
    assert on.ceiling_guard is True
    assert (flight.ceiling_climb_reserve_mps2, flight.ceiling_level_gain_per_s) == (0.0, 4.0)
    for key in ("ceiling_climb_reserve_mps2", "ceiling_level_gain_per_s"):
        with pytest.raises(ConfigError, match=f"deploy.flight.{key}"):
            deploy_params(compose("deploy", [f"deploy.flight.{key}=-1"]).deploy)


@pytest.mark.parametrize("reserve, gain", [(0.0, 4.0), (0.5, 2.5)], ids=["defaults", "other"])
def test_the_runner_binds_the_configured_reserve_gain_and_the_maps_gravity(reserve, gain):
    """The guard a flight uses is the configured one: its reserve and gain, the thrust map's
    gravity (here not 9.81, so a guard bound to the standard value shows); none when off."""
    from types import SimpleNamespace

    from datt.deploy.runner import FlightRunner

    runner = FlightRunner.__new__(FlightRunner)  # the settings alone: no link, no vehicle
    runner.thrust = SimpleNamespace(p=SimpleNamespace(gravity_mps2=9.0))
    on = dict(ceiling_guard=True, ceiling_climb_reserve_mps2=reserve, ceiling_level_gain_per_s=gain)
    runner.p = SimpleNamespace(**on)
    q, rates = tilted(math.radians(40.0)), (0.2, -0.1, 0.3)
    bound = runner._ceiling_guard()(CEILING, rates, q, CEILING)
    want = keep_altitude_at_ceiling(CEILING, rates, q, CEILING, 9.0, climb_reserve_mps2=reserve, level_gain_per_s=gain)
    assert bound == want and want[1]
    assert keep_altitude_at_ceiling(CEILING, rates, q, CEILING, G, reserve, gain) != want  # gravity matters here
    runner.p = SimpleNamespace(**{**on, "ceiling_guard": False})
    assert runner._ceiling_guard() is None


def test_the_flight_model_caps_only_the_thrust_at_the_maps_ceiling():
    """The commands a flight model sends are clipped at the thrust map's ceiling in thrust and at
    the env's bounds in the rates; an unknown ceiling (inf) leaves the env's thrust bound; a new
    ceiling (after the hover trim) replaces the old."""
    import torch

    free = _model(math.inf, None)
    assert torch.equal(free.command_high, free.env.command_high)
    capped = _model(11.0, None)
    assert capped.command_high[0].item() == pytest.approx(11.0)
    assert torch.equal(capped.command_high[1:], capped.env.command_high[1:])
    assert capped.env.command_high[0] > 11.0 and capped.env.command_high[1] != capped.env.command_high[0]
    capped.set_thrust_ceiling(10.5)
    assert capped.command_high[0].item() == pytest.approx(10.5)
    capped.set_thrust_ceiling(math.inf)
    assert capped.command_high[0] == capped.env.command_high[0]
