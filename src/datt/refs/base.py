"""Reference trajectory families.

A family samples, for N drones, positions on a shared time grid::

    table = family.sample(n, t_s, generator)      # t_s [T] (s), table [n, T, 3] (m, world)

The env calls it at reset with ``t_s = k * dt_s`` for ``k = 0 .. episode_steps + lookahead``, so
stepping the reference is an index. References lie in the x-y plane at z = 0 unless a family
says otherwise (csv). Yaw reference is zero (paper §3.2).

New family = a subclass here (or anywhere importable) + ``conf/traj/<name>.yaml`` with
``_target_`` naming it; nothing else changes.
"""

from __future__ import annotations

import torch
from torch import Tensor


class RefFamily:
    """Base class. Subclasses implement :meth:`sample`."""

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        raise NotImplementedError

    @staticmethod
    def _uniform(shape, low: float, high: float, generator: torch.Generator, like: Tensor) -> Tensor:
        u = torch.rand(*shape, generator=generator, dtype=like.dtype, device=like.device)
        return low + (high - low) * u


def piecewise_linear(knot_t: Tensor, knot_p: Tensor, t_s: Tensor) -> Tensor:
    """Linear interpolation through knots, batched over drones.

    ``knot_t [N, M]`` increasing knot times (s), ``knot_p [N, M, D]`` knot values,
    ``t_s [T]`` query times -> ``[N, T, D]``. Queries before the first / after the last knot
    hold the end values.
    """
    n, m = knot_t.shape
    if knot_p.shape[:2] != knot_t.shape:
        shapes = f"knot times {tuple(knot_t.shape)} and values {tuple(knot_p.shape)}"
        raise ValueError(f"piecewise_linear: {shapes} disagree")
    t = t_s.to(knot_t.dtype).expand(n, -1).contiguous()
    seg = torch.searchsorted(knot_t.contiguous(), t, right=True).clamp(1, m - 1) - 1  # [N, T]
    t0 = knot_t.gather(1, seg)
    t1 = knot_t.gather(1, seg + 1)
    alpha = ((t - t0) / (t1 - t0).clamp_min(1e-9)).clamp(0.0, 1.0).unsqueeze(-1)
    d = knot_p.shape[-1]
    p0 = knot_p.gather(1, seg.unsqueeze(-1).expand(-1, -1, d))
    p1 = knot_p.gather(1, (seg + 1).unsqueeze(-1).expand(-1, -1, d))
    return p0 + alpha * (p1 - p0)


def planar(xy: Tensor) -> Tensor:
    """``[..., 2] -> [..., 3]`` with z = 0."""
    return torch.cat((xy, torch.zeros_like(xy[..., :1])), dim=-1)
