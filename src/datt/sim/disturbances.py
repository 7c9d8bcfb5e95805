"""Disturbance models: a world-frame acceleration ``d [N, 3]`` (m/s²) added to paper eq. 1.

Every model follows one protocol, driven by the env:

* ``bind(n, dt_s, generator, device, dtype)`` once, to size buffers;
* ``reset(idx, state)`` when drones ``idx`` start an episode (draws per-episode parameters);
* ``update(state)`` after every sim step (advances internal processes by ``dt_s``).

Both refresh ``self.current_mps2``: the disturbance that acts during the *next* sim step,
which is also what a privileged policy observes as ``d``. State-dependent models (``wind``,
``plate``) evaluate at the state they are given (``QuadState``).

Each model is a Hydra option under ``conf/disturbance/`` (``_target_`` = the class).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import torch
from torch import Tensor

from datt.configuration import ACCEL_MPS2, POSITIVE_TIME_S, Range, check_arg_ranges
from datt.errors import ConfigError
from datt.sim.frames import quat_body_z, quat_rotate, quat_rotate_inverse
from datt.sim.quadrotor import QuadState


class Disturbance:
    """Base class: zero disturbance (the ``none`` option)."""

    n: int
    current_mps2: Tensor

    def bind(self, n: int, dt_s: float, generator: torch.Generator, device, dtype) -> None:
        self.n = n
        self.dt_s = dt_s
        self.generator = generator
        self.device = torch.device(device)
        self.dtype = dtype
        self.current_mps2 = torch.zeros(n, 3, device=self.device, dtype=dtype)
        self._bind_buffers()

    def _bind_buffers(self) -> None:
        """Allocate per-drone buffers; ``self.n`` etc. are set."""

    def reset(self, idx: Tensor, state: QuadState) -> None:
        self.current_mps2[idx] = 0.0

    def update(self, state: QuadState) -> Tensor:
        return self.current_mps2

    # -- helpers -------------------------------------------------------------------------
    def _uniform(self, shape: Sequence[int], low: float, high: float) -> Tensor:
        u = torch.rand(*shape, generator=self.generator, device=self.device, dtype=self.dtype)
        return low + (high - low) * u

    def _randn(self, *shape: int) -> Tensor:
        return torch.randn(*shape, generator=self.generator, device=self.device, dtype=self.dtype)


NoDisturbance = Disturbance


class ConstantForce(Disturbance):
    """Per-episode constant vector, each axis uniform in ``[-max_mps2, max_mps2]`` (paper: 3.5)."""

    ARG_RANGES = {"max_mps2": ACCEL_MPS2}

    def __init__(self, max_mps2: float = 3.5) -> None:
        check_arg_ranges(ConstantForce, locals(), "disturbance")
        self.max_mps2 = float(max_mps2)

    def reset(self, idx: Tensor, state: QuadState) -> None:
        self.current_mps2[idx] = self._uniform((len(idx), 3), -self.max_mps2, self.max_mps2)


class Brownian(ConstantForce):
    """Paper §4.1: random initial vector (as ``constant``), then ``d += ε, ε ~ N(0, Σ dt)``
    every step with ``Σ = sigma2 I`` (paper: 0.01, units m²/s⁵ so that d's variance grows by
    ``sigma2`` per second)."""

    ARG_RANGES = {"sigma2": Range(0.0, 1000.0)}  # m²/s⁵: 1000 drifts 30 m/s² in a second

    def __init__(self, max_mps2: float = 3.5, sigma2: float = 0.01) -> None:
        super().__init__(max_mps2)
        check_arg_ranges(Brownian, locals(), "disturbance")
        self.sigma2 = float(sigma2)

    def update(self, state: QuadState) -> Tensor:
        std = math.sqrt(self.sigma2 * self.dt_s)
        self.current_mps2.add_(self._randn(self.n, 3), alpha=std)
        return self.current_mps2


class Wind(Disturbance):
    """Spatial wind field with gusts, acting through quadratic drag on the air-relative velocity.

    Wind velocity at position p (world, m/s)::

        w(p, t) = w_mean + amp * Σ_j u_j sin(κ_j · p + φ_j) + g(t)

    * ``w_mean``: horizontal, random direction, speed ``U(speed_min_mps, speed_max_mps)``
      per episode (the paper's fan produced roughly 2-4 m/s at the drone);
    * spatial variation: ``num_modes`` random Fourier modes with wavelength
      ``U(wavelength_min_m, wavelength_max_m)``, random unit directions ``u_j``, and amplitude
      ``spatial_amp`` × the mean speed, so the drone meets stronger and weaker air as it moves;
    * gusts ``g(t)``: per-axis Ornstein-Uhlenbeck process with time constant ``gust_tau_s`` and
      stationary std ``gust_std_mps`` (vertical gusts scaled by ``gust_vertical_ratio``).

    Acceleration: ``d = drag_coef * ‖w − v‖ (w − v)``, with ``drag_coef`` in 1/m (drag force
    per unit mass per (m/s)²). At 3 m/s relative speed the default 0.25 gives 2.25 m/s².
    """

    ARG_RANGES = {
        "speed_min_mps": Range(0.0, 50.0),  # a gale
        "speed_max_mps": Range(0.0, 50.0),
        "drag_coef_per_m": Range(0.0, 100.0),
        "num_modes": Range(0, 100, integer=True),
        "spatial_amp": Range(0.0, 10.0),
        "wavelength_min_m": Range(0.0, 1000.0, low_open=True),
        "wavelength_max_m": Range(0.0, 1000.0, low_open=True),
        "gust_std_mps": Range(0.0, 50.0),
        "gust_tau_s": POSITIVE_TIME_S,
        "gust_vertical_ratio": Range(0.0, 10.0),
    }

    def __init__(
        self,
        speed_min_mps: float = 1.5,
        speed_max_mps: float = 3.5,
        drag_coef_per_m: float = 0.25,
        num_modes: int = 3,
        spatial_amp: float = 0.3,
        wavelength_min_m: float = 1.5,
        wavelength_max_m: float = 4.0,
        gust_std_mps: float = 0.5,
        gust_tau_s: float = 0.5,
        gust_vertical_ratio: float = 0.3,
    ) -> None:
        check_arg_ranges(Wind, locals(), "disturbance")
        if not speed_min_mps <= speed_max_mps:
            raise ConfigError("disturbance.speed_min_mps/speed_max_mps: need 0 <= min <= max")
        if not wavelength_min_m <= wavelength_max_m:
            raise ConfigError("disturbance.wavelength_min_m/wavelength_max_m: need 0 < min <= max")
        self.speed_min_mps = speed_min_mps
        self.speed_max_mps = speed_max_mps
        self.drag_coef = drag_coef_per_m
        self.num_modes = num_modes
        self.spatial_amp = spatial_amp
        self.wavelength_range = (wavelength_min_m, wavelength_max_m)
        self.gust_std = gust_std_mps
        self.gust_tau = gust_tau_s
        self.gust_vertical_ratio = gust_vertical_ratio

    def _bind_buffers(self) -> None:
        kw = {"device": self.device, "dtype": self.dtype}
        m = self.num_modes
        self.w_mean = torch.zeros(self.n, 3, **kw)
        self.mode_k = torch.zeros(self.n, m, 3, **kw)
        self.mode_dir = torch.zeros(self.n, m, 3, **kw)
        self.mode_phase = torch.zeros(self.n, m, **kw)
        self.gust = torch.zeros(self.n, 3, **kw)
        self.gust_axis_scale = torch.tensor([1.0, 1.0, self.gust_vertical_ratio], **kw)

    def _unit(self, *shape: int) -> Tensor:
        v = self._randn(*shape, 3)
        return v / torch.linalg.vector_norm(v, dim=-1, keepdim=True).clamp_min(1e-9)

    def reset(self, idx: Tensor, state: QuadState) -> None:
        k = len(idx)
        heading = self._uniform((k,), -math.pi, math.pi)
        speed = self._uniform((k,), self.speed_min_mps, self.speed_max_mps)
        self.w_mean[idx] = torch.stack(
            (speed * torch.cos(heading), speed * torch.sin(heading), torch.zeros_like(speed)), -1
        )
        if self.num_modes:
            m = self.num_modes
            wavelength = self._uniform((k, m, 1), *self.wavelength_range)
            self.mode_k[idx] = self._unit(k, m) * (2 * math.pi / wavelength)
            self.mode_dir[idx] = self._unit(k, m) * (self.spatial_amp * speed)[:, None, None]
            self.mode_phase[idx] = self._uniform((k, m), -math.pi, math.pi)
        self.gust[idx] = self._randn(k, 3) * self.gust_std * self.gust_axis_scale
        self.current_mps2[idx] = self._accel(state)[idx]

    def wind_mps(self, pos_m: Tensor) -> Tensor:
        """Wind velocity at ``pos_m [N, 3]`` (world)."""
        w = self.w_mean + self.gust
        if self.num_modes:
            phase = (self.mode_k * pos_m[:, None, :]).sum(-1) + self.mode_phase
            w = w + (self.mode_dir * torch.sin(phase)[..., None]).sum(1)
        return w

    def _accel(self, state: QuadState) -> Tensor:
        rel = self.wind_mps(state.pos_m) - state.vel_mps
        return self.drag_coef * torch.linalg.vector_norm(rel, dim=-1, keepdim=True) * rel

    def update(self, state: QuadState) -> Tensor:
        # Exact OU discretisation keeps the stationary std independent of dt.
        a = math.exp(-self.dt_s / self.gust_tau)
        noise = self._randn(self.n, 3) * (self.gust_std * math.sqrt(1 - a * a)) * self.gust_axis_scale
        self.gust.mul_(a).add_(noise)
        self.current_mps2 = self._accel(state)
        return self.current_mps2


class DragPlate(Disturbance):
    """A plate hanging under the drone (paper §5.3, studied zero-shot): extra mass plus
    anisotropic quadratic drag.

    With nominal mass m, plate mass ``mass_ratio * m`` and the body-frame air-relative
    velocity ``u = R^T (w − v)`` (``w`` = 0 unless ``wind`` is given), the true acceleration is
    ``g + (R e3 T + R (c ⊙ |u| ⊙ u)) / (1 + mass_ratio)``, so relative to the nominal model::

        d = R e3 T (1/(1+r) − 1) + R (c ⊙ |u| ⊙ u) / (1 + r)

    ``drag_coef_body_per_m`` = c (1/m, per unit nominal mass) along body x, y, z: the default
    plate faces body x (a vertical plate), so drag is largest along x.
    """

    ARG_RANGES = {"mass_ratio": Range(0.0, 10.0), "drag_coef_body_per_m": Range(0.0, 100.0, length=3)}  # body x, y, z

    def __init__(
        self,
        mass_ratio: float = 0.15,
        drag_coef_body_per_m: Sequence[float] = (0.6, 0.1, 0.2),
        wind: Wind | None = None,
    ) -> None:
        check_arg_ranges(DragPlate, locals(), "disturbance")
        self.mass_ratio = float(mass_ratio)
        self.drag_coef = tuple(float(c) for c in drag_coef_body_per_m)
        self.wind = wind

    def bind(self, n, dt_s, generator, device, dtype) -> None:
        super().bind(n, dt_s, generator, device, dtype)
        self.coef = torch.tensor(self.drag_coef, device=self.device, dtype=dtype)
        if self.wind is not None:
            self.wind.bind(n, dt_s, generator, device, dtype)

    def _accel(self, state: QuadState) -> Tensor:
        air = -state.vel_mps if self.wind is None else self.wind.wind_mps(state.pos_m) - state.vel_mps
        u = quat_rotate_inverse(state.quat, air)
        drag_world = quat_rotate(state.quat, self.coef * u.abs() * u)
        thrust = quat_body_z(state.quat) * state.thrust_mps2.unsqueeze(-1)
        scale = 1.0 / (1.0 + self.mass_ratio)
        return thrust * (scale - 1.0) + drag_world * scale

    def reset(self, idx: Tensor, state: QuadState) -> None:
        if self.wind is not None:
            self.wind.reset(idx, state)
        self.current_mps2[idx] = self._accel(state)[idx]

    def update(self, state: QuadState) -> Tensor:
        if self.wind is not None:
            self.wind.update(state)
        self.current_mps2 = self._accel(state)
        return self.current_mps2
