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


def test_brownian_without_a_walk_is_the_constant_start():
    """sigma2 = 0 is allowed: the walk's steps are 0, so the start holds (a ConstantForce)."""
    model, quad = bound(Brownian(max_mps2=2.0, sigma2=0.0), 5)
    d0 = model.current_mps2.clone()
    assert d0.abs().max() > 0
    for _ in range(20):
        model.update(quad.state)
    assert torch.equal(model.current_mps2, d0)


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


def test_wind_draws_follow_their_definitions():
    """Per episode: mean wind horizontal, heading uniform over the circle, speed uniform in
    [min, max]; Fourier modes with unit directions scaled by amp × speed and wavenumbers 2π/λ."""
    wind = Wind(
        speed_min_mps=1.0,
        speed_max_mps=2.0,
        num_modes=2,
        spatial_amp=0.5,
        wavelength_min_m=2.0,
        wavelength_max_m=3.0,
        gust_std_mps=0.4,
        gust_vertical_ratio=0.25,
    )
    model, _ = bound(wind, 20000)
    speed = model.w_mean.norm(dim=-1)
    assert model.w_mean[:, 2].abs().max() == 0
    assert 1.0 <= speed.min() < 1.01 and 1.99 < speed.max() <= 2.0 and abs(speed.mean() - 1.5) < 0.01
    heading = torch.atan2(model.w_mean[:, 1], model.w_mean[:, 0])
    for lo in (-math.pi, -math.pi / 2, 0.0, math.pi / 2):  # each quadrant holds a quarter
        share = ((heading >= lo) & (heading < lo + math.pi / 2)).double().mean()
        assert abs(share - 0.25) < 0.015
    k = model.mode_k.norm(dim=-1)
    assert model.mode_k.shape == (20000, 2, 3)
    assert 2 * math.pi / 3.0 - 1e-9 <= k.min() and k.max() <= 2 * math.pi / 2.0 + 1e-9
    amp = model.mode_dir.norm(dim=-1)
    assert torch.allclose(amp, 0.5 * speed[:, None].expand(-1, 2), atol=1e-9)
    assert model.mode_dir[:, 0].mean(0).abs().max() < 0.02 and model.mode_dir[:, :, 2].abs().mean() > 0.1
    phase = model.mode_phase
    assert phase.min() < -3.1 and phase.max() > 3.1
    gust_std = model.gust.std(0)
    assert torch.allclose(gust_std, torch.tensor([0.4, 0.4, 0.1], dtype=gust_std.dtype), rtol=0.05)
    # the field at a point: mean + gust + Σ modes
    pos = torch.randn(20000, 3, dtype=torch.float64)
    modes = (model.mode_dir * torch.sin((model.mode_k * pos[:, None]).sum(-1) + phase)[..., None]).sum(1)
    assert torch.allclose(model.wind_mps(pos), model.w_mean + model.gust + modes)


def test_wind_gust_is_an_ou_process():
    """One step of the exact OU discretisation: g' = a g + std sqrt(1 − a²) ε, a = exp(−dt/τ)."""
    wind = Wind(num_modes=0, gust_std_mps=0.5, gust_tau_s=0.25, gust_vertical_ratio=1.0)
    model, quad = bound(wind, 50000)
    model.gust.fill_(1.0)
    model.update(quad.state)
    a = math.exp(-0.02 / 0.25)
    assert torch.allclose(model.gust.mean(0), torch.full((3,), a, dtype=torch.float64), atol=0.003)
    assert torch.allclose(
        model.gust.std(0), torch.full((3,), 0.5 * math.sqrt(1 - a * a), dtype=torch.float64), rtol=0.03
    )


@pytest.mark.parametrize(
    "kwargs, ok",
    [
        ({"speed_min_mps": 0.0, "speed_max_mps": 0.0}, True),  # still air is allowed
        ({"drag_coef_per_m": 0.0, "gust_std_mps": 0.0, "num_modes": 0}, True),
        ({"speed_min_mps": 2.0, "speed_max_mps": 1.0}, False),
        ({"speed_min_mps": -0.5}, False),
        ({"drag_coef_per_m": -0.1}, False),
        ({"gust_std_mps": -0.1}, False),
        ({"gust_tau_s": 0.0}, False),
        ({"num_modes": -1}, False),
    ],
)
def test_wind_parameter_bounds(kwargs, ok):
    if ok:
        Wind(**kwargs)
        return
    with pytest.raises(ValueError, match=r"^disturbance[.:]"):
        Wind(**kwargs)


