"""Attitude integration from its definition, at attitudes where the order of a product shows: body
rates turn the body about its *own* axes (R <- R expm([w]x dt), a quaternion q <- q (x) exp(w dt / 2)),
so a yawed vehicle that rolls turns about its rolled body x, not the world's x. Each rate model is
checked against rotation matrices computed here, independently of ``datt.sim.frames``; at the
identity attitude both orders of the product agree, so every case starts yawed and tilted."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from datt.sim.quadrotor import Quadrotor, QuadrotorParams

DT_S = 0.02
G = 9.81


def _skew(w):
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def _expm_so3(rotvec):
    """Rodrigues' formula: the rotation matrix of ``rotvec`` (axis x angle)."""
    angle = float(np.linalg.norm(rotvec))
    if angle == 0.0:
        return np.eye(3)
    k = _skew(np.asarray(rotvec) / angle)
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k


def _euler_matrix(yaw, pitch, roll):
    return _expm_so3([0, 0, yaw]) @ _expm_so3([0, pitch, 0]) @ _expm_so3([roll, 0, 0])


def _matrix_to_quat(m):
    """[w, x, y, z] of a rotation matrix (Shepperd's method, the largest diagonal branch)."""
    t = np.trace(m)
    if t > 0:
        s = math.sqrt(t + 1.0) * 2
        return [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
    i = int(np.argmax(np.diag(m)))
    j, k = (i + 1) % 3, (i + 2) % 3
    s = math.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k]) * 2
    q = [0.0] * 4
    q[0] = (m[k, j] - m[j, k]) / s
    q[1 + i] = 0.25 * s
    q[1 + j] = (m[j, i] + m[i, j]) / s
    q[1 + k] = (m[k, i] + m[i, k]) / s
    return q


def _quat_to_matrix(q):
    w, x, y, z = (float(c) for c in q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


START = _euler_matrix(math.radians(90.0), math.radians(20.0), math.radians(-30.0))
RATES = {"roll": [2.0, 0.0, 0.0], "pitch": [0.0, 2.0, 0.0], "yaw": [0.0, 0.0, 2.0]}


def _quad(rate_model: str) -> Quadrotor:
    params = QuadrotorParams(rate_model=rate_model, latency_steps=0, max_thrust_mps2=40.0)
    quad = Quadrotor(1, params, dtype="float64")
    quad.reset()
    return quad


def _spinning(quad: Quadrotor, rate) -> None:
    """The vehicle at START turning at ``rate`` (body frame) in steady state: the rate command is
    the rate itself, so the rate loop has nothing to correct."""
    s = quad.state
    s.quat[0] = torch.tensor(_matrix_to_quat(START), dtype=torch.float64)
    s.rate_radps[0] = torch.tensor(rate, dtype=torch.float64)
    if quad.firmware is not None:  # the rate PIDs' derivative starts from this rate
        quad.firmware.state.prev_rate_dps[0] = torch.rad2deg(s.rate_radps[0])


def _step(quad: Quadrotor, thrust: float, rate) -> None:
    quad.step(torch.tensor([[thrust, *rate]], dtype=torch.float64))


def test_the_independent_rotations_agree_with_each_other():
    q = _matrix_to_quat(START)
    assert np.linalg.norm(q) == pytest.approx(1.0)
    np.testing.assert_allclose(_quat_to_matrix(q), START, atol=1e-12)
    np.testing.assert_allclose(_expm_so3([0.3, 0, 0]), _euler_matrix(0, 0, 0.3), atol=1e-12)


@pytest.mark.parametrize("axis", list(RATES))
def test_the_first_order_model_turns_the_body_about_its_own_axes(axis):
    quad = _quad("first_order")
    _spinning(quad, RATES[axis])
    _step(quad, G, RATES[axis])
    want = START @ _expm_so3(np.array(RATES[axis]) * DT_S)
    np.testing.assert_allclose(_quat_to_matrix(quad.state.quat[0]), want, atol=1e-9)
    # the world-frame product differs by far more than the tolerance: the case can tell them apart
    assert np.abs(_expm_so3(np.array(RATES[axis]) * DT_S) @ START - want).max() > 1e-3


def test_the_first_order_model_turns_about_a_rate_off_the_axes_too():
    rate = [1.5, -1.0, 0.7]
    quad = _quad("first_order")
    _spinning(quad, rate)
    _step(quad, G, rate)
    want = START @ _expm_so3(np.array(rate) * DT_S)
    np.testing.assert_allclose(_quat_to_matrix(quad.state.quat[0]), want, atol=1e-9)


def test_the_first_order_thrust_pushes_along_the_body_z_axis_the_step_began_with():
    """acc = R e_z T + g over the step (the attitude at its start); pos gains v dt + acc dt^2 / 2."""
    quad = _quad("first_order")
    _spinning(quad, RATES["roll"])
    _step(quad, G, RATES["roll"])
    acc = START[:, 2] * G + np.array([0.0, 0.0, -G])
    np.testing.assert_allclose(quad.state.vel_mps[0].numpy(), acc * DT_S, atol=1e-12)
    np.testing.assert_allclose(quad.state.pos_m[0].numpy(), acc * DT_S**2 / 2, atol=1e-12)


@pytest.mark.parametrize("axis", list(RATES))
def test_the_firmware_model_turns_the_body_about_its_own_axes(axis):
    """A rate about one principal axis, commanded as it is: the PIDs see no error, the gyroscopic
    term is zero, and ten 2 ms ticks compose to one rotation of rate x 20 ms about that body axis."""
    quad = _quad("firmware")
    _spinning(quad, RATES[axis])
    thrust = 9.0  # below the cap: the mixer leaves every motor equal
    _step(quad, thrust, RATES[axis])
    torch.testing.assert_close(quad.state.rate_radps[0], torch.tensor(RATES[axis], dtype=torch.float64))
    want = START @ _expm_so3(np.array(RATES[axis]) * DT_S)
    np.testing.assert_allclose(_quat_to_matrix(quad.state.quat[0]), want, atol=1e-9)
    assert np.abs(_expm_so3(np.array(RATES[axis]) * DT_S) @ START - want).max() > 1e-3


def test_the_firmware_models_thrust_follows_the_turning_body_z_axis_tick_by_tick():
    """Each 2 ms tick pushes along that tick's body z (after its turn): the velocity after the step is
    the sum over the ticks of (R_k e_z T_k + g) dt_tick with R_k = START expm(w k dt_tick)."""
    quad = _quad("firmware")
    rate = RATES["pitch"]
    _spinning(quad, rate)
    loop = quad.firmware
    forces_before = loop.state.forces_n[0].clone()
    _step(quad, 9.0, rate)
    # the motors' forces per tick, re-run from the same start (equal motors: the collective alone)
    target = math.trunc(math.trunc(9.0 * loop.command_per_mps2)) / 65535 * loop.vehicle.thrust_max_n
    forces = float(forces_before[0])
    vel = np.zeros(3)
    for k in range(1, loop.ticks + 1):
        forces += loop.blend * (target - forces)
        thrust = 4 * forces / loop.mass_kg
        r_k = START @ _expm_so3(np.array(rate) * loop.tick_s * k)
        vel += (r_k[:, 2] * thrust + np.array([0.0, 0.0, -G])) * loop.tick_s
    np.testing.assert_allclose(quad.state.vel_mps[0].numpy(), vel, atol=1e-9)
