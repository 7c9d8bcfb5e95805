"""Batched quadrotor dynamics (paper eq. 1) with first-order actuator delay.

Model, per drone (all SI, world frame z-up, unit mass so thrust is an acceleration)::

    p' = v
    v' = g + R(q) e3 T + d          T: collective thrust (m/s²), d: disturbance (m/s²)
    q' = q ⊗ (0, ω) / 2             ω: body rates (rad/s)

Inputs are the commanded thrust ``T_cmd`` and body rates ``ω_cmd``. A command reaches the
actuators ``latency_steps`` steps after it is sent, then passes through the first-order delay
of paper §4.1, ``x ← x + k (x_cmd − x)`` with ``k = 0.4`` per 0.02 s step for thrust and rates.

Integration over one step of ``dt_s`` (actuators first, then the state):
    p ← p + v dt + ½ a dt²,  v ← v + a dt     (exact for the step's constant a)
    q ← q ⊗ exp(ω dt / 2)                      (exact for the step's constant ω)
The quaternion is renormalised after the product to remove float rounding.

The rotational rigid-body equation of eq. 1 (``J ω' = ...``) is replaced by the delayed rate
tracking above, as in the paper's simulator: the onboard rate controller is assumed to track.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from datt.sim.frames import quat_body_z, quat_exp_rotvec, quat_mul, quat_normalize

_DTYPES = {"float32": torch.float32, "float64": torch.float64}


def resolve_dtype(name: str | torch.dtype) -> torch.dtype:
    if isinstance(name, torch.dtype):
        return name
    try:
        return _DTYPES[name]
    except KeyError:
        raise ValueError(f"dtype: unknown value {name!r}; allowed: {sorted(_DTYPES)}") from None


@dataclass
class QuadrotorParams:
    """Simulator constants (config ``env.quad``; the step ``dt_s`` is ``env.dt_s``).

    ``initial_thrust_mps2``: actuator thrust state after reset; ``None`` means hover (= g),
    which avoids the spurious drop of the authors' sim that started every episode at zero thrust.
    """

    gravity_mps2: float = 9.81
    k_thrust: float = 0.4
    k_rate: float = 0.4
    latency_steps: int = 1
    initial_thrust_mps2: float | None = None
    max_thrust_mps2: float = 40.0
    max_rate_radps: float = 40.0

    def validate(self, prefix: str = "env.quad") -> None:
        from datt.errors import ConfigError

        for key in ("k_thrust", "k_rate"):
            val = getattr(self, key)
            if not 0.0 < val <= 1.0:
                raise ConfigError(f"{prefix}.{key}: must be in (0, 1], got {val}")
        if self.latency_steps < 0:
            raise ConfigError(f"{prefix}.latency_steps: must be >= 0, got {self.latency_steps}")
        if not self.max_thrust_mps2 > 0:
            raise ConfigError(f"{prefix}.max_thrust_mps2: must be > 0, got {self.max_thrust_mps2}")
        if not self.max_rate_radps > 0:
            raise ConfigError(f"{prefix}.max_rate_radps: must be > 0, got {self.max_rate_radps}")


@dataclass
class QuadState:
    """State of N drones. Shapes: pos_m, vel_mps, rate_radps ``[N, 3]``; quat ``[N, 4]``;
    thrust_mps2 ``[N]`` (actuator output after the delay)."""

    pos_m: Tensor
    vel_mps: Tensor
    quat: Tensor
    rate_radps: Tensor
    thrust_mps2: Tensor


class CommandLatency:
    """Fixed transport delay of ``steps`` control steps for batched commands ``[N, *shape]``.

    ``push(cmd)`` stores the command sent now and returns the one sent ``steps`` steps ago
    (``steps = 0``: the command itself). Slots start at ``fill``; ``reset(idx)`` refills drones."""

    def __init__(self, steps: int, fill: Tensor, n: int) -> None:
        self.steps = int(steps)
        self.fill = fill
        self._queue = fill.expand(max(self.steps, 1), n, *fill.shape).clone()
        self._head = 0

    def push(self, cmd: Tensor) -> Tensor:
        if not self.steps:
            return cmd
        applied = self._queue[self._head].clone()
        self._queue[self._head] = cmd
        self._head = (self._head + 1) % self.steps
        return applied

    def in_flight(self) -> Tensor:
        """Commands sent but not yet applied, oldest first: ``[steps, N, *shape]``."""
        if not self.steps or self._head == 0:  # slot order is already oldest first (a view)
            return self._queue[: self.steps]
        order = (self._head + torch.arange(self.steps, device=self._queue.device)) % self.steps
        return self._queue.index_select(0, order)

    def reset(self, idx: Tensor) -> None:
        self._queue[:, idx] = self.fill

    def fill_all(self, value: Tensor | float) -> None:
        self._queue[:] = value


class Quadrotor:
    """N quadrotors integrated in lock-step; every operation is one batched tensor op."""

    def __init__(
        self,
        num_drones: int,
        params: QuadrotorParams | None = None,
        dt_s: float = 0.02,
        device: str | torch.device = "cpu",
        dtype: str | torch.dtype = "float32",
    ) -> None:
        self.params = params or QuadrotorParams()
        self.params.validate()
        if not dt_s > 0:
            from datt.errors import ConfigError

            raise ConfigError(f"env.dt_s: must be > 0, got {dt_s}")
        self.dt_s = float(dt_s)
        self.n = int(num_drones)
        self.device = torch.device(device)
        self.dtype = resolve_dtype(dtype)
        p = self.params
        kw = {"device": self.device, "dtype": self.dtype}
        self.gravity = torch.tensor([0.0, 0.0, -p.gravity_mps2], **kw)
        self.hover_cmd = torch.tensor([p.gravity_mps2, 0.0, 0.0, 0.0], **kw)
        self.initial_thrust = p.gravity_mps2 if p.initial_thrust_mps2 is None else p.initial_thrust_mps2
        n = self.n
        self.state = QuadState(
            pos_m=torch.zeros(n, 3, **kw),
            vel_mps=torch.zeros(n, 3, **kw),
            quat=torch.zeros(n, 4, **kw),
            rate_radps=torch.zeros(n, 3, **kw),
            thrust_mps2=torch.zeros(n, **kw),
        )
        self.state.quat[:, 0] = 1.0
        self.state.thrust_mps2.fill_(self.initial_thrust)
        self.latency = CommandLatency(p.latency_steps, self.hover_cmd, n)
        self.last_applied_cmd = self.hover_cmd.expand(n, 4).clone()
        self._integrate = integrate

    def reset(self, idx: Tensor | None = None, pos_m: Tensor | None = None) -> None:
        """Reset drones ``idx`` (long tensor; all when None) to rest, level, at ``pos_m [k, 3]``."""
        s = self.state
        if idx is None:
            idx = torch.arange(self.n, device=self.device)
        s.pos_m[idx] = 0.0 if pos_m is None else pos_m.to(self.dtype)
        s.vel_mps[idx] = 0.0
        s.quat[idx] = torch.tensor([1.0, 0.0, 0.0, 0.0], device=self.device, dtype=self.dtype)
        s.rate_radps[idx] = 0.0
        s.thrust_mps2[idx] = self.initial_thrust
        self.latency.reset(idx)
        self.last_applied_cmd[idx] = self.hover_cmd

    def step(self, cmd: Tensor, disturbance_mps2: Tensor | None = None) -> QuadState:
        """Advance all drones by ``dt_s``.

        ``cmd [N, 4]`` = (thrust_mps2, wx, wy, wz) commanded now; ``disturbance_mps2 [N, 3]``
        world-frame acceleration acting during this step. Updates and returns ``self.state``.
        """
        p = self.params
        applied = self.latency.push(cmd)
        self.last_applied_cmd = applied
        if disturbance_mps2 is None:
            disturbance_mps2 = torch.zeros_like(self.state.pos_m)
        s = self.state
        s.pos_m, s.vel_mps, s.quat, s.rate_radps, s.thrust_mps2 = self._integrate(
            s.pos_m,
            s.vel_mps,
            s.quat,
            s.rate_radps,
            s.thrust_mps2,
            applied,
            disturbance_mps2,
            self.gravity,
            self.dt_s,
            p.k_thrust,
            p.k_rate,
            p.max_thrust_mps2,
            p.max_rate_radps,
        )
        return s

    def compile(self, **kwargs) -> Quadrotor:
        """Use a ``torch.compile``-d integrator (fused loops; worth it for N in the thousands)."""
        from datt.compile import compile_or_eager

        self._integrate = compile_or_eager(integrate, **kwargs)
        return self


def integrate(
    pos: Tensor,
    vel: Tensor,
    quat: Tensor,
    rate: Tensor,
    thrust: Tensor,
    applied: Tensor,
    d: Tensor,
    gravity: Tensor,
    dt: float,
    k_thrust: float,
    k_rate: float,
    max_thrust: float,
    max_rate: float,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor]:
    """One step of the model in the module docstring; pure function of its inputs (compilable).

    Shapes: pos, vel, rate, d ``[N, 3]``; quat ``[N, 4]``; thrust ``[N]``; applied ``[N, 4]``.
    Returns the new (pos, vel, quat, rate, thrust).
    """
    thrust = torch.lerp(thrust, applied[:, 0], k_thrust).clamp(0.0, max_thrust)
    rate = torch.lerp(rate, applied[:, 1:], k_rate)
    rate_norm = torch.linalg.vector_norm(rate, dim=-1, keepdim=True)
    rate = rate * (max_rate / rate_norm.clamp_min(max_rate))
    acc = quat_body_z(quat) * thrust.unsqueeze(-1) + gravity + d
    pos = pos + vel * dt + acc * (0.5 * dt * dt)
    vel = vel + acc * dt
    quat = quat_normalize(quat_mul(quat, quat_exp_rotvec(rate * dt)))
    return pos, vel, quat, rate, thrust
