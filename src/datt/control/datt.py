"""The learned DATT policy as a controller (deterministic: the squashed location of its TanhNormal)."""

from __future__ import annotations

import warnings

import torch
from tensordict import TensorDictBase
from torch import nn

from datt.control.base import Controller
from datt.envs.observations import build_observation


class DattController(Controller):
    """Wraps a trained actor. ``d_hat`` comes from the env's adaptation option (privileged, none,
    l1, rma), so switching adaptation needs no retraining.

    Acting calls the actor's network directly and squashes its location as TorchRL's TanhNormal
    does for ``ExplorationType.DETERMINISTIC`` (``low + (high − low)(tanh(loc) + 1)/2``; a test
    checks the two agree): at batch 1 the tensordict and distribution plumbing costs more than the
    network itself, and per-step latency is what a flight computer pays.

    ``frozen=True`` (evaluation, deployment) builds the observation itself from the simulator's
    (measured) state, the reference window and the adaptation's d̂, and runs observation + network
    as one TorchScript graph traced and frozen once per input shape (about 3x faster at batch 1);
    the weights must not change afterwards. ``frozen=False`` (training-time uses such as RMA
    fitting) reads the env's observation ``td``, including any observation noise.
    """

    name = "datt"

    def __init__(self, actor, frozen: bool = False) -> None:
        self.actor = actor
        self.net = actor.module[0].module.net  # TrackingNet: (state, ref, d_hat) -> [loc | scale logits]
        dist_kwargs = actor.module[1].distribution_kwargs
        low, high = dist_kwargs["low"], dist_kwargs["high"]
        self.center, self.half = (high + low) / 2, (high - low) / 2
        self.frozen = frozen
        self.builds_observation = frozen
        self._traced: dict = {}

    @torch.no_grad()
    def act(self, env, td: TensorDictBase) -> torch.Tensor:
        if self.frozen:
            return self._act_frozen(env)
        loc = self.net(td["state"], td["ref"], td["d_hat"])[..., :4]
        return self.center + self.half * torch.tanh(loc)

    def _act_frozen(self, env) -> torch.Tensor:
        s, future, d_hat = env.sim.state, env._ref_future(), env.adaptation.d_hat
        obs = env.params.obs
        key = (tuple(future.shape), s.pos_m.dtype, obs.body_frame, obs.feedback)
        fn = self._traced.get(key)
        if fn is None:
            module = _ObservePolicy(self.net, self.center, self.half, obs.body_frame, obs.feedback).eval()
            with warnings.catch_warnings():  # TorchScript's deprecation notices
                warnings.simplefilter("ignore")
                traced = torch.jit.trace(module, (s.pos_m, s.vel_mps, s.quat, future, d_hat), check_trace=False)
            fn = self._traced[key] = torch.jit.freeze(traced)
        return fn(s.pos_m, s.vel_mps, s.quat, future, d_hat)


class _ObservePolicy(nn.Module):
    """Observation building + network + squashing as one graph (traced and frozen by
    :class:`DattController` with ``frozen=True``): the controller's whole per-step computation
    from the measured state, the future reference ``[H, N, 3]`` and d̂ to the action."""

    def __init__(self, net: nn.Module, center: torch.Tensor, half: torch.Tensor, body_frame: bool, feedback: bool) -> None:
        super().__init__()
        self.net, self.body_frame, self.feedback = net, body_frame, feedback
        self.register_buffer("action_center", center)
        self.register_buffer("action_half", half)

    def forward(self, pos, vel, quat, future, d_hat):
        state, ref = build_observation(pos, vel, quat, future, self.body_frame, self.feedback)
        loc = self.net(state, ref, d_hat)[..., :4]
        return self.action_center + self.action_half * torch.tanh(loc)
