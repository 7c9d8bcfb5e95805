"""Quaternion and frame helpers.

Convention: quaternions are scalar-first ``(w, x, y, z)`` and rotate body-frame
vectors into the world frame (``v_world = R(q) v_body``). World frame is z-up.
All functions broadcast over leading dimensions (``[..., 4]`` / ``[..., 3]``).
"""

from __future__ import annotations

import math

import torch
from torch import Tensor


def _cross(a: Tensor, b: Tensor) -> Tensor:
    # Explicit components: faster than torch.linalg.cross for small trailing dims
    # and broadcasts without the dim-size checks.
    ax, ay, az = a.unbind(-1)
    bx, by, bz = b.unbind(-1)
    return torch.stack((ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx), dim=-1)


def quat_rotate(q: Tensor, v: Tensor) -> Tensor:
    """Body -> world: ``R(q) v``. ``q [..., 4]``, ``v [..., 3]``."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v + w * t + _cross(u, t)


def quat_rotate_inverse(q: Tensor, v: Tensor) -> Tensor:
    """World -> body: ``R(q)^T v``. ``q [..., 4]``, ``v [..., 3]``."""
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * _cross(u, v)
    return v - w * t + _cross(u, t)


def quat_mul(a: Tensor, b: Tensor) -> Tensor:
    """Hamilton product ``a ⊗ b`` (apply ``b`` first, then ``a``)."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        dim=-1,
    )


def quat_exp_rotvec(rotvec: Tensor) -> Tensor:
    """Unit quaternion of the rotation vector ``rotvec`` (axis * angle, rad), ``[..., 3] -> [..., 4]``.

    Exact exponential map; uses the Taylor series of ``sin(θ/2)/θ`` near zero so the
    result is smooth and finite for tiny rotations.
    """
    angle = torch.linalg.vector_norm(rotvec, dim=-1, keepdim=True)
    half = 0.5 * angle
    small = angle < 1e-4
    # sin(θ/2)/θ ≈ 1/2 - θ²/48 for small θ
    safe = torch.where(small, torch.ones_like(angle), angle)
    scale = torch.where(small, 0.5 - angle * angle / 48.0, torch.sin(half) / safe)
    return torch.cat((torch.cos(half), rotvec * scale), dim=-1)


def quat_normalize(q: Tensor) -> Tensor:
    return q / torch.linalg.vector_norm(q, dim=-1, keepdim=True)


def quat_body_z(q: Tensor) -> Tensor:
    """Thrust axis ``R(q) e3`` in the world frame, ``[..., 4] -> [..., 3]``."""
    w, x, y, z = q.unbind(-1)
    return torch.stack((2.0 * (x * z + w * y), 2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y)), dim=-1)


def quat_to_rotmat(q: Tensor) -> Tensor:
    """Rotation matrix ``R(q)`` (body -> world), ``[..., 4] -> [..., 3, 3]``."""
    w, x, y, z = q.unbind(-1)
    row0 = torch.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1)
    row1 = torch.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1)
    row2 = torch.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1)
    return torch.stack((row0, row1, row2), dim=-2)


def _rotmat_quadratic_form() -> Tensor:  # pragma: no mutate block (runs at import: see docs/mutation.md)
    # R(q) of a unit quaternion is a quadratic form in q: R.flatten() = (q q^T).flatten() @ C.
    C = torch.zeros(4, 4, 9, dtype=torch.float64)
    w, x, y, z = range(4)
    terms = {
        0: [(1, w, w), (1, x, x), (-1, y, y), (-1, z, z)],
        1: [(2, x, y), (-2, w, z)],
        2: [(2, x, z), (2, w, y)],
        3: [(2, x, y), (2, w, z)],
        4: [(1, w, w), (-1, x, x), (1, y, y), (-1, z, z)],
        5: [(2, y, z), (-2, w, x)],
        6: [(2, x, z), (-2, w, y)],
        7: [(2, y, z), (2, w, x)],
        8: [(1, w, w), (-1, x, x), (-1, y, y), (1, z, z)],
    }
    for entry, products in terms.items():
        for coeff, a, b in products:
            C[a, b, entry] += coeff
    return C.reshape(16, 9)


