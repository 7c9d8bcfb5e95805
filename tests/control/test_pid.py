"""PID baseline: tilt-prioritised attitude math on hand cases, hover and step response settle."""

import math

import pytest
import torch

from datt.configuration import compose
from datt.control.pid import PidController
from datt.envs.factory import make_env
from datt.errors import ConfigError
from datt.eval.rollout import run_controller
from datt.refs.base import RefFamily
from datt.sim.frames import quat_from_euler


class Point(RefFamily):
    """A constant reference point (hover / step targets)."""

    def __init__(self, xyz):
        self.xyz = torch.tensor(xyz, dtype=torch.float64)

    def sample(self, n, t_s, generator):
        return self.xyz.to(t_s.dtype).expand(n, len(t_s), 3).clone()


def env_at(point, n=2, overrides=()):
    cfg = compose("sim", ["env.init_pos_range_m=0", "disturbance=none", *overrides])
    return make_env(cfg, num_envs=n, traj=Point(point))


def test_hover_at_the_reference_is_exact():
    env = env_at([0.0, 0.0, 0.0])
    trace = run_controller(env, PidController(), steps=200)
    assert trace.err_m.abs().max() < 1e-5
    assert torch.allclose(trace.action[:, -1], torch.tensor([9.81, 0.0, 0.0, 0.0]).expand(2, 4), atol=1e-4)


@pytest.mark.parametrize("target", [[0.5, 0.0, 0.0], [0.0, -0.5, 0.3]])
def test_step_response_settles(target):
    env = env_at(target)
    trace = run_controller(env, PidController(), steps=500)
    err = trace.err_m[0]
    assert err[0] > 0.4
    assert err[100:].max() < 0.1  # fast modes done within 2 s
    # then the integral's slow real pole (s ≈ -0.31 for s³ + 4s² + 6s + 1.5) decays the rest
    assert err[450:].max() < 0.02
    assert (err[150:].diff() <= 1e-6).all()
    assert (trace.crashed_at == 500).all()


def test_tilt_prioritised_attitude_hand_cases():
    env = env_at([0.0, 0.0, 0.0], n=3)
    td = env.reset()
    pid = PidController(kp=6, ki=0, kd=0, k_tilt=7.5, k_yaw=13.75)
    pid.reset(env)
    s = env.sim.state
    # drone 0 one metre behind the reference in x: a_fb = (6, 0, 9.81), level drone
    s.pos_m[0] = torch.tensor([-1.0, 0.0, 0.0])
    # drone 1 at the reference but yawed by 0.4 rad
    s.quat[1] = quat_from_euler(torch.tensor(0.0), torch.tensor(0.0), torch.tensor(0.4))
    # drone 2 one metre to +y of the reference: a_fb = (0, -6, 9.81)
    s.pos_m[2] = torch.tensor([0.0, 1.0, 0.0])
    a = pid.act(env, td)
    norm = math.hypot(6.0, 9.81)
    # thrust = a_fb · z with z = e3 (level) = 9.81; pitch rate tips the thrust axis toward +x
    assert a[0].tolist() == pytest.approx([9.81, 0.0, 7.5 * 6.0 / norm, 0.0], abs=1e-4)
    assert a[1].tolist() == pytest.approx([9.81, 0.0, 0.0, -13.75 * 0.4], abs=1e-4)
    # toward −y: a positive roll rate tips the thrust axis toward −y
    assert a[2].tolist() == pytest.approx([9.81, 7.5 * 6.0 / norm, 0.0, 0.0], abs=1e-4)


def test_l1_pid_removes_a_constant_disturbance_faster_than_pid():
    def final_error(ctl, adaptation):
        cfg = compose("sim", ["env.init_pos_range_m=0", "disturbance=constant", f"adaptation={adaptation}"])
        env = make_env(cfg, num_envs=32, traj=Point([0.0, 0.0, 0.0]))
        return run_controller(env, ctl, steps=100).err_m[:, 50:].mean().item()

    plain = final_error(PidController(), "none")
    adaptive = final_error(PidController(use_d_hat=True), "l1")
    assert adaptive < 0.3 * plain, (plain, adaptive)


class Quadratic(RefFamily):
    """p_d(t) = v0 t + ½ a t² (world, per axis): a reference whose velocity changes every step."""

    def __init__(self, v0, a):
        self.v0 = torch.tensor(v0, dtype=torch.float64)
        self.a = torch.tensor(a, dtype=torch.float64)

    def sample(self, n, t_s, generator):
        t = t_s.to(torch.float64).unsqueeze(-1)
        return (self.v0 * t + 0.5 * self.a * t * t).to(t_s.dtype).expand(n, len(t_s), 3).clone()


def quadratic_env(v0, a, n=1):
    cfg = compose("sim", ["env.init_pos_range_m=0", "disturbance=none", "env.dtype=float64"])
    return make_env(cfg, num_envs=n, traj=Quadratic(v0, a))


