"""Zigzag references (paper appendix C.2): infeasible, piecewise-linear paths."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from datt.refs.base import RefFamily, piecewise_linear, planar


class Zigzag(RefFamily):
    """Random waypoints joined by straight lines, starting at the origin.

    Segment durations are ``U(seg_min_s, seg_max_s)`` (paper: 0.5-1.5 s; authors' code 0.6-1.5);
    each waypoint's x and y are ``U(-range_m, range_m)`` (paper: ±1 m). With
    ``alternate_sign=True`` the waypoints instead alternate between ``U(0, range_m)`` and
    ``U(-range_m, 0)`` per axis, as the authors' generator did (faster, ~1.4 m/s vs ~1 m/s mean
    speed). Timing is shared by x and y.
    """

    def __init__(
        self,
        seg_min_s: float = 0.5,
        seg_max_s: float = 1.5,
        range_m: float = 1.0,
        alternate_sign: bool = False,
    ) -> None:
        if not 0 < seg_min_s <= seg_max_s:
            raise ValueError(f"traj.seg_min_s/seg_max_s: need 0 < min <= max, got {seg_min_s}, {seg_max_s}")
        if range_m < 0:
            raise ValueError(f"traj.range_m: must be >= 0, got {range_m}")
        self.seg_min_s = seg_min_s
        self.seg_max_s = seg_max_s
        self.range_m = range_m
        self.alternate_sign = alternate_sign

    def sample_knots(self, n: int, duration_s: float, generator: torch.Generator, like: Tensor):
        """Knot times ``[n, M]`` (first 0) and planar knots ``[n, M, 2]`` (first the origin)."""
        m = math.ceil(duration_s / self.seg_min_s) + 1  # segments; enough to cover duration
        seg = self._uniform((n, m), self.seg_min_s, self.seg_max_s, generator, like)
        knot_t = torch.cat((torch.zeros_like(seg[:, :1]), seg.cumsum(1)), dim=1)
        r = self.range_m
        if self.alternate_sign:
            mag = self._uniform((n, m, 2), 0.0, r, generator, like)
            first = torch.where(self._uniform((n, 1, 2), 0, 1, generator, like) < 0.5, -1.0, 1.0)
            parity = 1.0 - 2.0 * (torch.arange(m, device=like.device) % 2).to(like.dtype)
            wp = mag * first * parity[None, :, None]
        else:
            wp = self._uniform((n, m, 2), -r, r, generator, like)
        knot_p = torch.cat((torch.zeros_like(wp[:, :1]), wp), dim=1)
        return knot_t, knot_p

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        knot_t, knot_p = self.sample_knots(n, float(t_s[-1]), generator, t_s)
        return planar(piecewise_linear(knot_t, knot_p, t_s))