ROTMAT_QUADRATIC_FORM = _rotmat_quadratic_form()
BODY_Z_QUADRATIC_FORM = ROTMAT_QUADRATIC_FORM[:, 2::3].contiguous()  # third column of R: R e3


def quat_to_rotmat_bilinear(q: Tensor, form: Tensor | None = None) -> Tensor:
    """``R(q)`` for unit quaternions ``[N, 4] -> [N, 3, 3]`` in three tensor ops (outer product,
    one matmul, reshape), for batch-1 inference where per-op dispatch dominates; equals
    :func:`quat_to_rotmat` for unit ``q``. ``form``: ``ROTMAT_QUADRATIC_FORM`` in ``q``'s dtype."""
    form = ROTMAT_QUADRATIC_FORM.to(q) if form is None else form
    n = q.shape[0]
    return ((q.unsqueeze(-1) * q.unsqueeze(-2)).reshape(n, 16) @ form).reshape(n, 3, 3)


def quat_body_z_bilinear(q: Tensor, form: Tensor | None = None) -> Tensor:
    """:func:`quat_body_z` (the third column of ``R(q)``) for unit quaternions ``[N, 4] -> [N, 3]``
    as one bilinear form: three tensor ops instead of fourteen. ``form``:
    ``BODY_Z_QUADRATIC_FORM`` in ``q``'s dtype (callers in a loop keep one)."""
    form = BODY_Z_QUADRATIC_FORM.to(q) if form is None else form
    return (q.unsqueeze(-1) * q.unsqueeze(-2)).reshape(q.shape[0], 16) @ form


def quat_from_euler(roll: Tensor, pitch: Tensor, yaw: Tensor) -> Tensor:
    """ZYX (yaw, then pitch, then roll) Euler angles in rad -> quaternion ``[..., 4]``."""
    cr, sr = torch.cos(roll / 2), torch.sin(roll / 2)
    cp, sp = torch.cos(pitch / 2), torch.sin(pitch / 2)
    cy, sy = torch.cos(yaw / 2), torch.sin(yaw / 2)
    return torch.stack(
        (
            cr * cp * cy + sr * sp * sy,
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
        ),
        dim=-1,
    )


def quat_yaw(q: Tensor) -> Tensor:
    """Yaw angle (rad, ZYX convention) in (-π, π], ``[..., 4] -> [...]``."""
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def wrap_angle(angle: Tensor) -> Tensor:
    """Wrap to (-π, π]."""
    return angle - 2.0 * math.pi * torch.ceil((angle - math.pi) / (2.0 * math.pi))


def body_z_floats(q: list[float]) -> list[float]:
    """:func:`quat_body_z` of one quaternion on plain floats (w, x, y, z), for per-tick loops where a
    tensor op costs more than the math (the simulated vehicle's stabilizer, the off-board predictor)."""
    w, x, y, z = q
    return [2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)]


def world_up_floats(q: list[float]) -> list[float]:
    """World z expressed in the body frame of one quaternion (w, x, y, z, body to world) on plain
    floats: ``quat_rotate_inverse(q, e_z)``, the third row of the rotation (:func:`body_z_floats`
    is its third column)."""
    w, x, y, z = q
    return [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]


def quat_turned_floats(q: list[float], rotvec: list[float]) -> list[float]:
    """``q`` (w, x, y, z, body to world) turned by the body-frame rotation vector ``rotvec`` (rad):
    ``quat_normalize(quat_mul(q, quat_exp_rotvec(rotvec)))`` on plain floats (the same series near 0)."""
    angle = math.sqrt(sum(r * r for r in rotvec))
    scale = 0.5 - angle * angle / 48.0 if angle < 1e-4 else math.sin(0.5 * angle) / angle
    dw, dx, dy, dz = math.cos(0.5 * angle), rotvec[0] * scale, rotvec[1] * scale, rotvec[2] * scale
    w, x, y, z = q
    out = [
        w * dw - x * dx - y * dy - z * dz,
        w * dx + x * dw + y * dz - z * dy,
        w * dy - x * dz + y * dw + z * dx,
        w * dz + x * dy - y * dx + z * dw,
    ]
    norm = math.sqrt(sum(c * c for c in out))
    return [c / norm for c in out]
