"""Closed polygon and star-polygon references flown at constant speed."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from datt.configuration import LENGTH_M, POSITIVE_SPEED_MPS, TIME_S, Range, check_arg_ranges
from datt.errors import ConfigError
from datt.refs.base import RefFamily, piecewise_linear, planar

POINTS = Range(3, 1000, integer=True)  # corners of one polygon


class Polygon(RefFamily):
    """Regular polygon ``{p}`` or star polygon ``{p/step}`` flown vertex to vertex, repeatedly.

    Per drone: ``p ~ U{points_min..points_max}`` vertices on a circle of ``radius_m``, visited in
    the order ``0, step, 2 step, ... (mod p)`` at a constant speed ``U(speed_min_mps, speed_max_mps)``,
    first vertex at angle ``phase_deg`` (+ a uniform random angle if ``random_rotation``).

    * ``through_origin=True``: the shape is shifted so its first vertex is the origin
      (authors' polygons); the path starts there.
    * otherwise the shape is centred on the origin and the path starts at the origin with a
      straight lead-in of ``lead_in_s`` seconds to the first vertex (authors' star).

    Defaults give the authors' polygon sizes and speeds (mean speed ≈ 1.23 m/s over 1000 draws;
    theirs are irregular, ours regular); ``conf/traj/star.yaml`` sets the authors' star: p = 5,
    step 2, r = 0.7 m, first vertex (0.7, 0), 1 m/s (≈ 0.99 m/s with the lead-in), 1 s lead-in.
    """

    ARG_RANGES = {
        "points_min": POINTS,
        "points_max": POINTS,
        "step": Range(1, 1000, integer=True),
        "radius_m": LENGTH_M,
        "speed_min_mps": POSITIVE_SPEED_MPS,
        "speed_max_mps": POSITIVE_SPEED_MPS,
        "lead_in_s": TIME_S,
        "phase_deg": Range(-360.0, 360.0),
    }

    def __init__(
        self,
        points_min: int = 3,
        points_max: int = 6,
        step: int = 1,
        radius_m: float = 0.5,
        speed_min_mps: float = 0.9,
        speed_max_mps: float = 1.6,
        through_origin: bool = True,
        lead_in_s: float = 0.0,
        phase_deg: float = 90.0,
        random_rotation: bool = True,
    ) -> None:
        check_arg_ranges(Polygon, locals(), "traj")
        if not points_min <= points_max:
            raise ConfigError(f"traj.points_min/points_max: need 3 <= min <= max, got {points_min}, {points_max}")
        if step < 1 or any(math.gcd(p, step) != 1 for p in range(points_min, points_max + 1)):
            raise ConfigError(f"traj.step: must be >= 1 and coprime with every point count, got {step}")
        if not speed_min_mps <= speed_max_mps:
            raise ConfigError(
                f"traj.speed_min_mps/speed_max_mps: need min <= max, got {speed_min_mps}, {speed_max_mps}"
            )
        self.points = (points_min, points_max)
        self.step = step
        self.radius_m = radius_m
        self.speed = (speed_min_mps, speed_max_mps)
        self.through_origin = through_origin
        self.lead_in_s = lead_in_s
        self.phase = math.radians(phase_deg)
        self.random_rotation = random_rotation

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        like = t_s.double()
        dev = like.device
        p = torch.randint(self.points[0], self.points[1] + 1, (n,), generator=generator, device=dev)
        speed = self._uniform((n,), *self.speed, generator, like)
        phase = torch.full((n,), self.phase, dtype=like.dtype, device=dev)
        if self.random_rotation:
            phase = phase + self._uniform((n,), -math.pi, math.pi, generator, like)
        pf = p.to(like.dtype)
        side_m = 2 * self.radius_m * torch.sin(math.pi * self.step / pf)  # chord between visits
        duration = float(t_s[-1])
        # Vertex visits needed to cover the duration for the slowest/shortest case.
        max_side = 2 * self.radius_m * math.sin(math.pi * self.step / self.points[1])
        min_side = min(max_side, 2 * self.radius_m * math.sin(math.pi * self.step / self.points[0]))
        k = math.ceil(duration * self.speed[1] / min_side) + 2
        visit = torch.arange(k, device=dev)
        vertex = (visit[None, :] * self.step) % p[:, None]  # [n, k]
        ang = phase[:, None] + 2 * math.pi * vertex.to(like.dtype) / pf[:, None]
        xy = self.radius_m * torch.stack((torch.cos(ang), torch.sin(ang)), -1)  # [n, k, 2]
        seg_t = (side_m / speed)[:, None].expand(n, k - 1)
        if self.through_origin:
            xy = xy - xy[:, :1]
            knot_t = torch.cat((torch.zeros_like(seg_t[:, :1]), seg_t.cumsum(1)), 1)
        else:
            xy = torch.cat((torch.zeros_like(xy[:, :1]), xy), 1)
            lead = torch.full((n, 1), max(self.lead_in_s, 1e-6), dtype=like.dtype, device=dev)
            knot_t = torch.cat((torch.zeros_like(lead), (torch.cat((lead, seg_t), 1)).cumsum(1)), 1)
        return planar(piecewise_linear(knot_t, xy, like)).to(t_s.dtype)
