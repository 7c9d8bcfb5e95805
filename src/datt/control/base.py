"""Controller protocol shared by evaluation, tables and deployment.

A controller is batched: ``reset(env)`` after the env (re)starts its N drones, then
``act(env, td) -> [N, 4]`` every step, returning ``[thrust_mps2, wx, wy, wz]`` (the env's action
convention). Inputs come from the env's public control input, ``env.control_input(ahead_steps)``
(measured state, reference window and the reference further ahead, commands in flight, command
history, d̂, step index; see :meth:`datt.envs.TrackingEnv.control_input`) and its constants
(``dt_s``, ``action_low/high``, ``hover_action``, ``sim.params``); ``td`` is the env's policy
observation, used by controllers with ``builds_observation = False``.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase


class Controller:
    name = "controller"
    # True: act() reads the sim state / reference / d̂ itself and ignores ``td`` (so timing does not
    # charge it for the env's observation); False: act() consumes the env's observation ``td``.
    builds_observation = True

    def reset(self, env) -> None:
        """Called after ``env.reset()`` (all drones)."""

    def act(self, env, td: TensorDictBase) -> torch.Tensor:
        raise NotImplementedError


class HoverController(Controller):
    """Holds hover thrust and zero rates: the do-nothing reference point for tracking errors
    (its error is how far the reference strays from the start)."""

    name = "hover"

    def act(self, env, td: TensorDictBase) -> torch.Tensor:
        return env.hover_action
