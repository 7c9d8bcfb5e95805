import math

import torch

from datt.sim.frames import (
    quat_body_z,
    quat_body_z_bilinear,
    quat_exp_rotvec,
    quat_from_euler,
    quat_mul,
    quat_rotate,
    quat_rotate_inverse,
    quat_to_rotmat,
    quat_to_rotmat_bilinear,
    quat_yaw,
    wrap_angle,
)


def random_quats(n, seed=0):
    g = torch.Generator().manual_seed(seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    return q / q.norm(dim=-1, keepdim=True)


def test_rotate_matches_rotation_matrix_and_inverse():
    q = random_quats(64)
    v = torch.randn(64, 3, dtype=torch.float64)
    r = quat_to_rotmat(q)
    assert torch.allclose(quat_rotate(q, v), (r @ v.unsqueeze(-1)).squeeze(-1), atol=1e-12)
    assert torch.allclose(quat_rotate_inverse(q, quat_rotate(q, v)), v, atol=1e-12)
    assert torch.allclose(quat_body_z(q), r[..., :, 2], atol=1e-12)
    assert torch.allclose(r @ r.transpose(-1, -2), torch.eye(3, dtype=torch.float64).expand(64, 3, 3), atol=1e-12)


def test_bilinear_forms_equal_the_rotation_matrix_for_unit_quaternions():
    q = random_quats(64, seed=3)
    assert torch.allclose(quat_to_rotmat_bilinear(q), quat_to_rotmat(q), atol=1e-12)
    assert torch.allclose(quat_body_z_bilinear(q), quat_body_z(q), atol=1e-12)
    assert torch.allclose(quat_body_z_bilinear(q.float()), quat_body_z(q.float()), atol=1e-6)


def test_euler_yaw_round_trip_and_composition():
    yaw = torch.tensor([0.3, -2.0, 3.0], dtype=torch.float64)
    q = quat_from_euler(torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), yaw)
    assert torch.allclose(quat_yaw(q), yaw, atol=1e-12)
    # composing two yaw rotations adds the angles
    q2 = quat_mul(q, q)
    assert torch.allclose(quat_yaw(q2), wrap_angle(2 * yaw), atol=1e-12)


def test_exp_of_rotation_vector():
    axis = torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64)
    q = quat_exp_rotvec(axis * (math.pi / 2))
    assert torch.allclose(
        quat_rotate(q, torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)),
        torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64),
        atol=1e-12,
    )
    tiny = quat_exp_rotvec(torch.tensor([[1e-7, 0.0, 0.0]], dtype=torch.float64))
    assert torch.allclose(tiny, torch.tensor([[1.0, 5e-8, 0.0, 0.0]], dtype=torch.float64), atol=1e-15)


def test_wrap_angle_range():
    a = torch.tensor([0.0, math.pi, -math.pi, 3 * math.pi, -3.5 * math.pi, 7.0])
    w = wrap_angle(a)
    assert (w > -math.pi - 1e-6).all() and (w <= math.pi + 1e-6).all()
    assert torch.allclose(torch.sin(w), torch.sin(a), atol=1e-5) and torch.allclose(
        torch.cos(w), torch.cos(a), atol=1e-5
    )
    assert w[2].item() == torch.tensor(math.pi).item()
