"""Evaluation protocols: how an episode of the evaluation bank starts and which steps count.

``eval.protocol`` names one of :data:`PROTOCOLS`:

* ``project``: every drone starts at rest *on* the reference (its start, the origin) at hover
  thrust, whatever start the policy was trained from; the mean error of an episode runs over the
  steps flown before it crashed, and crashed episodes are left out of the group's mean (shown as a
  count). This measures tracking once the drone is on the track.
* ``authors``: the protocol that produced the paper's numbers, read from KevinHuang8/DATT
  (commit 42ddfc8):

  - start position uniform within ±0.5 m per axis of the reference start, at rest and level
    (``configuration/datt.py`` lines 20-40: ``init_config.pos`` randomised on [-0.5, 0.5]^3,
    ``vel``/``rot``/``ang`` fixed at zero; drawn at every reset, ``learning/base_env.py``
    lines 152-159);
  - zero thrust at the start: the simulator is rebuilt at every reset (``base_env.py`` line 148),
    so its actuator state ``curr_bodyz_force`` and an empty command queue give zero thrust until
    the first command comes out of the queue (``quadsim/sim.py`` lines 27-33 and 90-102);
  - 500 steps per episode (``base_env.py`` line 117, ``t_end = 500 dt``), every step counted:
    the error of step k is ``‖p(t_k) − p_d(t_k)‖`` of the true state after the step against the
    reference at the env's time (``learning/eval_policy.py`` lines 119-148), averaged over the
    episode (line 260); there is no termination and no episode is left out.

Both protocols draw the starts from their own generator seeded with the evaluation seed, so every
controller and every condition (disturbance, adaptation) of a seed sees the same starts.
Observation timing (``env.obs.timing``) belongs to the policy, not to the protocol.
"""

from __future__ import annotations

from dataclasses import dataclass

from omegaconf import DictConfig

from datt.errors import ConfigError


@dataclass(frozen=True)
class Protocol:
    """``init_pos_range_m``: start uniformly within ± this per axis of the reference start;
    ``initial_thrust_mps2``: actuator thrust at the start (``None``: hover); ``episode_steps``:
    steps per episode (``None`` keeps ``env.episode_steps``); ``count_every_step``: the episode
    mean runs over every step and no episode is left out of a group's mean (crashes are still
    counted); ``terminate_on_error``: honour ``env.max_tracking_error_m`` as a crash."""

    init_pos_range_m: float
    initial_thrust_mps2: float | None
    episode_steps: int | None
    count_every_step: bool
    terminate_on_error: bool


PROTOCOLS: dict[str, Protocol] = {
    "project": Protocol(0.0, None, None, count_every_step=False, terminate_on_error=True),
    "authors": Protocol(0.5, 0.0, 500, count_every_step=True, terminate_on_error=False),
}


def get_protocol(name: str) -> Protocol:
    if name not in PROTOCOLS:
        raise ConfigError(f"eval.protocol: unknown value {name!r}; allowed: {', '.join(PROTOCOLS)}")
    return PROTOCOLS[name]


def apply_protocol(env_cfg: DictConfig, protocol: Protocol) -> None:
    """Set the ``env`` node of a (copied) run config to the protocol's episode."""
    env_cfg.env.init_pos_range_m = protocol.init_pos_range_m
    env_cfg.env.quad.initial_thrust_mps2 = protocol.initial_thrust_mps2
    if protocol.episode_steps is not None:
        env_cfg.env.episode_steps = protocol.episode_steps
    if not protocol.terminate_on_error:
        env_cfg.env.max_tracking_error_m = None
