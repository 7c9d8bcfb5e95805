"""Whether a vehicle can follow a reference: the thrust the reference asks for against the vehicle's
thrust ceiling, and the slow-down in time that makes it fit.

A reference ``p(t)`` asks for the collective thrust (mass-normalised, m/s²) ``‖p̈(t) + g e_z‖``. A
piecewise-linear reference (the star, the zigzags) has corners where ``p̈`` is a Dirac pulse: no
vehicle follows them exactly, every tracker rounds them off over its response time. So the
acceleration is taken over a window ``w`` (``deploy.flight.thrust_window_s``, a tracker's response
time): the second difference ``(p(t + w) − 2 p(t) + p(t − w)) / w²``, which is ``p̈`` averaged
with a triangular weight over ``t ± w``. A corner where the velocity turns by ``Δv`` then asks for
``Δv / w`` at its peak; a smooth reference's own acceleration is unchanged where it varies slowly
over ``w``. The reference fits when its peak ask plus ``thrust_reserve_mps2`` (the feedback's
share, to correct errors) stays under the ceiling.

Slowing a reference by ``s`` (flying ``p(t / s)``) divides a smooth reference's acceleration by
``s²`` and a corner's by ``s``; :func:`slow_factor` searches the smallest ``s`` that fits.

Shapes: a path is ``[T, 3]`` positions (m, any fixed frame with z up) at a spacing of ``dt_s``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SLOW_STEP = 0.05  # the slow-down factors tried: 1, 1.05, 1.10, ...


@dataclass(frozen=True)
class Ask:
    """The peak thrust a path asks for (m/s²), and when (s from the path's start)."""

    peak_mps2: float
    at_s: float


def _sample(path_m: np.ndarray, t_s: np.ndarray, dt_s: float) -> np.ndarray:
    """``path_m`` at times ``t_s`` (linear interpolation; held at its first and last point)."""
    grid = np.arange(len(path_m)) * dt_s
    return np.stack([np.interp(t_s, grid, path_m[:, axis]) for axis in range(3)], axis=-1)


def thrust_asked(path_m: np.ndarray, dt_s: float, window_s: float, gravity_mps2: float) -> np.ndarray:
    """``[T]`` the collective thrust (m/s²) following ``path_m`` asks for at each of its points:
    ``‖(p(t + w) − 2 p(t) + p(t − w)) / w² + g e_z‖`` (module docstring), the path held at its ends
    (the vehicle is at rest before the start, and holds the last point)."""
    t = np.arange(len(path_m)) * dt_s
    accel = (_sample(path_m, t + window_s, dt_s) - 2.0 * path_m + _sample(path_m, t - window_s, dt_s)) / window_s**2
    accel[:, 2] += gravity_mps2
    return np.linalg.norm(accel, axis=-1)


def peak_ask(path_m: np.ndarray, dt_s: float, window_s: float, gravity_mps2: float, points: int | None = None) -> Ask:
    """The largest :func:`thrust_asked` over the path's first ``points`` points (None: all), and
    its time. The points after them still count as the path's future (a flight's reference table
    runs on past the phase that flies it: its end is not a stop)."""
    asked = thrust_asked(path_m, dt_s, window_s, gravity_mps2)[:points]
    k = int(np.argmax(asked))
    return Ask(float(asked[k]), k * dt_s)


def slowed(path_m: np.ndarray, dt_s: float, factor: float) -> np.ndarray:
    """``path_m`` flown ``factor`` times slower, on the same grid and length: point ``k`` is the
    original at ``k dt_s / factor`` (so the same duration covers ``1 / factor`` of the path)."""
    return _sample(path_m, np.arange(len(path_m)) * dt_s / factor, dt_s)


def slow_factor(
    path_m: np.ndarray,
    dt_s: float,
    window_s: float,
    gravity_mps2: float,
    limit_mps2: float,
    max_factor: float,
    points: int | None = None,
) -> float | None:
    """The smallest factor in ``1, 1 + SLOW_STEP, ...`` up to ``max_factor`` at which
    :func:`slowed` ``path_m`` asks for at most ``limit_mps2`` over its first ``points`` points;
    None if even ``max_factor`` asks for more."""
    steps = int(np.floor((max_factor - 1.0) / SLOW_STEP + 1e-9))
    for factor in [1.0 + SLOW_STEP * i for i in range(steps + 1)]:
        ask = peak_ask(slowed(path_m, dt_s, factor), dt_s, window_s, gravity_mps2, points)
        if ask.peak_mps2 <= limit_mps2:
            return factor
    return None
