import math

import torch

from datt.sim.frames import (
    BODY_Z_QUADRATIC_FORM,
    ROTMAT_QUADRATIC_FORM,
    quat_body_z,
    quat_body_z_bilinear,
    quat_exp_rotvec,
    quat_from_euler,
    quat_mul,
    quat_normalize,
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
    assert torch.allclose(quat_to_rotmat_bilinear(q.float()), quat_to_rotmat(q.float()), atol=1e-6)
    # a caller's own form (kept across a control loop) is the one used
    form = ROTMAT_QUADRATIC_FORM.to(q)
    assert torch.allclose(quat_to_rotmat_bilinear(q, 2 * form), 2 * quat_to_rotmat(q), atol=1e-12)
    assert torch.allclose(quat_body_z_bilinear(q, 2 * BODY_Z_QUADRATIC_FORM.to(q)), 2 * quat_body_z(q), atol=1e-12)


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


def test_quat_mul_is_the_hamilton_product():
    """The unit table (i² = j² = k² = ijk = −1) and, for random unit quaternions, R(a ⊗ b) = R(a) R(b)."""
    one, i, j, k = torch.eye(4, dtype=torch.float64)
    table = {
        (i, i): -one, (j, j): -one, (k, k): -one,
        (i, j): k, (j, k): i, (k, i): j,
        (j, i): -k, (k, j): -i, (i, k): -j,
        (one, j): j, (k, one): k,
    }  # fmt: skip
    for (a, b), want in table.items():
        assert torch.equal(quat_mul(a, b), want)
    a, b = random_quats(64, seed=1), random_quats(64, seed=2)
    assert torch.allclose(quat_to_rotmat(quat_mul(a, b)), quat_to_rotmat(a) @ quat_to_rotmat(b), atol=1e-12)
    assert torch.allclose(quat_mul(a, b).norm(dim=-1), torch.ones(64, dtype=torch.float64), atol=1e-12)


def test_exp_of_a_small_rotation_vector_is_the_exact_map_to_float64_precision():
    """Under 1e-4 rad the Taylor branch stands in for sin(θ/2)/θ: it must agree to ~1 ulp."""
    for angle in (1e-7, 5e-5, 9.9e-5, 1e-4, 2e-4):
        v = torch.tensor([[0.6, -0.8, 0.0]], dtype=torch.float64) * angle
        exact = torch.cat(
            (torch.cos(torch.tensor([[angle / 2]], dtype=torch.float64)), v * (math.sin(angle / 2) / angle)), -1
        )
        assert torch.allclose(quat_exp_rotvec(v), exact, rtol=1e-15, atol=0), angle


def test_wrap_angle_range():
    a = torch.tensor([0.0, math.pi, -math.pi, 3 * math.pi, -3.5 * math.pi, 7.0])
    w = wrap_angle(a)
    assert (w > -math.pi - 1e-6).all() and (w <= math.pi + 1e-6).all()
    assert torch.allclose(torch.sin(w), torch.sin(a), atol=1e-5) and torch.allclose(
        torch.cos(w), torch.cos(a), atol=1e-5
    )
    assert w[2].item() == torch.tensor(math.pi).item()


def _axis_rotation(axis, angle):
    rotvec = torch.zeros(*angle.shape, 3, dtype=angle.dtype)
    rotvec[..., axis] = angle
    return quat_exp_rotvec(rotvec)


def test_euler_is_yaw_then_pitch_then_roll_in_body_order():
    """ZYX: q = q_z(yaw) ⊗ q_y(pitch) ⊗ q_x(roll), on a [2, 5] batch (leading dims broadcast)."""
    g = torch.Generator().manual_seed(7)
    roll, pitch, yaw = (torch.rand(2, 5, generator=g, dtype=torch.float64) * 3 - 1.5 for _ in range(3))
    expect = quat_mul(_axis_rotation(2, yaw), quat_mul(_axis_rotation(1, pitch), _axis_rotation(0, roll)))
    expect = expect * torch.sign(expect[..., :1])  # q and -q are the same rotation
    q = quat_from_euler(roll, pitch, yaw)
    assert q.shape == (2, 5, 4)
    assert torch.allclose(q * torch.sign(q[..., :1]), expect, atol=1e-12)
    assert torch.allclose(quat_yaw(q), yaw, atol=1e-12)


def test_frame_helpers_broadcast_over_leading_dims():
    q = random_quats(6, seed=5).reshape(2, 3, 4)
    v = torch.randn(2, 3, 3, dtype=torch.float64)
    flat = quat_to_rotmat(q.reshape(6, 4)).reshape(2, 3, 3, 3)
    assert torch.allclose(quat_to_rotmat(q), flat, atol=1e-12)
    assert torch.allclose(quat_rotate(q, v), (flat @ v.unsqueeze(-1)).squeeze(-1), atol=1e-12)
    assert torch.allclose(quat_body_z(q), flat[..., 2], atol=1e-12)
    assert torch.allclose(quat_mul(q, q).reshape(6, 4), quat_mul(q.reshape(6, 4), q.reshape(6, 4)), atol=1e-12)
    rv = torch.randn(2, 3, 3, dtype=torch.float64)
    assert torch.allclose(quat_exp_rotvec(rv).reshape(6, 4), quat_exp_rotvec(rv.reshape(6, 3)), atol=1e-12)
    assert torch.allclose(quat_yaw(q).reshape(6), quat_yaw(q.reshape(6, 4)), atol=1e-12)
    assert torch.allclose(quat_normalize(3 * q), q, atol=1e-12)
