"""The learned DATT policy as a controller (deterministic: the squashed location of its TanhNormal)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from datt.control.base import Controller


class DattController(Controller):
    """Wraps a trained actor. ``d_hat`` comes from the env's adaptation option (privileged, none,
    l1, rma), so switching adaptation needs no retraining."""

    name = "datt"

    def __init__(self, actor) -> None:
        self.actor = actor

    @torch.no_grad()
    def act(self, env, td: TensorDictBase) -> torch.Tensor:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.actor(td.select("state", "ref", "d_hat"))["action"]
