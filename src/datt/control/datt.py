"""The learned DATT policy as a controller (deterministic: the squashed location of its TanhNormal)."""

from __future__ import annotations

import warnings

import torch
from tensordict import TensorDictBase
from torch import nn

from datt.control.base import Controller
from datt.envs.tracking import action_center_half
from datt.policies.networks import InferenceNet
from datt.sim.frames import quat_to_rotmat_bilinear

# Up to this many drones the frozen path runs the conv encoder as dense layers (fewer ops, more
# arithmetic; see InferenceNet), above it as convs.
DENSE_ENCODER_MAX_BATCH = 16


class DattController(Controller):
    """Wraps a trained actor. ``d_hat`` comes from the env's adaptation option (privileged, none,
    l1, rma), so switching adaptation needs no retraining.

    Acting calls the actor's network directly and squashes its location as TorchRL's TanhNormal
    does for ``ExplorationType.DETERMINISTIC`` (``low + (high − low)(tanh(loc) + 1)/2``; a test
    checks the two agree): at batch 1 the tensordict and distribution plumbing costs more than the
    network itself, and per-step latency is what a flight computer pays.

    ``frozen=True`` (evaluation, deployment) builds the observation itself from the env's public
    control input (:meth:`~datt.envs.TrackingEnv.control_input`: measured state, reference window,
    d̂, command history), and runs observation + network
    as one TorchScript graph traced and frozen once per input shape, with the network rewritten
    for batch 1 (:class:`~datt.policies.networks.InferenceNet`; a test checks it computes the same
    actions); the weights must not change afterwards. ``frozen=False`` (training-time uses such as RMA
    fitting) reads the env's observation ``td``, including any observation noise.
    """

    name = "datt"

    def __init__(self, actor, frozen: bool = False) -> None:
        self.actor = actor
        self.net = actor.module[0].module.net  # TrackingNet: (state, ref, d_hat) -> [loc | scale logits]
        dist_kwargs = actor.module[1].distribution_kwargs
        low, high = dist_kwargs["low"], dist_kwargs["high"]
        self.center, self.half = action_center_half(low, high)
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
        inputs = env.control_input()
        d_hat = inputs["d_hat"]
        # the state and window as the observation sees them (obs.predict_latency, a deployment's lead);
        # the window [H, N, 3] is the graph's slot-major layout
        pos, vel, quat, future = env.policy_view()
        obs = env.params.obs
        cmds = inputs["cmd_history"].flatten(1)  # [N, 4k], k = obs.action_history (may be 0)
        key = (tuple(future.shape), pos.dtype, obs.body_frame, obs.feedback, cmds.shape[1])
        fn = self._traced.get(key)
        if fn is None:
            module = ObservePolicy(
                self.net,
                future.shape[0],
                self.center,
                self.half,
                obs.body_frame,
                obs.feedback,
                dense_encoder=future.shape[1] <= DENSE_ENCODER_MAX_BATCH,
            ).eval()
            with warnings.catch_warnings():  # TorchScript's deprecation notices
                warnings.simplefilter("ignore")
                traced = torch.jit.trace(module, (pos, vel, quat, future, d_hat, cmds), check_trace=False)
            fn = self._traced[key] = torch.jit.freeze(traced)
        return fn(pos, vel, quat, future, d_hat, cmds)


class ObservePolicy(nn.Module):
    """Observation building + network + squashing as one graph (traced and frozen by
    :class:`DattController` with ``frozen=True``): the controller's whole per-step computation
    from the measured state, the future reference ``[H, N, 3]``, d̂ and the scaled command history
    ``[N, 4k]`` to the action.

    Same function as :func:`~datt.envs.observations.build_observation` followed by the net, with
    fewer tensor ops: ``R(q)`` as one bilinear form and one batched matmul rotating every vector,
    and the net as its :class:`~datt.policies.networks.InferenceNet` (loc rows only; dense encoder up
    to ``DENSE_ENCODER_MAX_BATCH`` drones).
    """

    def __init__(
        self,
        net: nn.Module,
        horizon: int,
        center: torch.Tensor,
        half: torch.Tensor,
        body_frame: bool,
        feedback: bool,
        dense_encoder: bool = True,
    ) -> None:
        super().__init__()
        self.net = InferenceNet(net, horizon, 4, dense_encoder)
        self.body_frame, self.feedback = body_frame, feedback
        self.register_buffer("action_center", center)
        self.register_buffer("action_half", half)

    def forward(self, pos, vel, quat, future, d_hat, cmds):
        vecs = torch.cat((pos.unsqueeze(0), vel.unsqueeze(0), pos.unsqueeze(0) - future), 0)
        vecs = vecs.transpose(0, 1)  # [N, 2+H, 3]
        if self.body_frame:  # row vectors: v^T R = (R^T v)^T
            vecs = torch.bmm(vecs, quat_to_rotmat_bilinear(quat))  # the form is a constant of the frozen graph
            feedforward = vecs[:, 2:]
        else:  # raw future reference positions, as build_observation
            feedforward = future.transpose(0, 1)
        p = vecs[:, 0] if self.feedback else torch.zeros_like(vecs[:, 0])
        state = torch.cat((p, vecs[:, 1], quat, vecs[:, 2], cmds), dim=-1)
        loc = self.net(state, feedforward, d_hat)
        return self.action_center + self.action_half * torch.tanh(loc)