@pytest.mark.parametrize(
    "make, message",
    [
        (
            lambda: Wind(speed_min_mps=3, speed_max_mps=1),
            "disturbance.speed_min_mps/speed_max_mps: need 0 <= min <= max",
        ),
        (lambda: Wind(gust_tau_s=0), "disturbance.gust_tau_s: must be a finite number in (0, 3600], got 0"),
        (lambda: Wind(num_modes=-1), "disturbance.num_modes: must be an integer in [0, 100], got -1"),
        (lambda: ConstantForce(-1), "disturbance.max_mps2: must be a finite number in [0, 200], got -1"),
        (lambda: Brownian(sigma2=-0.1), "disturbance.sigma2: must be a finite number in [0, 1000], got -0.1"),
        (lambda: Brownian(sigma2=float("nan")), "disturbance.sigma2: must be a finite number in [0, 1000], got nan"),
        (lambda: DragPlate(mass_ratio=-0.1), "disturbance.mass_ratio: must be a finite number in [0, 10], got -0.1"),
        (
            lambda: DragPlate(drag_coef_body_per_m=(0.1, -0.1, 0.1)),
            "disturbance.drag_coef_body_per_m: must be 3 elements, each a finite number in [0, 100], "
            "got [0.1, -0.1, 0.1]",
        ),
        (
            lambda: DragPlate(drag_coef_body_per_m=(0.1, 0.1)),
            "disturbance.drag_coef_body_per_m: must be 3 elements, each a finite number in [0, 100], got [0.1, 0.1]",
        ),
    ],
)
def test_bad_parameter_messages(make, message):
    with pytest.raises(ValueError) as info:
        make()
    assert str(info.value).startswith(message)


def test_plate_in_wind_sees_the_air_relative_velocity():
    """With ``wind``, the plate's drag acts on w − v (a drone moving with the wind feels none)."""
    wind = Wind(speed_min_mps=2.0, speed_max_mps=2.0, num_modes=0, gust_std_mps=0.0)
    plate = DragPlate(mass_ratio=0.0, drag_coef_body_per_m=(0.5, 0.5, 0.5), wind=wind)
    model, quad = bound(plate, 3)
    quad.state.thrust_mps2.zero_()
    w = wind.w_mean  # body = world at identity attitude: drag c ⊙ |w| ⊙ w per axis
    assert torch.allclose(model.update(quad.state), 0.5 * w.abs() * w)
    quad.state.vel_mps = wind.w_mean.clone()
    assert model.update(quad.state).abs().max() < 1e-12


def test_wind_modes_are_drawn_per_drone_and_gusts_exactly():
    wind = Wind(num_modes=2, gust_std_mps=0.5, gust_tau_s=0.5, gust_vertical_ratio=0.3)
    model, quad = bound(wind, 3, seed=4)
    # each drone its own field: wave directions and amplitude directions differ between drones
    k_dir = model.mode_k / model.mode_k.norm(dim=-1, keepdim=True)
    a_dir = model.mode_dir / model.mode_dir.norm(dim=-1, keepdim=True)
    assert not torch.allclose(k_dir[0], k_dir[1]) and not torch.allclose(a_dir[0], a_dir[1])
    # one gust step, recomputed in float64 from the same generator state
    state = model.generator.get_state()
    before = model.gust.clone()
    model.update(quad.state)
    gen = torch.Generator().manual_seed(0)
    gen.set_state(state)
    a = math.exp(-0.02 / 0.5)
    noise = torch.randn(3, 3, generator=gen, dtype=torch.float64) * (0.5 * math.sqrt(1 - a * a))
    expect = before * a + noise * torch.tensor([1.0, 1.0, 0.3], dtype=torch.float64)
    assert torch.allclose(model.gust, expect, rtol=1e-14, atol=1e-15)


def test_plate_drag_in_the_sims_precision_and_from_the_given_generator():
    plate = DragPlate(mass_ratio=0.0, drag_coef_body_per_m=(0.6, 0.0, 0.2))  # a zero coefficient is allowed
    model, quad = bound(plate, 1)
    quad.state.thrust_mps2.zero_()
    quad.state.vel_mps = torch.tensor([[1.0, 0.0, 0.0]], dtype=torch.float64)
    assert model.update(quad.state)[0, 0].item() == -0.6  # exactly, in float64

    def windy(global_seed):
        torch.manual_seed(global_seed)
        m, _ = bound(DragPlate(wind=Wind()), 4, seed=3)
        return m.wind.w_mean.clone()

    assert torch.equal(windy(1), windy(2))  # the plate passes its generator to the wind
