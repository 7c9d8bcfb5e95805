"""Batched quadrotor dynamics (paper eq. 1) with first-order actuator delay.

Model, per drone (all SI, world frame z-up, unit mass so thrust is an acceleration)::

    p' = v
    v' = g + R(q) e3 T + d          T: collective thrust (m/s²), d: disturbance (m/s²)
    q' = q ⊗ (0, ω) / 2             ω: body rates (rad/s)

Inputs are the commanded thrust ``T_cmd`` and body rates ``ω_cmd``. A command reaches the
actuators ``latency_steps`` steps after it is sent, then passes through the first-order delay
of paper §4.1, ``x ← x + k (x_cmd − x)`` with ``k = 0.4`` per 0.02 s step for thrust and rates.

Domain randomisation (all off by default; drawn per drone at each reset, see
:class:`QuadrotorParams`): the thrust actually produced is ``s T`` with ``s = gain / mass``
(a vehicle heavier or weaker than the controller's unit-mass model); the latency is drawn from
``latency_steps..latency_steps_max``; the rates follow the authors' second-order model
(``second_order`` below) instead of the first-order one.

Second-order rate model (the authors' ``QuadSim.step_angvel_raw``, per step)::

    τ_des = kw (ω_cmd − ω);   τ ← τ + kt (τ_des − τ);   ω ← ω + τ

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

from datt.configuration import FRACTION, GRAVITY_MPS2, POSITIVE_ACCEL_MPS2, RATE_RADPS, Range, check_ranges, ranged
from datt.sim.firmware_rates import FirmwareRateLoop
from datt.sim.frames import quat_body_z, quat_exp_rotvec, quat_mul, quat_normalize
from datt.sim.vehicles import DEFAULT_VEHICLE, VEHICLES

_DTYPES = {"float32": torch.float32, "float64": torch.float64}
RATE_MODELS = ("first_order", "second_order", "mixed", "firmware")
LATENCY_STEPS = Range(0, 100, integer=True)  # whole control steps of command delay
SPREAD = Range(0.0, 1.0, high_open=True)  # a relative half-width: U(1 - s, 1 + s) stays positive


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

    ``initial_thrust_mps2``: actuator thrust state after reset, and the thrust of the commands
    "in flight" before the first one sent (an idle actuator was commanded what it holds);
    ``None`` means hover (= g), which avoids the drop of the authors' sim that starts every
    episode at zero thrust (``0.0`` reproduces it: ``eval.protocol=authors``).

    Domain randomisation, drawn per drone at every reset (0 / ``None`` / ``first_order`` = off):
    ``mass_spread`` and ``thrust_gain_spread``: the vehicle's mass and motor gain are
    ``U(1 − s, 1 + s)`` times nominal, so the thrust produced is ``gain / mass`` times the
    actuator's; ``latency_steps_max``: the latency is uniform on ``latency_steps..latency_steps_max``
    steps; ``rate_model``: ``first_order`` (paper, ``k_rate``), ``second_order`` (the authors'
    model with ``kw_rate``, ``kt_rate``), ``mixed`` (each drone draws one of the two) or
    ``firmware`` (a stock Crazyflie's rate PIDs, mixing, motors and rigid body at 500 Hz,
    :mod:`datt.sim.firmware_rates`: ``vehicle`` (a preset of :mod:`datt.sim.vehicles`),
    ``vehicle_mass_kg`` (None: the preset's) and ``motor_time_constant_s`` are its vehicle, and
    its motors' lag replaces ``k_thrust``, ``k_rate`` and ``max_rate_radps``).

    ``command_loss_max``: each drone loses a share ``U(0, command_loss_max)`` of its commands on
    the way (a radio that drops setpoints): at a lost step the actuators keep the command they
    had, while the latency buffer (what the sender, and the training predictor, know was sent)
    keeps the one sent, as a host that cannot see which setpoints arrived.

    ``thrust_map_trimmed``: the vehicle flies behind a thrust map trimmed to it, as a deployed one
    after ``deploy.flight.hover_trim``: the commanded thrust is divided by the trim's estimate of
    ``gain / mass`` (that ratio times ``U(1 − trim_error_spread, 1 + trim_error_spread)``) before
    the actuator, so the vehicle produces the commanded thrust (up to the trim's error) and its
    mass and gain move only its ceiling (``max_thrust_mps2 · gain / mass`` in commanded units,
    :attr:`Quadrotor.command_ceiling_mps2`), where without the trim they scale every command and
    L1's d̂ carries the error.
    """

    gravity_mps2: float = ranged(9.81, GRAVITY_MPS2)
    k_thrust: float = ranged(0.4, FRACTION)
    k_rate: float = ranged(0.4, FRACTION)
    latency_steps: int = ranged(1, LATENCY_STEPS)
    initial_thrust_mps2: float | None = ranged(None, Range(0.0, 200.0, optional=True))
    max_thrust_mps2: float = ranged(40.0, POSITIVE_ACCEL_MPS2)
    max_rate_radps: float = ranged(40.0, RATE_RADPS)
    mass_spread: float = ranged(0.0, SPREAD)
    thrust_gain_spread: float = ranged(0.0, SPREAD)
    thrust_map_trimmed: bool = False
    trim_error_spread: float = ranged(0.0, SPREAD)
    latency_steps_max: int | None = ranged(None, Range(0, 100, integer=True, optional=True))
    rate_model: str = ranged("first_order", Range(choices=RATE_MODELS))
    kw_rate: float = ranged(0.4, FRACTION)
    kt_rate: float = ranged(0.6, FRACTION)
    vehicle: str = ranged(DEFAULT_VEHICLE, Range(choices=tuple(VEHICLES)))  # firmware rate model: the preset
    vehicle_mass_kg: float | None = ranged(None, Range(0.005, 5.0, optional=True))  # None: the preset's
    motor_time_constant_s: float = ranged(0.03, Range(0.0, 1.0))
    # below one half: a radio that loses every other setpoint is not one to fly with
    command_loss_max: float = ranged(0.0, Range(0.0, 0.5))

    @property
    def max_latency_steps(self) -> int:
        return self.latency_steps if self.latency_steps_max is None else int(self.latency_steps_max)

    def validate(self, prefix: str = "env.quad") -> None:
        """Rules across fields (each field's own range is declared with it, :func:`ranged`)."""
        from datt.errors import ConfigError

        check_ranges(self, prefix)
        top = self.latency_steps_max
        if top is not None and top < self.latency_steps:
            raise ConfigError(
                f"{prefix}.latency_steps_max: must be null or an integer >= latency_steps "
                f"({self.latency_steps}), got {top!r}"
            )


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
    """Transport delay of batched commands ``[N, *shape]``: ``steps`` control steps for every
    drone, or a per-drone delay (``set_delay``) of up to ``max_steps``.

    ``push(cmd)`` stores the command sent now and returns, per drone, the one sent ``delay``
    steps ago (0: the command itself). Slots start at ``fill``; ``reset(idx)`` refills drones."""

    def __init__(self, steps: int, fill: Tensor, n: int, max_steps: int | None = None) -> None:
        self.steps = int(steps)
        self.max_steps = self.steps if max_steps is None else int(max_steps)
        self.fill = fill
        # ring of the last max_steps + 1 commands sent; slot `_head` is written next
        self._ring = fill.expand(self.max_steps + 1, n, *fill.shape).clone()
        self._head = 0
        self._rows = torch.arange(n, device=fill.device)
        self.delay: Tensor | None = None  # [N] long, per-drone steps; None = `steps` for all

    def set_delay(self, idx: Tensor, steps: Tensor) -> None:
        """Per-drone delays ``steps [k]`` (each in 0..max_steps) for drones ``idx [k]``."""
        if self.delay is None:
            self.delay = torch.full_like(self._rows, self.steps)
        self.delay[idx] = steps.to(self.delay.dtype)

    def push(self, cmd: Tensor) -> Tensor:
        size = self.max_steps + 1
        if size == 1:
            return cmd
        self._ring[self._head] = cmd
        if self.delay is None:
            applied = self._ring[(self._head - self.steps) % size].clone()
        else:
            applied = self._ring[(self._head - self.delay) % size, self._rows]
        self._head = (self._head + 1) % size
        return applied

    def in_flight(self) -> Tensor:
        """The last ``steps`` commands sent (those not yet applied at the nominal delay), oldest
        first: ``[steps, N, *shape]``."""
        size = self.max_steps + 1
        order = (self._head - self.steps + torch.arange(self.steps, device=self._ring.device)) % size
        return self._ring.index_select(0, order)

    def delays(self) -> Tensor:
        """Each drone's delay in steps, ``[N]`` long (``steps`` for all until ``set_delay``)."""
        return self.delay if self.delay is not None else torch.full_like(self._rows, self.steps)

    def pending(self, assumed: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The commands the next steps will apply before the last one sent reaches the
        actuators: for a drone with delay d, the d − 1 commands sent before the last, oldest
        first, and the one acting now (the last applied). Returns ``(commands [S, N, *shape],
        active [S, N], acting [N, *shape])`` with S = ``max_steps − 1`` (at least 0);
        ``active[j, n]`` is False where drone n has fewer than j + 1 such commands.
        ``assumed [N]`` (each in 1..max_steps): what a predictor that takes the delay to be these
        would list instead (a longer one lists commands that already acted, a shorter one misses
        some)."""
        size = self.max_steps + 1
        count = max(self.max_steps - 1, 0)
        if assumed is None:
            assumed = self.delays()
        j = torch.arange(count, device=self._ring.device).unsqueeze(1)  # [S, 1]
        slots = (self._head - assumed.unsqueeze(0) + j) % size  # [S, N]: the one applied j steps on
        commands = self._ring[slots, self._rows.unsqueeze(0)]
        acting = self._ring[(self._head - 1 - assumed) % size, self._rows]
        return commands, j < (assumed.unsqueeze(0) - 1), acting

    def reset(self, idx: Tensor) -> None:
        self._ring[:, idx] = self.fill

    def fill_all(self, value: Tensor | float) -> None:
        self._ring[:] = value


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
        self.initial_thrust = p.gravity_mps2 if p.initial_thrust_mps2 is None else p.initial_thrust_mps2
        # what the actuators are taken to have been commanded before the first command of an episode
        self.idle_cmd = torch.tensor([self.initial_thrust, 0.0, 0.0, 0.0], **kw)
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
        self.latency = CommandLatency(p.latency_steps, self.idle_cmd, n, p.max_latency_steps)
        self.last_applied_cmd = self.idle_cmd.expand(n, 4).clone()
        self._integrate = integrate
        self._init_variations(kw)

    def _init_variations(self, kw: dict) -> None:
        """The per-drone state of the domain randomisation, the radio's losses and the rate model
        (None = nominal for every drone; see :class:`QuadrotorParams`)."""
        p, n = self.params, self.n
        self.thrust_scale: Tensor | None = None  # [N] thrust produced per unit of actuator thrust
        self.second_order: Tensor | None = None  # [N] bool: drone follows the second-order rate model
        self.rate_torque: Tensor | None = None  # [N, 3] second-order model's rate increment per step
        if p.mass_spread or p.thrust_gain_spread:
            self.thrust_scale = torch.ones(n, **kw)
        # [N] thrust_map_trimmed: the trimmed map's gain / mass, which divides the commanded thrust
        self.map_scale: Tensor | None = None
        if p.thrust_map_trimmed and (self.thrust_scale is not None or p.trim_error_spread):
            self.map_scale = torch.ones(n, **kw)
        # [N] command_loss_max: each drone's chance of losing a command; the generator its losses draw from
        self.command_loss: Tensor | None = torch.zeros(n, **kw) if p.command_loss_max > 0 else None
        self._loss_generator: torch.Generator | None = None
        self.motor_gain: Tensor | None = None  # [N] firmware rate model: motor force / nominal
        self.firmware: FirmwareRateLoop | None = None
        if p.rate_model == "firmware":
            preset = VEHICLES[p.vehicle]
            mass_kg = preset.mass_kg if p.vehicle_mass_kg is None else p.vehicle_mass_kg
            self.firmware = FirmwareRateLoop(
                n, self.dt_s, mass_kg, p.motor_time_constant_s, self.initial_thrust, self.device, self.dtype, preset
            )
            if self.thrust_scale is not None:
                self.motor_gain = torch.ones(n, **kw)
        elif p.rate_model != "first_order":
            self.second_order = torch.full((n,), p.rate_model == "second_order", device=self.device)
            self.rate_torque = torch.zeros(n, 3, **kw)

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
        # a copy: with no latency the last applied command is the caller's own tensor
        self.last_applied_cmd = self.last_applied_cmd.clone()
        self.last_applied_cmd[idx] = self.idle_cmd
        if self.rate_torque is not None:
            self.rate_torque[idx] = 0.0
        if self.firmware is not None:
            self.firmware.reset(idx, self.initial_thrust)

    def randomise(self, idx: Tensor, generator: torch.Generator) -> None:
        """Draw the domain-randomised parameters of drones ``idx`` (see :class:`QuadrotorParams`).
        Draws nothing (the generator's stream is untouched) when randomisation is off."""
        p, k = self.params, len(idx)
        kw = {"device": self.device, "generator": generator}

        def spread(s: float) -> Tensor:
            return 1.0 + s * (2.0 * torch.rand(k, dtype=self.dtype, **kw) - 1.0)

        if self.thrust_scale is not None:
            gain = spread(p.thrust_gain_spread)
            self.thrust_scale[idx] = gain / spread(p.mass_spread)
            if self.motor_gain is not None:
                self.motor_gain[idx] = gain
        if self.map_scale is not None:
            true_scale = self.thrust_scale[idx] if self.thrust_scale is not None else 1.0
            self.map_scale[idx] = true_scale * spread(p.trim_error_spread)
        if p.max_latency_steps != p.latency_steps:
            self.latency.set_delay(idx, torch.randint(p.latency_steps, p.max_latency_steps + 1, (k,), **kw))
        if p.rate_model == "mixed":
            self.second_order[idx] = torch.rand(k, **kw) < 0.5
        if self.command_loss is not None:
            self.command_loss[idx] = p.command_loss_max * torch.rand(k, dtype=self.dtype, **kw)
            self._loss_generator = generator

    @property
    def command_ceiling_mps2(self) -> Tensor | None:
        """``[N]``: with ``thrust_map_trimmed``, the most thrust each drone's map commands (its
        actuator's ``max_thrust_mps2`` in commanded units); None otherwise (``max_thrust_mps2``)."""
        return None if self.map_scale is None else self.params.max_thrust_mps2 * self.map_scale

    def step(self, cmd: Tensor, disturbance_mps2: Tensor | None = None) -> QuadState:
        """Advance all drones by ``dt_s``.

        ``cmd [N, 4]`` = (thrust_mps2, wx, wy, wz) commanded now; ``disturbance_mps2 [N, 3]``
        world-frame acceleration acting during this step. Updates and returns ``self.state``.
        """
        p = self.params
        applied = self.latency.push(cmd)
        if self.command_loss is not None:  # a lost command: the actuators keep the one they had
            draw = torch.rand(self.n, device=self.device, dtype=self.dtype, generator=self._loss_generator)
            applied = torch.where((draw < self.command_loss).unsqueeze(-1), self.last_applied_cmd, applied)
        self.last_applied_cmd = applied
        if self.map_scale is not None:  # the trimmed map: the actuator's thrust for the one commanded
            applied = torch.cat((applied[:, :1] / self.map_scale.unsqueeze(-1), applied[:, 1:]), dim=-1)
        if disturbance_mps2 is None:
            disturbance_mps2 = torch.zeros_like(self.state.pos_m)
        s = self.state
        if self.firmware is not None:
            s.pos_m, s.vel_mps, s.quat, s.rate_radps, s.thrust_mps2 = self.firmware.step(
                s.pos_m,
                s.vel_mps,
                s.quat,
                s.rate_radps,
                applied,
                disturbance_mps2,
                self.gravity,
                p.max_thrust_mps2,
                self.motor_gain,
                self.thrust_scale,
            )
            return s
        s.pos_m, s.vel_mps, s.quat, s.rate_radps, s.thrust_mps2, torque = self._integrate(
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
            self.thrust_scale,
            self.rate_torque,
            self.second_order,
            p.kw_rate,
            p.kt_rate,
        )
        if torque is not None:
            self.rate_torque = torque
        return s

    def compile(self, **kwargs) -> Quadrotor:
        """Use a ``torch.compile``-d integrator (fused loops; worth it for N in the thousands)."""
        from datt.compile import compile_or_eager

        self._integrate = compile_or_eager(integrate, **kwargs)
        if self.firmware is not None:
            self.firmware.compile(**kwargs)
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
    thrust_scale: Tensor | None = None,
    rate_torque: Tensor | None = None,
    second_order: Tensor | None = None,
    kw: float = 0.4,
    kt: float = 0.6,
) -> tuple[Tensor, Tensor, Tensor, Tensor, Tensor, Tensor | None]:
    """One step of the model in the module docstring; pure function of its inputs (compilable).

    Shapes: pos, vel, rate, d ``[N, 3]``; quat ``[N, 4]``; thrust ``[N]``; applied ``[N, 4]``.
    Optional (domain randomisation): ``thrust_scale [N]`` (produced / actuator thrust),
    ``rate_torque [N, 3]`` with ``second_order [N]`` (bool: which drones follow the
    second-order rate model with ``kw``, ``kt``). Returns the new (pos, vel, quat, rate, thrust,
    rate_torque).
    """
    thrust = torch.lerp(thrust, applied[:, 0], k_thrust).clamp(0.0, max_thrust)
    rate_cmd = applied[:, 1:]
    first = torch.lerp(rate, rate_cmd, k_rate)
    if rate_torque is not None and second_order is not None:
        rate_torque = torch.lerp(rate_torque, kw * (rate_cmd - rate), kt)
        rate = torch.where(second_order.unsqueeze(-1), rate + rate_torque, first)
    else:
        rate = first
    rate_norm = torch.linalg.vector_norm(rate, dim=-1, keepdim=True)
    rate = rate * (max_rate / rate_norm.clamp_min(max_rate))
    produced = thrust if thrust_scale is None else thrust * thrust_scale
    acc = quat_body_z(quat) * produced.unsqueeze(-1) + gravity + d
    pos = pos + vel * dt + acc * (0.5 * dt * dt)
    vel = vel + acc * dt
    quat = quat_normalize(quat_mul(quat, quat_exp_rotvec(rate * dt)))
    return pos, vel, quat, rate, thrust, rate_torque
