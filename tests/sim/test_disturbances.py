"""Disturbance models against their definitions."""

import math

import pytest
import torch

from datt.sim import Brownian, ConstantForce, DragPlate, NoDisturbance, Quadrotor, Wind
from datt.sim.frames import quat_from_euler

G = 9.81


def bound(model, n, seed=0, dtype=torch.float64):
    quad = Quadrotor(n, dtype=dtype)
    gen = torch.Generator().manual_seed(seed)
    model.bind(n, 0.02, gen, "cpu", dtype)
    model.reset(torch.arange(n), quad.state)
    return model, quad


def test_none_is_zero():
    model, quad = bound(NoDisturbance(), 5)
    assert model.update(quad.state).abs().sum() == 0


def test_constant_is_bounded_constant_and_spread():
    model, quad = bound(ConstantForce(3.5), 4000)
    d0 = model.current_mps2.clone()
    assert d0.abs().max() <= 3.5 and d0.abs().max() > 3.3
    assert d0.std(0).min() > 1.8  # uniform on [-3.5, 3.5]: std 2.02
    for _ in range(10):
        model.update(quad.state)
    assert torch.equal(model.current_mps2, d0)


def test_brownian_variance_grows_linearly():
    n, sigma2, steps = 20000, 0.01, 250
    model, quad = bound(Brownian(max_mps2=0.0, sigma2=sigma2), n)
    assert model.current_mps2.abs().max() == 0
    for _ in range(steps):
        model.update(quad.state)
    var = model.current_mps2.var(0)
    expect = sigma2 * steps * 0.02  # Σ dt per step
    assert torch.allclose(var, torch.full_like(var, expect), rtol=0.05), (var, expect)
    assert model.current_mps2.mean(0).abs().max() < 4 * math.sqrt(expect / n)


def test_brownian_starts_uniform():
    model, _ = bound(Brownian(max_mps2=3.5), 20000)
    var = model.current_mps2.var(0)
    assert torch.allclose(var, torch.full_like(var, 7.0**2 / 12), rtol=0.05)


def test_disturbance_seeded_reproducible_and_partial_reset():
    a, qa = bound(Brownian(), 6, seed=3)
    b, qb = bound(Brownian(), 6, seed=3)
    c, _ = bound(Brownian(), 6, seed=4)
    assert torch.equal(a.current_mps2, b.current_mps2) and not torch.equal(a.current_mps2, c.current_mps2)
    before = a.current_mps2.clone()
    a.reset(torch.tensor([2]), qa.state)
    changed = (a.current_mps2 != before).any(-1)
    assert changed.tolist() == [False, False, True, False, False, False]


def test_wind_quadratic_drag_on_air_relative_velocity():
    wind = Wind(speed_min_mps=3.0, speed_max_mps=3.0, drag_coef_per_m=0.25, num_modes=0, gust_std_mps=0.0)
    model, quad = bound(wind, 8)
    d = model.current_mps2
    # drone at rest in a uniform 3 m/s horizontal wind: |d| = c * 3^2 along the wind
    assert torch.allclose(d.norm(dim=-1), torch.full((8,), 0.25 * 9.0, dtype=d.dtype), atol=1e-9)
    assert d[:, 2].abs().max() < 1e-12
    # moving with the air: no force; moving twice as fast: force reverses
    quad.state.vel_mps = model.w_mean.clone()
    assert model.update(quad.state).abs().max() < 1e-9
    quad.state.vel_mps = 2 * model.w_mean
    assert torch.allclose(model.update(quad.state), -d, atol=1e-9)


def test_wind_field_varies_in_space_and_gusts_have_stationary_std():
    wind = Wind(num_modes=3, spatial_amp=0.3, gust_std_mps=0.5, gust_tau_s=0.5)
    model, quad = bound(wind, 4000)
    w0 = model.wind_mps(torch.zeros(4000, 3, dtype=torch.float64))
    w1 = model.wind_mps(torch.full((4000, 3), 0.7, dtype=torch.float64))
    assert (w1 - w0).norm(dim=-1).mean() > 0.1
    for _ in range(200):
        model.update(quad.state)
    std = model.gust.std(0)
    assert torch.allclose(std, torch.tensor([0.5, 0.5, 0.15], dtype=std.dtype), rtol=0.08)


def test_plate_extra_mass_and_anisotropic_drag():
    plate = DragPlate(mass_ratio=0.25, drag_coef_body_per_m=(0.6, 0.1, 0.2))
    model, quad = bound(plate, 2)
    # hover thrust, at rest: the extra mass removes g * r / (1 + r) of lift
    assert torch.allclose(model.current_mps2[:, 2], torch.full((2,), -G * 0.25 / 1.25, dtype=torch.float64))
    quad.state.thrust_mps2.zero_()
    quad.state.vel_mps = torch.tensor([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0]], dtype=torch.float64)
    d = model.update(quad.state)
    assert torch.allclose(d[0], torch.tensor([-0.6 * 4 / 1.25, 0, 0], dtype=torch.float64))
    assert torch.allclose(d[1], torch.tensor([0, -0.1 * 4 / 1.25, 0], dtype=torch.float64))
    # the drag axes turn with the body: yaw by 90° swaps which world axis sees the large drag
    quad.state.quat = quat_from_euler(
        *(torch.zeros(2, dtype=torch.float64),) * 2, torch.full((2,), math.pi / 2, dtype=torch.float64)
    )
    d = model.update(quad.state)
    assert torch.allclose(d[1], torch.tensor([0, -0.6 * 4 / 1.25, 0], dtype=torch.float64), atol=1e-9)


@pytest.mark.parametrize(
    "bad",
    [
        lambda: ConstantForce(-1),
        lambda: Brownian(sigma2=-0.1),
        lambda: Wind(gust_tau_s=0),
        lambda: DragPlate(mass_ratio=-0.1),
    ],
)
def test_bad_parameters_rejected(bad):
    with pytest.raises(ValueError, match="disturbance"):
        bad()
