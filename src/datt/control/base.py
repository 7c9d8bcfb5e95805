"""Controller protocol shared by evaluation, tables and deployment.

A controller is batched: ``reset(env)`` after the env (re)starts its N drones, then
``act(env, td) -> [N, 4]`` every step, returning ``[thrust_mps2, wx, wy, wz]`` (the env's action
convention). ``td`` is the env's current observation (``state``, ``ref``, ``d_hat``); the
controller may also read ``env.sim.state`` and the reference window for model-based control.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase


class Controller:
    name = "controller"

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
