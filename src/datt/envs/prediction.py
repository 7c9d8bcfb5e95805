"""The training side of the off-board state predictor (``env.obs.predict_latency``).

Off-board, the command a policy sends acts several steps after the state it answers; the
deployment's :class:`datt.deploy.predictor.StatePredictor` rolls the estimate forward over the
commands already on their way so the policy answers the state its command will meet. A policy
that is to fly behind it is trained behind the same prediction: with ``d`` steps of command
latency, the measured state is rolled over the ``d − 1`` commands in flight before the last one
sent, so that (as at the nominal one step of latency) the next command to act is the last one
sent, which the policy reads from its command history.

The model is the controller's own nominal one (:func:`datt.sim.quadrotor.integrate` with unit
thrust scale and the first-order actuators, whatever the simulated vehicle's rate model), with
the adaptation's d̂ as the disturbance, and the actuators taken to hold the command acting when
the state was measured (as the deployment's predictor assumes: the vehicle's actuator state is
not measured). Frames: world z up, quaternions (w, x, y, z) body to world.
"""

from __future__ import annotations

import torch
from torch import Tensor

from datt.sim.quadrotor import QuadrotorParams, integrate


def roll_forward(
    pos_m: Tensor,
    vel_mps: Tensor,
    quat: Tensor,
    acting_cmd: Tensor,
    commands: Tensor,
    active: Tensor,
    d_hat_mps2: Tensor,
    gravity_mps2: Tensor,
    quad: QuadrotorParams,
    dt_s: float,
) -> tuple[Tensor, Tensor, Tensor]:
    """The state ``(pos [N, 3], vel [N, 3], quat [N, 4])`` rolled forward one ``dt_s`` step per
    command of ``commands [S, N, 4]`` (thrust m/s², body rates rad/s; oldest first) where
    ``active [S, N]``; a drone's inactive steps leave it where it is. ``acting_cmd [N, 4]``: the
    command acting when the state was measured (the actuators' assumed state); ``d_hat_mps2
    [N, 3]``: world-frame disturbance estimate; ``gravity_mps2 [3]``: the world-frame gravity
    vector (the simulator's ``gravity``)."""
    if commands.shape[0] == 0:
        return pos_m, vel_mps, quat
    thrust, rate = acting_cmd[:, 0].clone(), acting_cmd[:, 1:].clone()
    pos, vel, q = pos_m, vel_mps, quat
    for command, on in zip(commands, active):
        if not bool(on.any()):
            break  # later steps are inactive for every drone too (active is a prefix)
        new = integrate(
            pos, vel, q, rate, thrust, command, d_hat_mps2, gravity_mps2, dt_s,
            quad.k_thrust, quad.k_rate, quad.max_thrust_mps2, quad.max_rate_radps,
        )[:5]  # fmt: skip
        keep = on.unsqueeze(-1)
        pos, vel, q, rate = (torch.where(keep, a, b) for a, b in zip(new[:4], (pos, vel, q, rate)))
        thrust = torch.where(on, new[4], thrust)
    return pos, vel, q
