"""Smooth references (paper appendix C.1): polynomials (degree 5 by default; 3 and 7 as in the
authors' code) and chained degree-5 polynomials."""

from __future__ import annotations

import math

import torch
from torch import Tensor

from datt.configuration import ACCEL_MPS2, POSITIVE_TIME_S, SPEED_MPS, Range, check_arg_ranges
from datt.errors import ConfigError
from datt.refs.base import RefFamily, planar


def quintic_zero_ends(h: Tensor) -> Tensor:
    """Linear map from boundary data to a quintic that is 0 at both ends of ``[0, h]``.

    For ``p(τ) = Σ_i c_i τ^i`` with ``p(0) = p(h) = 0``, ``p'(0) = v0``, ``p'(h) = v1``,
    ``p''(0) = a0``, ``p''(h) = a1``, returns ``K [..., 6, 4]`` with
    ``c = K @ (v0, v1, a0, a1)``. ``h [...]`` piece durations.
    """
    h = h.unsqueeze(-1).unsqueeze(-1)  # [..., 1, 1]
    one = torch.ones_like(h)
    zero = torch.zeros_like(h)
    # Conditions at τ = h on c3, c4, c5 (c0 = 0, c1 = v0, c2 = a0 / 2 are fixed).
    m = torch.cat(
        (
            torch.cat((h**3, h**4, h**5), -1),
            torch.cat((3 * h**2, 4 * h**3, 5 * h**4), -1),
            torch.cat((6 * h, 12 * h**2, 20 * h**3), -1),
        ),
        -2,
    )  # [..., 3, 3]
    # Right-hand sides minus the fixed low-order terms, as a map of (v0, v1, a0, a1).
    b = torch.cat(
        (
            torch.cat((-h, zero, -(h**2) / 2, zero), -1),
            torch.cat((-one, one, -h, zero), -1),
            torch.cat((zero, zero, -one, one), -1),
        ),
        -2,
    )  # [..., 3, 4]
    high = torch.linalg.solve(m, b)  # [..., 3, 4]
    low = torch.cat(
        (
            torch.cat((zero, zero, zero, zero), -1),
            torch.cat((one, zero, zero, zero), -1),
            torch.cat((zero, zero, one / 2, zero), -1),
        ),
        -2,
    )
    return torch.cat((low, high), -2)


def zero_ends_fit(degree: int, h: Tensor) -> Tensor:
    """Linear map from boundary derivatives to an odd-degree polynomial that is 0 at both ends of
    ``[0, h]``: for ``degree`` = 2m − 1, ``p(0) = p(h) = 0`` and derivatives 1 … m − 1 given at
    both ends, ordered ``(p'(0), p'(h), p''(0), p''(h), ...)``. Returns ``K [..., degree + 1,
    2 (m − 1)]`` with ``c = K @ derivatives`` (ascending powers). ``h [...]`` durations. The
    conditions of the authors' ``polyu.deriv_fitting_matrix``; at degree 5 the closed form
    :func:`quintic_zero_ends`, which every reference of the paper's degree was drawn with."""
    if degree == 5:
        return quintic_zero_ends(h)
    m = (degree + 1) // 2
    n = degree + 1
    powers = torch.arange(n, dtype=h.dtype, device=h.device)
    rows, picks = [], []
    for k in range(m):  # the k-th derivative of t^j is j!/(j-k)! t^(j-k)
        fall = torch.ones(n, dtype=h.dtype, device=h.device)
        for i in range(k):
            fall = fall * (powers - i)
        at_zero = torch.where(powers == k, fall, torch.zeros_like(fall)).expand(*h.shape, n)
        at_end = fall * h.unsqueeze(-1) ** (powers - k).clamp(min=0) * (powers >= k)
        rows += [at_zero, at_end]
        picks += [k > 0, k > 0]
    a = torch.stack(rows, -2)  # [..., n, n]: p, p at h, p', p' at h, ...
    select = torch.eye(n, dtype=h.dtype, device=h.device)[:, torch.tensor(picks, device=h.device)]  # [n, 2(m-1)]
    return torch.linalg.solve(a, select.expand(*h.shape, n, 2 * (m - 1)))


