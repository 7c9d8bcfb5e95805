"""Zigzag references (paper appendix C.2): infeasible, piecewise-linear paths."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from datt.configuration import DISTANCE_M, POSITIVE_TIME_S, Range, check_arg_ranges
from datt.errors import ConfigError
from datt.refs.base import RefFamily, piecewise_linear, planar

WAYPOINT_LAWS = ("alternating", "iid")


class Zigzag(RefFamily):
    """Random waypoints joined by straight lines, starting at the origin; timing shared by x and y.

    Segment durations are ``U(seg_min_s, seg_max_s)``. Waypoint laws (``waypoints``):

    * ``alternating`` (the authors' generator, ``refs/random_zigzag.py``): waypoint k's x and y
      are each ``U(0, range_m)`` for even k (the first waypoint is positive) and
      ``U(-range_m, 0)`` for odd k, so every segment crosses the axes.
    * ``iid`` (the paper's text): x and y ``U(-range_m, range_m)``.

    The constructor's defaults are the authors' (alternating, 0.6-1.5 s, 1 m). Mean speeds
    (time average of ‖ṗ‖ over a 10 s episode, measured in ``tests/refs/test_families.py``):
    ``traj=zigzag`` (the defaults) ≈ 1.32 m/s; ``traj=zigzag_fast`` (segments 0.4-1.0 s) ≈
    2.0 m/s, the paper's "≈ 2 m/s"; ``traj=zigzag_iid`` (iid, 0.5-1.5 s) ≈ 1.0 m/s.
    """

    ARG_RANGES = {
        "seg_min_s": POSITIVE_TIME_S,
        "seg_max_s": POSITIVE_TIME_S,
        "range_m": DISTANCE_M,
        "waypoints": Range(choices=WAYPOINT_LAWS),
    }

    def __init__(
        self,
        seg_min_s: float = 0.6,
        seg_max_s: float = 1.5,
        range_m: float = 1.0,
        waypoints: str = "alternating",
    ) -> None:
        check_arg_ranges(Zigzag, locals(), "traj")
        if not seg_min_s <= seg_max_s:
            raise ConfigError(f"traj.seg_min_s/seg_max_s: need 0 < min <= max, got {seg_min_s}, {seg_max_s}")
        self.seg_min_s = seg_min_s
        self.seg_max_s = seg_max_s
        self.range_m = range_m
        self.waypoints = waypoints

    def sample_knots(self, n: int, duration_s: float, generator: torch.Generator, like: Tensor):
        """Knot times ``[n, M]`` (first 0) and planar knots ``[n, M, 2]`` (first the origin)."""
        m = math.ceil(duration_s / self.seg_min_s) + 1  # segments; enough to cover duration
        seg = self._uniform((n, m), self.seg_min_s, self.seg_max_s, generator, like)
        knot_t = torch.cat((torch.zeros_like(seg[:, :1]), seg.cumsum(1)), dim=1)
        r = self.range_m
        if self.waypoints == "alternating":
            mag = self._uniform((n, m, 2), 0.0, r, generator, like)
            sign = 1.0 - 2.0 * (torch.arange(m, device=like.device) % 2).to(like.dtype)  # +, -, +, ...
            wp = mag * sign[None, :, None]
        else:
            wp = self._uniform((n, m, 2), -r, r, generator, like)
        knot_p = torch.cat((torch.zeros_like(wp[:, :1]), wp), dim=1)
        return knot_t, knot_p

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        knot_t, knot_p = self.sample_knots(n, float(t_s[-1]), generator, t_s)
        return planar(piecewise_linear(knot_t, knot_p, t_s))
