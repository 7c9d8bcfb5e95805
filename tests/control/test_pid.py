"""PID baseline: tilt-prioritised attitude math on hand cases, hover and step response settle."""

import math

import pytest
import torch

from datt.configuration import compose
from datt.control.pid import PidController
from datt.envs.factory import make_env
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
