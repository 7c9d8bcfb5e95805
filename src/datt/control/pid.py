"""PID position control with tilt-prioritised attitude control (paper §5.1), and L1-PID.

Per drone, with e = p − p_d (world), d̂ from the env's adaptation option (zero for plain PID)::

    a_fb = −K_P e − K_D (v − v_d) − K_I ∫e + a_d − g − d̂            (g = (0, 0, −9.81))
    z_fb = a_fb / ‖a_fb‖,  z = R e3,  thrust = a_fb · z
    ω    = −K_R (R^T z_fb × e3) + ψ_fb e3,  ψ_fb = −K_yaw wrap(ψ − ψ_ref)   (body frame)

The tilt term is evaluated in the body frame (``R^T z_fb × e3`` is the body-frame form of the
paper's ``z_fb × z``), so ω is directly the body-rate command.

Gains: K_P 6, K_I 1.5, K_D 4 and K_yaw 13.75 are the paper's. The paper's K_R = 120 is in the
authors' firmware units: their code divides the attitude gains by 16 (K_yaw 13.75 = 220 / 16,
tilt 150 / 16), so ``k_tilt`` defaults to 120 / 16 = 7.5 rad/s per unit tilt error; 120 rad/s
drives the delayed rate loop unstable. Reference velocity and acceleration come from finite
differences of the reference table (the env gives references only as positions), so on zigzags
the acceleration feed-forward is zero between corners and a spike at them.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from datt.configuration import WEIGHT, check_arg_ranges
from datt.control.base import Controller
from datt.sim.frames import quat_rotate_inverse, quat_yaw, wrap_angle


class PidController(Controller):
    name = "pid"
    ARG_RANGES = dict.fromkeys(("kp", "ki", "kd", "k_tilt", "k_yaw", "integral_limit_m_s"), WEIGHT)

    def __init__(
        self,
        kp: float = 6.0,
        ki: float = 1.5,
        kd: float = 4.0,
        k_tilt: float = 7.5,
        k_yaw: float = 13.75,
        integral_limit_m_s: float = 2.0,
        use_d_hat: bool = False,
    ) -> None:
        check_arg_ranges(PidController, locals(), "controller")
        self.kp, self.ki, self.kd = kp, ki, kd
        self.k_tilt, self.k_yaw = k_tilt, k_yaw
        self.integral_limit = integral_limit_m_s
        self.use_d_hat = use_d_hat
        self.name = "l1_pid" if use_d_hat else "pid"

    def reset(self, env) -> None:
        self.integral = torch.zeros(env.n, 3, device=env.device, dtype=env.dtype)
        self._last_step = env.step_idx.clone()

    def act(self, env, td: TensorDictBase) -> torch.Tensor:
        inputs = env.control_input(ahead_steps=2)
        pos, vel, quat, step = inputs["pos_m"], inputs["vel_mps"], inputs["quat"], inputs["step"]
        dt = env.dt_s
        # A drone whose episode restarted (partial reset) starts a fresh integral.
        restarted = step < self._last_step
        self.integral[restarted] = 0.0
        self._last_step = step.clone()

        p0, p1, p2 = inputs["ref_window_m"][:, 0], inputs["ref_ahead_m"][:, 0], inputs["ref_ahead_m"][:, 1]
        v_ref = (p1 - p0) / dt
        a_ref = (p2 - 2 * p1 + p0) / (dt * dt)
        err = pos - p0
        self.integral = (self.integral + err * dt).clamp(-self.integral_limit, self.integral_limit)
        a_fb = -self.kp * err - self.kd * (vel - v_ref) - self.ki * self.integral + a_ref
        a_fb = a_fb - env.sim.gravity
        if self.use_d_hat:
            a_fb = a_fb - inputs["d_hat"]
        a_body = quat_rotate_inverse(quat, a_fb)
        norm = torch.linalg.vector_norm(a_body, dim=-1, keepdim=True).clamp_min(1e-6)
        z_fb = a_body / norm
        thrust = a_body[:, 2]  # a_fb · z, with z = R e3 -> third body component
        # −K_R (z_fb × e3) in the body frame = K_R (−z_fb_y, z_fb_x, 0): a positive rotation about
        # body y tips the thrust axis toward +x, one about body x toward −y.
        rates = torch.stack(
            (-self.k_tilt * z_fb[:, 1], self.k_tilt * z_fb[:, 0], -self.k_yaw * wrap_angle(quat_yaw(quat))), dim=-1
        )
        return torch.cat((thrust.unsqueeze(-1), rates), dim=-1)
