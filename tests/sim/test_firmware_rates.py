"""The training-side firmware rate model (``env.quad.rate_model: firmware``) against the simulated
Crazyflie's own stabilizer (an independent implementation of the same firmware) and against
cases with a known answer."""

from __future__ import annotations

import math

import pytest
import torch

from datt.deploy.sim.motors import FirmwareMotors, MotorParams
from datt.deploy.sim.stabilizer import Stabilizer
from datt.sim.firmware_rates import UINT16_MAX
from datt.sim.quadrotor import Quadrotor, QuadrotorParams
from datt.sim.vehicles import CF21

MASS_KG = 0.034
HOVER = 9.81


def _quad(n: int = 1, **kw) -> Quadrotor:
    params = QuadrotorParams(rate_model="firmware", latency_steps=0, max_thrust_mps2=12.92, **kw)
    quad = Quadrotor(n, params, dtype="float64")
    quad.reset()
    return quad


def _step(quad: Quadrotor, thrust: float, rates=(0.0, 0.0, 0.0), d=None) -> None:
    cmd = torch.tensor([[thrust, *rates]], dtype=torch.float64).expand(quad.n, 4)
    quad.step(cmd, d)


@pytest.mark.parametrize("tau_s", [0.03, 0.0])
def test_it_turns_and_lifts_the_body_as_the_simulated_crazyflies_stabilizer_does(tau_s):
    """Tick for tick the same rates and collective as :class:`datt.deploy.sim.stabilizer.Stabilizer`
    over a sequence that saturates the PIDs, hits the cap and cuts the motors."""
    quad = _quad(motor_time_constant_s=tau_s)
    ref = Stabilizer(FirmwareMotors(MotorParams(mass_kg=MASS_KG)), tau_s)
    ref.reset()
    ref.forces_n = [HOVER * MASS_KG / 4] * 4  # the training model starts in the air at hover
    sequence = [(9.81, 1.0, 0.0, 0.0), (12.0, 5.0, -3.0, 1.0), (12.9, 12.0, 0.0, 0.0), (5.0, -2.0, 1.0, 0.5)]
    sequence += [(0.0, 3.0, 3.0, 0.0), (1.0, 0.0, 0.0, 0.0), (11.0, -8.0, 8.0, -2.0)]
    for thrust, *rates in sequence * 2:
        _step(quad, thrust, rates)
        command = int(min(thrust, 12.92) * MASS_KG / 4 / CF21.thrust_max_n * UINT16_MAX)
        for _ in range(10):
            force_n = ref.tick(tuple(rates), command, 4.0)
        torch.testing.assert_close(quad.state.rate_radps[0], torch.tensor(ref.rate_radps, dtype=torch.float64))
        assert float(quad.state.thrust_mps2[0]) == pytest.approx(force_n / MASS_KG, abs=1e-9)


def test_at_the_hover_command_it_holds_its_place_and_attitude():
    quad = _quad()
    for _ in range(50):
        _step(quad, HOVER)
    s = quad.state
    # the command is truncated to whole units: at most one unit (2e-4 m/s^2) short of hover
    assert s.pos_m[0].abs().max() < 1e-4
    assert s.quat[0].tolist() == pytest.approx([1.0, 0.0, 0.0, 0.0], abs=1e-12)
    assert float(s.thrust_mps2[0]) == pytest.approx(HOVER, abs=3e-4)


def test_near_full_thrust_a_hard_roll_costs_collective_thrust_that_the_first_order_model_never_charges():
    """The cap lowers all four motors together: at the ceiling (12.92 m/s^2, command 60000) a
    10 rad/s roll demand leaves over 1 m/s^2 less collective than the same command flown level,
    while at 7 m/s^2 (headroom) a roll back and forth costs under 1 %."""

    def mean_thrust(thrust: float, roll) -> float:
        quad, total = _quad(), 0.0
        for k in range(5):
            _step(quad, thrust, (roll(k), 0.0, 0.0))
            total += float(quad.state.thrust_mps2[0]) / 5
        return total

    assert mean_thrust(12.92, lambda k: 10.0) < mean_thrust(12.92, lambda k: 0.0) - 1.0
    assert mean_thrust(7.0, lambda k: 10.0 * (-1) ** k) == pytest.approx(mean_thrust(7.0, lambda k: 0.0), rel=0.01)


def test_a_zero_thrust_command_stops_the_motors_and_clears_the_pids():
    quad = _quad(motor_time_constant_s=0.0)
    _step(quad, 12.0, (5.0, 5.0, 1.0))
    assert quad.firmware.state.integral_degs.abs().sum() > 0
    _step(quad, 0.0, (5.0, 5.0, 1.0))
    assert float(quad.state.thrust_mps2[0]) == 0.0
    assert quad.firmware.state.integral_degs.abs().sum() == 0.0
    # free fall over the step (from the velocity the first step left)
    assert quad.firmware.state.forces_n.abs().sum() == 0.0