def eval_pieces(knot_t: Tensor, coeffs: Tensor, t_s: Tensor, derivative: int = 0) -> Tensor:
    """Evaluate piecewise polynomials.

    ``knot_t [N, M+1]`` piece boundaries, ``coeffs [N, M, C, D]`` (C coefficients in ascending
    powers of the local time: 6 for quintics), ``t_s [T]`` -> ``[N, T, D]``. Times beyond the
    last knot evaluate the last piece at its end (the references end at rest at the origin, so
    this holds position).
    """
    n, m1 = knot_t.shape
    t = t_s.to(knot_t.dtype).expand(n, -1).contiguous()
    t = torch.minimum(t, knot_t[:, -1:])
    piece = (torch.searchsorted(knot_t.contiguous(), t, right=True) - 1).clamp(0, m1 - 2)
    tau = t - knot_t.gather(1, piece)  # [N, T]
    n_coeffs, d = coeffs.shape[-2:]
    c = coeffs.gather(1, piece[..., None, None].expand(-1, -1, n_coeffs, d))  # [N, T, C, D]
    out = torch.zeros_like(c[:, :, 0])
    for i in range(n_coeffs - 1, derivative - 1, -1):  # Horner on the differentiated polynomial
        factor = math.factorial(i) // math.factorial(i - derivative)
        out = out * tau.unsqueeze(-1) + factor * c[:, :, i]
    return out


POLY_DEGREES = (3, 5, 7)


