"""MPPI sampling MPC (paper §5.1) over the project's own dynamics, and L1-MPPI.

Per drone and control step (Williams et al. 2017, information-theoretic MPPI)::

    u_k = clip(U + ε_k),  ε_k ~ N(0, diag σ²),  k = 1..K   (K samples of an H-step sequence)
    c_k = dt Σ_j [ w_p ‖p_j − p_ref(t + j + 1)‖ + w_q (1 − q_w,j²) ]   (rollout of u_k)
    w_k = softmax(−(c_k − min c) / λ),   U ← Σ_k w_k u_k,   send U[0],  shift U by one step

The rollout model is :func:`datt.sim.quadrotor.integrate` (paper eq. 1 with the first-order
actuator delay) from the simulator's current state, including the commands already in flight
(``latency_steps``), with d = 0 (MPPI) or the env's d̂ held constant over the horizon (L1-MPPI,
``use_d_hat=true`` with ``adaptation=l1``). Samples are clipped to the policy's action bounds.

Defaults are the paper's (K 8192, H 40, dt 0.02 s = the env step, λ 0.05) and, where the paper is
silent, the authors' code (σ = [0.25 g, 0.7, 0.7, 0.7], cost weights 5 on position and 3 on
attitude, the attitude term being 1 − ⟨q, q_level⟩², mean warm-started and initialised at hover).
All N drones are solved at once: the rollout batch is N·K.
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from datt.configuration import BATCH, POSITIVE_WEIGHT, SEED, WEIGHT, Range, check_arg_ranges
from datt.control.base import Controller
from datt.sim.quadrotor import integrate


class MppiController(Controller):
    name = "mppi"
    ARG_RANGES = {
        "num_samples": BATCH,
        "horizon_steps": Range(1, 10_000, integer=True),
        "temperature": POSITIVE_WEIGHT,
        "noise_std": Range(0.0, 100.0, length=4),  # thrust, wx, wy, wz
        "pos_weight": WEIGHT,
        "att_weight": WEIGHT,
        "seed": SEED,
    }

    def __init__(
        self,
        num_samples: int = 8192,
        horizon_steps: int = 40,
        temperature: float = 0.05,
        noise_std: list[float] | tuple[float, ...] = (2.4525, 0.7, 0.7, 0.7),
        pos_weight: float = 5.0,
        att_weight: float = 3.0,
        use_d_hat: bool = False,
        seed: int = 0,
        compile: bool = True,
    ) -> None:
        check_arg_ranges(MppiController, locals(), "controller")
        self.num_samples, self.horizon = int(num_samples), int(horizon_steps)
        self.temperature = float(temperature)
        self.noise_std = torch.tensor([float(s) for s in noise_std])
        self.pos_weight, self.att_weight = float(pos_weight), float(att_weight)
        self.use_d_hat = bool(use_d_hat)
        self.seed = int(seed)
        self.name = "l1_mppi" if use_d_hat else "mppi"
        if compile:
            from datt.compile import compile_or_eager

            self._step = compile_or_eager(_rollout_step)
        else:
            self._step = _rollout_step

    def reset(self, env) -> None:
        kw = {"device": env.device, "dtype": env.dtype}
        self.generator = torch.Generator(device=env.device).manual_seed(self.seed)
        self.std = self.noise_std.to(**kw)
        self.hover = env.hover_action[:1].to(**kw)  # [1, 4]
        self.mean = self.hover.expand(env.n, self.horizon, 4).clone()  # [N, H, 4]
        self._last_step = env.step_idx.clone()

    def rollout_cost(self, env, u: torch.Tensor, d_mps2: torch.Tensor, inputs=None) -> torch.Tensor:
        """Cost ``[N, K]`` of the action sequences ``u [N, K, H, 4]`` from the current state
        (``inputs``: the env's control input with ``ahead_steps >= H``)."""
        n, k, h = u.shape[0], u.shape[1], u.shape[2]
        if inputs is None:
            inputs = env.control_input(ahead_steps=h)
        qp = env.sim.params
        state = (inputs["pos_m"], inputs["vel_mps"], inputs["quat"], inputs["rate_radps"], inputs["thrust_mps2"])

        def expand(x: torch.Tensor) -> torch.Tensor:
            return x.unsqueeze(1).expand(n, k, *x.shape[1:]).reshape(n * k, *x.shape[1:])

        pos, vel, quat, rate, thrust = (expand(x) for x in state)
        d = expand(d_mps2)
        ref = inputs["ref_ahead_m"]  # [N, H, 3]: p_d(t + 1 .. t + H)
        in_flight = inputs["cmd_in_flight"].transpose(0, 1)  # [L, N, 4], oldest first
        lat = in_flight.shape[0]
        u_flat = u.reshape(n * k, h, 4)
        cost = torch.zeros(n * k, device=u.device, dtype=u.dtype)
        consts = (
            env.sim.gravity,
            env.dt_s,
            qp.k_thrust,
            qp.k_rate,
            qp.max_thrust_mps2,
            qp.max_rate_radps,
            self.pos_weight,
            self.att_weight,
        )
        for j in range(h):
            applied = expand(in_flight[j]) if j < lat else u_flat[:, j - lat]
            pos, vel, quat, rate, thrust, cost = self._step(
                pos, vel, quat, rate, thrust, cost, applied, d, ref[:, j], *consts
            )
        return (cost * env.dt_s).view(n, k)

    @torch.no_grad()
    def act(self, env, td: TensorDictBase) -> torch.Tensor:
        inputs = env.control_input(ahead_steps=self.horizon)
        restarted = inputs["step"] < self._last_step
        self.mean[restarted] = self.hover
        self._last_step = inputs["step"].clone()
        n, k, h = env.n, self.num_samples, self.horizon
        noise = torch.randn(n, k, h, 4, generator=self.generator, device=env.device, dtype=env.dtype) * self.std
        u = torch.maximum(torch.minimum(self.mean.unsqueeze(1) + noise, env.action_high), env.action_low)
        d = inputs["d_hat"] if self.use_d_hat else torch.zeros(n, 3, device=env.device, dtype=env.dtype)
        cost = self.rollout_cost(env, u, d, inputs)
        weights = torch.softmax(-(cost - cost.min(dim=1, keepdim=True).values) / self.temperature, dim=1)
        self.mean = torch.einsum("nk,nkhc->nhc", weights, u)
        action = self.mean[:, 0].clone()
        self.mean = torch.cat((self.mean[:, 1:], self.mean[:, -1:]), dim=1)
        return action


def _rollout_step(
    pos: torch.Tensor,
    vel: torch.Tensor,
    quat: torch.Tensor,
    rate: torch.Tensor,
    thrust: torch.Tensor,
    cost: torch.Tensor,
    applied: torch.Tensor,
    d: torch.Tensor,
    ref: torch.Tensor,
    gravity: torch.Tensor,
    dt: float,
    k_thrust: float,
    k_rate: float,
    max_thrust: float,
    max_rate: float,
    pos_weight: float,
    att_weight: float,
):
    """One model step of all N·K rollouts and its running cost (compilable). ``ref [N, 3]``; the
    rollouts are drone-major, so rows ``i·K .. (i+1)·K − 1`` belong to drone i."""
    pos, vel, quat, rate, thrust, _ = integrate(
        pos, vel, quat, rate, thrust, applied, d, gravity, dt, k_thrust, k_rate, max_thrust, max_rate
    )
    n = ref.shape[0]
    err = torch.linalg.vector_norm(pos.view(n, -1, 3) - ref.unsqueeze(1), dim=-1).reshape(-1)
    cost = cost + pos_weight * err + att_weight * (1.0 - quat[:, 0] ** 2)
    return pos, vel, quat, rate, thrust, cost
