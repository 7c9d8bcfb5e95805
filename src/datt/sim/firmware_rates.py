"""A stock Crazyflie 2.1's own rotational loop as a training-side rate model, batched
(``env.quad.rate_model: firmware``): the rate setpoint goes through the firmware's rate PIDs, its
motor mixing and thrust cap, four motors with a spin-up lag, and a rigid body, at the firmware's
500 Hz inside each control step. A policy trained on it learns what the paper's first-order model
never charges: a hard turn near full thrust takes thrust from the collective (the cap lowers all
four motors together), and the body turns through its own inertia, not a fixed fraction per step.

Read from crazyflie-firmware 2026.08, the same sources as the simulated Crazyflie's
:mod:`datt.deploy.sim.stabilizer` (an independent, batched implementation: the tests compare the
two tick for tick). The vehicle's numbers (gains, frame, inertia, THRUST_MAX, THRUST_MIN) are its
preset's (``env.quad.vehicle``, :mod:`datt.sim.vehicles`, each cited and checked against a
firmware checkout):

* rate PIDs (``controller_pid.c`` in rate mode, ``utils/src/pid.c``): per body axis on the error
  in deg/s, derivative on the measurement, integral clamped to its limit, output saturated to
  int16 (truncated); a zero thrust command resets them and stops the motors;
* mixing and cap (``power_distribution_quadrotor.c``, legacy): motor ``i`` gets the thrust command
  plus its signs times half the roll and pitch outputs and the whole yaw output; every motor is
  lowered by the largest one's excess over 65535 and floored at 0;
* motors: command ``c`` asks for ``c / 65535 * THRUST_MAX`` N; under ``THRUST_MIN`` the motor is
  off; the force follows with a first-order lag of ``motor_time_constant_s`` (an estimate, not a
  firmware number) and is scaled by the drone's motor gain (domain randomisation). A full battery
  is assumed (its cap, above ``THRUST_MAX`` for a charged cell, never binds);
* body: X frame, ``ARM_LENGTH`` from centre to motor, ``THRUST2TORQUE`` yaw torque per newton,
  diagonal inertia of ``controller_lee.c``; Euler's equations; each tick turns the attitude by the
  tick's rates and moves the drone with the tick's acceleration (semi-implicit Euler).

The policy's thrust (m/s², mass-normalised) becomes the per-motor command of a linear thrust map,
``c = a * mass_kg / 4 / THRUST_MAX * 65535``, the map of ``datt.deploy.thrust`` for the firmware's
own fit, so ``env.quad.max_thrust_mps2`` 12.92 is ``max_command`` 60000 on a 34 g ``cf21``.

Frames and shapes: world z-up, body FLU; rates ``[N, 3]`` rad/s, forces ``[N, 4]`` N (motors
M1..M4: front-right, back-right, back-left, front-left).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor

from datt.sim.frames import quat_body_z, quat_exp_rotvec, quat_mul, quat_normalize
from datt.sim.vehicles import CF21, Vehicle

ATTITUDE_RATE_HZ = 500  # stabilizer_types.h: ATTITUDE_RATE
UINT16_MAX = 65535
INT16_MIN, INT16_MAX = -32768, 32767
# signs of the roll, pitch and yaw outputs in each motor's command (legacy mixing, body FLU torques)
MIX_SIGNS = ((-0.5, -0.5, -1.0), (-0.5, 0.5, 1.0), (0.5, 0.5, -1.0), (0.5, -0.5, 1.0))


@dataclass
class FirmwareLoopState:
    """Per-drone state of the loop. Shapes: ``integral_degs`` and ``prev_rate_dps`` ``[N, 3]``
    (the PIDs' integral, in deg, and last measured rate, in deg/s); ``forces_n`` ``[N, 4]``."""

    integral_degs: Tensor
    prev_rate_dps: Tensor
    forces_n: Tensor


class FirmwareRateLoop:
    """The loop's constants as tensors, its state, and :meth:`step` over one control step."""

    def __init__(
        self,
        n: int,
        dt_s: float,
        mass_kg: float,
        motor_time_constant_s: float,
        initial_thrust_mps2: float,
        device: torch.device,
        dtype: torch.dtype,
        vehicle: Vehicle = CF21,
    ) -> None:
        kw = {"device": device, "dtype": dtype}
        self.vehicle = vehicle
        self.ticks = max(1, round(dt_s * ATTITUDE_RATE_HZ))
        self.tick_s = dt_s / self.ticks
        gains = torch.tensor(vehicle.rate_pid, **kw)
        self.kp, self.ki, self.kd, self.i_limit = gains.unbind(-1)  # each [3]
        self.mix = torch.tensor(MIX_SIGNS, **kw)  # [4, 3]
        arm = vehicle.arm_length_m / math.sqrt(2.0)
        # torque about body x, y, z of a newton on each motor ([3, 4]): x = +y arm, y = -x arm
        motor_xy = ((1, -1), (-1, -1), (-1, 1), (1, 1))
        yaw = [signs[2] * vehicle.thrust2torque_m for signs in MIX_SIGNS]  # drag turns the body with the yaw sign
        self.torque_per_n = torch.tensor([[y * arm for _, y in motor_xy], [-x * arm for x, _ in motor_xy], yaw], **kw)
        self.inertia = torch.tensor(vehicle.inertia_kgm2, **kw)
        self.mass_kg = float(mass_kg)
        self.command_per_mps2 = mass_kg / 4.0 / vehicle.thrust_max_n * UINT16_MAX
        self.blend = 1.0 if motor_time_constant_s <= 0 else 1.0 - math.exp(-self.tick_s / motor_time_constant_s)
        self.state = FirmwareLoopState(
            integral_degs=torch.zeros(n, 3, **kw),
            prev_rate_dps=torch.zeros(n, 3, **kw),
            forces_n=torch.zeros(n, 4, **kw),
        )
        self.reset(torch.arange(n, device=device), initial_thrust_mps2)
        self._ticks = run_ticks

    def reset(self, idx: Tensor, thrust_mps2: float) -> None:
        """Drones ``idx`` at rest: PIDs cleared, motors spinning at ``thrust_mps2``."""
        s = self.state
        s.integral_degs[idx] = 0.0
        s.prev_rate_dps[idx] = 0.0
        s.forces_n[idx] = thrust_mps2 * self.mass_kg / 4.0

    def step(self, *inputs: Tensor | float | None) -> tuple[Tensor, ...]:
        """One control step: :func:`run_ticks` on ``inputs`` (``pos`` to ``thrust_scale``, in its
        order) and this loop's state, which it updates. Returns (pos, vel, quat, rate,
        thrust_mps2), the thrust being the motors' collective force per unit mass before the
        drone's gain/mass."""
        s = self.state
        *out, s.integral_degs, s.prev_rate_dps, s.forces_n = self._ticks(
            self, *inputs, s.integral_degs, s.prev_rate_dps, s.forces_n
        )
        return tuple(out)

    def compile(self, **kwargs) -> None:
        """Use a ``torch.compile``-d tick loop."""
        from datt.compile import compile_or_eager

        self._ticks = compile_or_eager(run_ticks, **kwargs)


def run_ticks(
    loop: FirmwareRateLoop,
    pos: Tensor,
    vel: Tensor,
    quat: Tensor,
    rate: Tensor,
    applied: Tensor,
    d: Tensor,
    gravity: Tensor,
    max_thrust: float,
    motor_gain: Tensor | None,
    thrust_scale: Tensor | None,
    integral: Tensor,
    prev: Tensor,
    forces: Tensor,
) -> tuple[Tensor, ...]:
    """The ``loop.ticks`` stabilizer ticks of one control step (module docstring); a function of
    its inputs and the loop's constants. Returns (pos, vel, quat, rate, thrust, integral, prev,
    forces)."""
    tick_s = loop.tick_s
    command = torch.trunc(applied[:, 0].clamp(0.0, max_thrust) * loop.command_per_mps2)
    flying = (command > 0).unsqueeze(-1)
    setpoint_dps = torch.rad2deg(applied[:, 1:])
    for _ in range(loop.ticks):  # at least one: the thrust below is the last tick's
        rate_dps = torch.rad2deg(rate)
        error = setpoint_dps - rate_dps
        integral = torch.minimum(torch.maximum(integral + error * tick_s, -loop.i_limit), loop.i_limit)
        out = loop.kp * error - loop.kd * (rate_dps - prev) / tick_s + loop.ki * integral
        out = torch.trunc(out.clamp(INT16_MIN, INT16_MAX))
        # a zero thrust command: outputs zero, integrals cleared, the derivative restarts here
        integral = torch.where(flying, integral, torch.zeros_like(integral))
        prev = rate_dps
        motors = command.unsqueeze(-1) + out @ loop.mix.T  # [N, 4]
        excess = (motors.amax(-1, keepdim=True) - UINT16_MAX).clamp_min(0.0)
        motors = torch.where(flying, (motors - excess).clamp_min(0.0), torch.zeros_like(motors))
        target = torch.trunc(motors).clamp(max=UINT16_MAX) / UINT16_MAX * loop.vehicle.thrust_max_n
        target = torch.where(target < loop.vehicle.thrust_min_n, torch.zeros_like(target), target)
        forces = forces + loop.blend * (target - forces)
        produced = forces if motor_gain is None else forces * motor_gain.unsqueeze(-1)
        torque = produced @ loop.torque_per_n.T  # [N, 3]
        jw = rate * loop.inertia
        rate = rate + tick_s * (torque - torch.linalg.cross(rate, jw)) / loop.inertia
        quat = quat_normalize(quat_mul(quat, quat_exp_rotvec(rate * tick_s)))
        thrust = forces.sum(-1) / loop.mass_kg
        accel = thrust if thrust_scale is None else thrust * thrust_scale
        acc = quat_body_z(quat) * accel.unsqueeze(-1) + gravity + d
        vel = vel + acc * tick_s
        pos = pos + vel * tick_s
    return pos, vel, quat, rate, thrust, integral, prev, forces