class Poly(RefFamily):
    """One polynomial of odd ``degree`` per axis (x, y) over ``duration_s`` (the 10 s episode),
    with ``p(0) = p(T) = 0`` and random end derivatives: velocities ``U(±vel_max_mps)``, and from
    degree 5 accelerations ``U(±acc_max_mps2)``, at degree 7 jerks ``U(±jerk_max_mps3)``. If a
    sample strays beyond ``max_amplitude_m`` it is scaled down to that amplitude (keeps the end
    positions at the origin). After ``duration_s`` the reference holds the origin. Mean speed
    (``traj=poly``, degree 5, 1000 draws): ≈ 0.41 m/s.

    ``degree`` 5 is the paper's (appendix C.1); the authors' ``PolyRef`` draws the same
    conditions, all ``U(±1)``, at degree 3 by default (their mixed reference) and without an
    amplitude cap (``max_amplitude_m=1000``): ``traj=poly_authors``."""

    ARG_RANGES = {
        "duration_s": POSITIVE_TIME_S,
        "degree": Range(choices=POLY_DEGREES),
        "vel_max_mps": SPEED_MPS,
        "acc_max_mps2": ACCEL_MPS2,
        "jerk_max_mps3": Range(0.0, 1000.0),  # 1000 m/s^3: beyond any quadrotor's thrust change
        "max_amplitude_m": Range(0.0, 1000.0, low_open=True),  # 1000: no rescaling
    }

    def __init__(
        self,
        duration_s: float = 10.0,
        vel_max_mps: float = 1.0,
        acc_max_mps2: float = 1.0,
        max_amplitude_m: float = 1.5,
        degree: int = 5,
        jerk_max_mps3: float = 1.0,
    ) -> None:
        check_arg_ranges(Poly, locals(), "traj")
        self.duration_s = duration_s
        self.degree = int(degree)
        self.vel_max = vel_max_mps
        self.acc_max = acc_max_mps2
        self.jerk_max = jerk_max_mps3
        self.max_amplitude_m = max_amplitude_m

    def sample_pieces(self, n: int, generator: torch.Generator, like: Tensor):
        """Knot times ``[n, 2]`` and coefficients ``[n, 1, degree + 1, 2]``."""
        bounds = (self.vel_max, self.acc_max, self.jerk_max)[: (self.degree - 1) // 2]
        # one draw per derivative, [n, end, axis], in the order velocity, acceleration, jerk
        ends = [self._uniform((n, 2, 2), -b, b, generator, like) for b in bounds]
        h = torch.full((n,), self.duration_s, dtype=like.dtype, device=like.device)
        bc = torch.cat(ends, dim=1)  # [n, 2 (m - 1), 2]: p'(0), p'(T), p''(0), ...
        coeffs = (zero_ends_fit(self.degree, h) @ bc).unsqueeze(1)  # [n, 1, degree + 1, 2]
        knot_t = torch.stack((torch.zeros_like(h), h), dim=1)
        grid = torch.linspace(0, self.duration_s, 2001, dtype=like.dtype, device=like.device)
        peak = eval_pieces(knot_t, coeffs, grid).abs().amax(dim=(1, 2))
        scale = (self.max_amplitude_m / peak.clamp_min(1e-9)).clamp(max=1.0)
        return knot_t, coeffs * scale[:, None, None, None]

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        t64 = t_s.double()  # solve and evaluate in float64; the table takes t_s's dtype
        knot_t, coeffs = self.sample_pieces(n, generator, t64)
        return planar(eval_pieces(knot_t, coeffs, t64)).to(t_s.dtype)


class ChainedPoly(RefFamily):
    """Chained degree-5 polynomials through the origin (paper appendix C.1).

    Nodes at the origin at random times (gaps ``U(piece_min_s, piece_max_s)``, shared by x and
    y); node velocities ``U(±knot_vel_max_mps)`` per axis (0 at the first node: the reference
    starts at rest, like the drone). Node accelerations solve the linear system that makes jerk
    continuous at every interior node, with zero acceleration at the first and last node, so
    the chain is C3: position, velocity and acceleration by construction, jerk by the solve.
    Mean speed (``traj=chained_poly``, 1000 draws): ≈ 0.72 m/s.
    """

    ARG_RANGES = {"piece_min_s": POSITIVE_TIME_S, "piece_max_s": POSITIVE_TIME_S, "knot_vel_max_mps": SPEED_MPS}

    def __init__(self, piece_min_s: float = 1.5, piece_max_s: float = 4.0, knot_vel_max_mps: float = 1.5) -> None:
        check_arg_ranges(ChainedPoly, locals(), "traj")
        if not piece_min_s <= piece_max_s:
            raise ConfigError(f"traj.piece_min_s/piece_max_s: need 0 < min <= max, got {piece_min_s}, {piece_max_s}")
        self.piece_min_s = piece_min_s
        self.piece_max_s = piece_max_s
        self.knot_vel_max = knot_vel_max_mps

    def sample_pieces(self, n: int, duration_s: float, generator: torch.Generator, like: Tensor):
        """Knot times ``[n, M+1]`` and coefficients ``[n, M, 6, 2]`` covering ``duration_s``."""
        m = math.ceil(duration_s / self.piece_min_s)
        h = self._uniform((n, m), self.piece_min_s, self.piece_max_s, generator, like)
        knot_t = torch.cat((torch.zeros_like(h[:, :1]), h.cumsum(1)), dim=1)
        v = self._uniform((n, m + 1, 2), -self.knot_vel_max, self.knot_vel_max, generator, like)
        v[:, 0] = 0.0
        k = quintic_zero_ends(h)  # [n, m, 6, 4]; columns act on (v_k, v_k+1, a_k, a_k+1)
        j0 = 6.0 * k[:, :, 3]  # jerk at piece start, [n, m, 4]
        hh = h.unsqueeze(-1)
        j1 = 6.0 * k[:, :, 3] + 24.0 * hh * k[:, :, 4] + 60.0 * hh**2 * k[:, :, 5]  # at piece end
        # Unknowns a_0..a_m. Row 0: a_0 = 0, row m: a_m = 0, rows 1..m-1: j1[k-1] = j0[k].
        A = torch.zeros(n, m + 1, m + 1, dtype=like.dtype, device=like.device)
        rhs = torch.zeros(n, m + 1, 2, dtype=like.dtype, device=like.device)
        A[:, 0, 0] = 1.0
        A[:, m, m] = 1.0
        rows = torch.arange(1, m, device=like.device)
        A[:, rows, rows - 1] = j1[:, rows - 1, 2]
        A[:, rows, rows] = j1[:, rows - 1, 3] - j0[:, rows, 2]
        A[:, rows, rows + 1] = -j0[:, rows, 3]
        rhs[:, rows] = (
            j0[:, rows, 0, None] * v[:, rows]
            + j0[:, rows, 1, None] * v[:, rows + 1]
            - j1[:, rows - 1, 0, None] * v[:, rows - 1]
            - j1[:, rows - 1, 1, None] * v[:, rows]
        )
        a = torch.linalg.solve(A, rhs)  # [n, m+1, 2]
        bc = torch.stack((v[:, :-1], v[:, 1:], a[:, :-1], a[:, 1:]), dim=2)  # [n, m, 4, 2]
        return knot_t, k @ bc

    def sample(self, n: int, t_s: Tensor, generator: torch.Generator) -> Tensor:
        t64 = t_s.double()
        knot_t, coeffs = self.sample_pieces(n, float(t_s[-1]), generator, t64)
        return planar(eval_pieces(knot_t, coeffs, t64)).to(t_s.dtype)
