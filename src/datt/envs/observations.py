"""Policy inputs (paper §3.1 and the authors' layout), built for N drones at once.

Keys and shapes (body frame unless ``ObsParams.body_frame`` is False):

* ``state [N, 13 + 4k]`` = (R^T p, R^T v, q (w, x, y, z), R^T (p − p_d(t)), then the last k
  commands scaled to [-1, 1], oldest first (``ObsParams.action_history`` = k, default 0))
* ``ref [N, H, 3]``: R^T (p − p_d(t + i Δ)) for i = 0..H−1, Δ = ``ref_spacing_s`` (own minus
  reference, as the authors; i = 0 repeats the feedback term, matching the paper's h_t)
* ``d_hat [N, 3]``: disturbance input, world frame
* ``critic_ref [N, K, 3]`` (only with ``ObsParams.critic_ref_points`` = K > 0; the critic's
  input, never the policy's): the entries of ``ref`` at t + k Δc, k = 1..K

Ablations change only what is written here, as the authors defined them
(``learning/tasks/trajectory_fbff.py``): ``body_frame=False`` drops the rotations (the quaternion
stays) and ``ref`` holds the raw future reference positions p_d(t + iΔ) (world) instead of
errors; ``feedback=False`` zeroes the absolute position R^T p in ``state`` (the authors' layout
``[R^T (p − p_d(t)), R^T v, q]``: the feedback error takes the position's place), same width.
"""

from __future__ import annotations

import torch
from torch import Tensor

from datt.envs.params import ObsParams, RewardParams
from datt.sim.frames import quat_rotate_inverse, quat_yaw, wrap_angle

STATE_DIM = 13  # without the optional command history
FEEDBACK = slice(10, 13)  # the feedback error's entries in ``state``


def state_width(obs: ObsParams) -> int:
    """Width of ``state``: the 13 entries plus 4 per command of ``obs.action_history``."""
    return STATE_DIM + 4 * obs.action_history


def build_observation(
    pos_m: Tensor, vel_mps: Tensor, quat: Tensor, ref_future_m: Tensor, body_frame: bool = True, feedback: bool = True
) -> tuple[Tensor, Tensor]:
    """Return ``(state [N, 13], ref [N, H, 3])``.

    ``pos_m, vel_mps [N, 3]`` (measured, world), ``quat [N, 4]``, ``ref_future_m [H, N, 3]``
    reference points (world) at t + iΔ, i = 0..H−1 (slot-major, as the env stores them).
    """
    err = pos_m.unsqueeze(0) - ref_future_m  # [H, N, 3]
    if body_frame:
        # One batched rotation for every vector of the drone: [2 + H, N, 3].
        vecs = quat_rotate_inverse(quat.unsqueeze(0), torch.cat((torch.stack((pos_m, vel_mps)), err), 0))
        p_b, v_b, err = vecs[0], vecs[1], vecs[2:]
        feedforward = err
    else:  # the authors' no-body-frame input: where the reference goes, not how far off the drone is
        p_b, v_b = pos_m, vel_mps
        feedforward = ref_future_m
    if not feedback:
        p_b = torch.zeros_like(p_b)
    state = torch.cat((p_b, v_b, quat, err[0]), dim=-1)
    return state, feedforward.transpose(0, 1).contiguous()


def critic_reference(pos_m: Tensor, quat: Tensor, points_m: Tensor, body_frame: bool = True) -> Tensor:
    """``critic_ref [N, K, 3]`` from the reference points ``points_m [N, K, 3]`` (world): own
    minus reference in the body frame, as ``ref``; without the body frame the raw points."""
    if not body_frame:
        return points_m.clone()
    err = pos_m.unsqueeze(1) - points_m
    return quat_rotate_inverse(quat.unsqueeze(1), err)


def observe_and_cost(
    pos_meas_m: Tensor,
    vel_meas_mps: Tensor,
    quat_meas: Tensor,
    pos_m: Tensor,
    vel_mps: Tensor,
    quat: Tensor,
    ref_future_m: Tensor,
    obs: ObsParams,
    reward: RewardParams,
    obs_ref_future_m: Tensor | None = None,
) -> tuple[Tensor, Tensor, Tensor, Tensor]:
    """Observation plus the per-step cost, in one pass (compiled as one kernel by the env).

    The observation is built from the measured ``*_meas`` state, the tracking error and cost from
    the true one; ``obs_ref_future_m [H, N, 3]`` (default ``ref_future_m``) is the window the
    observation reads (``obs.predict_latency``: the reference as far ahead as the prediction).
    Returns ``state [N, 13]``, ``ref [N, H, 3]``, ``tracking_error_m [N, 1]`` and
    ``cost [N, 1]`` = pos ‖p − p_d‖ + yaw |ψ| + vel min(‖v‖, cap) (reward = −cost).
    """
    seen = ref_future_m if obs_ref_future_m is None else obs_ref_future_m
    state, ref = build_observation(pos_meas_m, vel_meas_mps, quat_meas, seen, obs.body_frame, obs.feedback)
    err_m = torch.linalg.vector_norm(pos_m - ref_future_m[0], dim=-1, keepdim=True)
    yaw_err = wrap_angle(quat_yaw(quat)).abs().unsqueeze(-1)  # ψ_ref = 0
    speed = torch.linalg.vector_norm(vel_mps, dim=-1, keepdim=True).clamp_max(reward.vel_cap_mps)
    cost = reward.pos * err_m + reward.yaw * yaw_err + reward.vel * speed
    return state, ref, err_m, cost