def test_feed_forward_is_the_forward_difference_of_the_reference_at_the_drones_own_step():
    """v_d = (p_d(t + dt) − p_d(t)) / dt = v0 + a (t + dt / 2) and a_d = a on p_d = v0 t + ½ a t²,
    read at the drone's step k (t = k dt): a level drone on the reference, moving with v_d(t),
    commands thrust g + a_z + K_D (v_d − v)_z = g + a_z + K_D a_z dt / 2."""
    v0, a, kd = [0.0, 0.0, 0.5], [0.0, 0.0, 1.5], 4.0
    env = quadratic_env(v0, a)
    td = env.reset()
    for _ in range(10):  # step 10: t = 0.2 s
        td = env.step(td.set("action", env.hover_action.expand(1, 4).clone()))["next"]
    t, dt = 10 * env.dt_s, env.dt_s
    assert int(env.step_idx[0]) == 10
    pos = [0.0, 0.0, v0[2] * t + 0.5 * a[2] * t * t]
    env.set_state([pos], [[0.0, 0.0, v0[2] + a[2] * t]], [[1.0, 0.0, 0.0, 0.0]])
    pid = PidController(kp=6.0, ki=0.0, kd=kd, k_tilt=7.5, k_yaw=0.0)
    pid.reset(env)
    action = pid.act(env, td)[0]
    assert action[0].item() == pytest.approx(9.81 + a[2] + kd * a[2] * dt / 2, abs=1e-6)
    assert action[1:].abs().max().item() < 1e-9


def test_horizontal_feed_forward_tilts_toward_the_references_acceleration():
    """At rest at p_d(0) with p_d = ½ a t² along x and only the feed-forward (gains 0 but K_D):
    a_fb = (K_D a dt / 2 + a, 0, g), so the pitch rate is K_tilt a_fb,x / ‖a_fb‖ and thrust g."""
    a, kd, k_tilt = 2.0, 1.0, 7.5
    env = quadratic_env([0.0, 0.0, 0.0], [a, 0.0, 0.0])
    td = env.reset()
    pid = PidController(kp=0.0, ki=0.0, kd=kd, k_tilt=k_tilt, k_yaw=0.0)
    pid.reset(env)
    action = pid.act(env, td)[0]
    ax = a + kd * a * env.dt_s / 2
    assert action.tolist() == pytest.approx([9.81, 0.0, k_tilt * ax / math.hypot(ax, 9.81), 0.0], abs=1e-6)


def test_the_integral_is_error_times_dt_clamped_and_restarts_only_for_a_restarted_drone():
    env = env_at([0.0, 0.0, 0.0], n=2)
    td = env.reset()
    pid = PidController(kp=0.0, ki=1.0, kd=0.0, integral_limit_m_s=2.0)
    pid.reset(env)
    env.set_state([[0.5, 0.0, 0.0], [0.0, -10.0, 0.0]], torch.zeros(2, 3), [[1.0, 0.0, 0.0, 0.0]] * 2)
    dt = env.dt_s
    for m in range(1, 4):
        pid.act(env, td)
        assert pid.integral[0].tolist() == pytest.approx([0.5 * dt * m, 0.0, 0.0])
        assert pid.integral[1].tolist() == pytest.approx([0.0, -10.0 * dt * m, 0.0])
    for _ in range(10):
        action = pid.act(env, td)
    assert pid.integral[1].tolist() == pytest.approx([0.0, -2.0, 0.0])  # clamped at the limit
    # the integral enters the command: drone 0 feels −K_I ∫e along x (roll stays 0), drone 1 +2 along y
    assert action[0, 2] < 0 and action[1, 1] < 0 and action[0, 1].abs() < 1e-9
    # drone 0's episode restarts (a partial reset): its integral starts over, drone 1's is kept
    td = env.step(td.set("action", env.hover_action.expand(2, 4).clone()))["next"]
    pid.act(env, td)  # at step 1 (no restart: both integrals go on)
    assert pid.integral[0].tolist() == pytest.approx([0.5 * dt * 14, 0.0, 0.0], rel=1e-5)
    held = pid.integral[1].clone()
    env.reset(td.empty().set("_reset", torch.tensor([[True], [False]])))
    env.set_state([[0.5, 0.0, 0.0], [0.0, -10.0, 0.0]], torch.zeros(2, 3), [[1.0, 0.0, 0.0, 0.0]] * 2)
    pid.act(env, td)
    assert pid.integral[0].tolist() == pytest.approx([0.5 * dt, 0.0, 0.0])
    assert torch.equal(pid.integral[1], held)  # saturated: one more step keeps it at the limit


@pytest.mark.parametrize("sign", [1.0, -1.0], ids=["above", "below"])
def test_the_integral_saturates_at_the_limit_on_either_side(sign):
    """A drone held 10 m from its reference on each axis accumulates ∫e until the anti-windup limit,
    +limit for a positive error and −limit for a negative one, per axis."""
    env = env_at([0.0, 0.0, 0.0], n=1)
    td = env.reset()
    pid = PidController(kp=0.0, ki=1.0, kd=0.0, integral_limit_m_s=0.5)
    pid.reset(env)
    env.set_state([[10.0 * sign, 10.0 * sign, 10.0 * sign]], torch.zeros(1, 3), [[1.0, 0.0, 0.0, 0.0]])
    for _ in range(10):  # 10 m x 0.02 s per step: the limit after 3 steps
        pid.act(env, td)
    assert pid.integral[0].tolist() == pytest.approx([0.5 * sign] * 3)


def test_a_pid_is_named_by_its_estimator_and_refuses_a_bad_gain_naming_the_controller_key():
    assert PidController().name == "pid" and PidController(use_d_hat=True).name == "l1_pid"
    assert not PidController().use_d_hat
    with pytest.raises(ConfigError, match=r"^controller\.kd: must be a finite number in \[0, 1000\]"):
        PidController(kd=-1.0)