def test_a_disturbance_and_gravity_move_it_as_a_point_mass_when_the_motors_are_off():
    quad = _quad(motor_time_constant_s=0.0)
    d = torch.tensor([[1.0, -2.0, 0.0]], dtype=torch.float64)
    _step(quad, 0.0, d=d)
    # semi-implicit Euler over 10 ticks of 2 ms: x = a h^2 (1 + 2 + ... + 10)
    h = 0.002
    expected = torch.tensor([1.0, -2.0, -9.81], dtype=torch.float64) * h * h * 55
    torch.testing.assert_close(quad.state.pos_m[0], expected)


def test_a_drones_motor_gain_turns_it_and_its_mass_only_lifts_it():
    """Domain randomisation: the drawn gain scales the motor forces (torques and lift), the drawn
    mass only the lift; ``thrust_scale`` = gain / mass as in the other rate models."""
    quad = _quad(2, thrust_gain_spread=0.2, mass_spread=0.2)
    quad.randomise(torch.arange(2), torch.Generator().manual_seed(1))
    gain, scale = quad.motor_gain.clone(), quad.thrust_scale.clone()
    assert not torch.allclose(gain, scale)
    strong = _quad(1, motor_time_constant_s=0.0)
    weak = _quad(1, motor_time_constant_s=0.0, thrust_gain_spread=0.2)
    weak.motor_gain[:] = 0.8
    weak.thrust_scale[:] = 0.8
    _step(strong, 9.81, (0.0, 0.0, 1.0))
    _step(weak, 9.81, (0.0, 0.0, 1.0))
    # yaw torque is linear in the forces: 80 % of it on the first tick, before the rates differ
    assert 0.7 < float(weak.state.rate_radps[0, 2]) / float(strong.state.rate_radps[0, 2]) < 0.9
    assert float(weak.state.vel_mps[0, 2]) == pytest.approx(-9.81 * 0.2 * 0.02, rel=0.02)


def test_reset_puts_a_drone_back_at_rest_with_its_motors_at_the_initial_thrust():
    quad = _quad(2)
    _step(quad, 12.0, (6.0, -3.0, 1.0))
    quad.reset(torch.tensor([0]))
    fw = quad.firmware.state
    assert fw.integral_degs[0].abs().sum() == 0 and fw.prev_rate_dps[0].abs().sum() == 0
    assert fw.forces_n[0].tolist() == pytest.approx([HOVER * MASS_KG / 4] * 4)
    assert fw.integral_degs[1].abs().sum() > 0  # the other drone keeps its loop


def test_a_tracking_env_trains_on_it():
    """The env and its specs with the firmware rate model (a compiled step as well)."""
    from torchrl.envs.utils import check_env_specs

    from datt.envs.params import EnvParams
    from datt.envs.tracking import TrackingEnv
    from datt.refs.zigzag import Zigzag

    params = EnvParams(quad=QuadrotorParams(rate_model="firmware", max_thrust_mps2=12.92))
    env = TrackingEnv(8, Zigzag(), params=params, seed=0)
    check_env_specs(env)
    assert env.sim.firmware is not None and math.isclose(env.sim.firmware.tick_s, 0.002)


@pytest.mark.parametrize("kwargs, key", [({"vehicle_mass_kg": 0.0}, "vehicle_mass_kg"),
                                         ({"motor_time_constant_s": -0.01}, "motor_time_constant_s")])  # fmt: skip
def test_its_settings_are_checked(kwargs, key):
    from datt.errors import ConfigError

    with pytest.raises(ConfigError, match=f"env.quad.{key}"):
        Quadrotor(1, QuadrotorParams(rate_model="firmware", **kwargs))


def test_the_transfer_test_evaluates_each_simulated_rate_loop_on_its_training_twin():
    """``benchmarks/transfer.py --rate-loop``: every loop the simulated Crazyflie flies has the
    training simulator's rate model that evaluates the same loop (the ratio's denominator)."""
    from datt.deploy.sim.server import RATE_LOOPS
    from datt.sim.quadrotor import RATE_MODELS
    from datt.tasks.transfer import EVAL_RATE_MODEL

    assert set(EVAL_RATE_MODEL) == set(RATE_LOOPS)
    assert EVAL_RATE_MODEL["firmware"] == "firmware" and set(EVAL_RATE_MODEL.values()) <= set(RATE_MODELS)
