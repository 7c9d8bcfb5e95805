"""A test-only example of adding a reference family: this module plus one YAML
(``tests/examples/conf/traj/figure8.yaml``), found through ``--config-dir``; nothing in the
package changes."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from datt.refs.base import RefFamily


class Figure8(RefFamily):
    """Lemniscate of Gerono in the x-y plane through the origin: ``x = a sin(ωt)``,
    ``y = a sin(ωt) cos(ωt)``, ``ω = 2π / period_s`` (peak speed ≈ a ω)."""

    def __init__(self, amplitude_m: float = 0.8, period_s: float = 4.0) -> None:
        if not amplitude_m > 0 or not period_s > 0:
            raise ValueError(f"traj: amplitude_m and period_s must be > 0, got {amplitude_m}, {period_s}")
        self.amplitude_m, self.period_s = amplitude_m, period_s

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        phase = 2 * math.pi * t_s / self.period_s
        x = self.amplitude_m * torch.sin(phase)
        y = x * torch.cos(phase)
        return torch.stack((x, y, torch.zeros_like(x)), dim=-1).expand(n, -1, -1).clone()
