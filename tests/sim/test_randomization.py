"""Domain randomisation of the simulator (env.quad.* spreads, per-drone latency, the authors'
second-order rate model) and the observation noise, each against its definition."""

import pytest
import torch

from datt.errors import ConfigError
from datt.sim import Quadrotor, QuadrotorParams
from datt.sim.quadrotor import CommandLatency

G = 9.81


def hover(n, dtype=torch.float64):
    return torch.tensor([G, 0.0, 0.0, 0.0], dtype=dtype).expand(n, 4).clone()


def test_thrust_scale_is_gain_over_mass_within_the_spreads_and_sets_the_acceleration():
    """A hovering command gives a vertical acceleration of (gain / mass − 1) g per drone."""
    n, s_mass, s_gain = 4000, 0.1, 0.2
    params = QuadrotorParams(mass_spread=s_mass, thrust_gain_spread=s_gain, latency_steps=0, k_thrust=1.0)
    quad = Quadrotor(n, params, dtype="float64")
    quad.randomise(torch.arange(n), torch.Generator().manual_seed(1))
    scale = quad.thrust_scale
    assert scale.min() >= (1 - s_gain) / (1 + s_mass) and scale.max() <= (1 + s_gain) / (1 - s_mass)
    # both factors are drawn: the spread of the ratio is wider than either alone could give
    assert scale.min() < (1 - s_gain) + 0.02 and scale.max() > (1 + s_gain) - 0.02
    quad.reset(pos_m=torch.zeros(n, 3, dtype=torch.float64))
    quad.step(hover(n))
    acc = quad.state.vel_mps[:, 2] / quad.dt_s
    assert torch.allclose(acc, (scale - 1.0) * G, atol=1e-9)


def test_nominal_drones_draw_nothing_and_keep_the_exact_model():
    gen = torch.Generator().manual_seed(3)
    before = gen.get_state()
    quad = Quadrotor(5, QuadrotorParams())
    quad.randomise(torch.arange(5), gen)
    assert torch.equal(gen.get_state(), before)
    assert quad.thrust_scale is None and quad.second_order is None and quad.latency.delay is None


def test_per_drone_latency_delays_each_command_by_its_own_steps():
    latency = CommandLatency(1, torch.zeros(1), n=3, max_steps=3)
    latency.set_delay(torch.arange(3), torch.tensor([1, 2, 3]))
    out = [latency.push(torch.full((3, 1), float(k + 1)))[:, 0].tolist() for k in range(6)]
    # drone i applies at push k the command sent at push k − delay_i (the fill, 0, before that)
    for k, row in enumerate(out):
        assert row == [float(max(k + 1 - d, 0)) for d in (1, 2, 3)], k
    # in flight = the last `steps` (nominal) commands sent, oldest first
    assert latency.in_flight()[:, 0, 0].tolist() == [6.0]


def test_latency_draws_cover_the_range_uniformly():
    n = 6000
    quad = Quadrotor(n, QuadrotorParams(latency_steps=1, latency_steps_max=3))
    quad.randomise(torch.arange(n), torch.Generator().manual_seed(0))
    counts = torch.bincount(quad.latency.delay, minlength=4)
    assert counts[0] == 0 and counts[1:].sum() == n
    assert (counts[1:].float() / n - 1 / 3).abs().max() < 0.03


def test_a_step_in_rate_reaches_the_body_after_the_drawn_latency():
    """Two drones, delays 1 and 3, k_rate = 1: the roll rate appears after 1 and 3 steps."""
    quad = Quadrotor(2, QuadrotorParams(k_rate=1.0, latency_steps=1, latency_steps_max=3), dtype="float64")
    quad.latency.set_delay(torch.arange(2), torch.tensor([1, 3]))
    cmd = hover(2)
    cmd[:, 1] = 2.0
    seen = [quad.step(cmd).rate_radps[:, 0].tolist() for _ in range(4)]
    assert seen == [[0.0, 0.0], [2.0, 0.0], [2.0, 0.0], [2.0, 2.0]]


@pytest.mark.parametrize("kw, kt", [(0.4, 0.6), (0.3, 0.5)])  # the authors' gains, and others
def test_second_order_rate_model_follows_the_authors_recurrence(kw, kt):
    quad = Quadrotor(
        1, QuadrotorParams(latency_steps=0, rate_model="second_order", kw_rate=kw, kt_rate=kt), dtype="float64"
    )
    cmd = hover(1)
    cmd[:, 1:] = torch.tensor([1.0, -2.0, 0.5], dtype=torch.float64)
    w, tau = [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]
    for _ in range(30):
        quad.step(cmd)
        for i, target in enumerate((1.0, -2.0, 0.5)):  # τ_des = kw (ω_cmd − ω); τ += kt (τ_des − τ); ω += τ
            tau[i] += kt * (kw * (target - w[i]) - tau[i])
            w[i] += tau[i]
        assert quad.state.rate_radps[0].tolist() == pytest.approx(w, abs=1e-12)


def test_second_order_overshoots_where_first_order_does_not():
    first = Quadrotor(1, QuadrotorParams(latency_steps=0), dtype="float64")
    second = Quadrotor(1, QuadrotorParams(latency_steps=0, rate_model="second_order"), dtype="float64")
    cmd = hover(1)
    cmd[:, 1] = 1.0
    peak = {"first": 0.0, "second": 0.0}
    for _ in range(40):
        peak["first"] = max(peak["first"], first.step(cmd).rate_radps[0, 0].item())
        peak["second"] = max(peak["second"], second.step(cmd).rate_radps[0, 0].item())
    assert peak["first"] <= 1.0 + 1e-12 and 1.02 < peak["second"] < 1.05  # ~3 % overshoot (kw 0.4, kt 0.6)


def test_mixed_rate_model_gives_about_half_the_drones_each_model_and_redraws_at_reset():
    n = 4000
    quad = Quadrotor(n, QuadrotorParams(rate_model="mixed"))
    gen = torch.Generator().manual_seed(0)
    quad.randomise(torch.arange(n), gen)
    first_draw = quad.second_order.clone()
    assert abs(first_draw.float().mean().item() - 0.5) < 0.03
    quad.randomise(torch.arange(n), gen)
    assert not torch.equal(first_draw, quad.second_order)


def test_reset_clears_the_second_order_state():
    quad = Quadrotor(2, QuadrotorParams(latency_steps=0, rate_model="second_order"))
    cmd = hover(2, torch.float32)
    cmd[:, 1] = 3.0
    for _ in range(5):
        quad.step(cmd)
    quad.reset(torch.tensor([0]))
    assert quad.rate_torque[0].abs().sum() == 0 and quad.rate_torque[1].abs().sum() > 0


@pytest.mark.parametrize(
    "kwargs, key",
    [
        ({"mass_spread": -0.1}, "mass_spread"),
        ({"thrust_gain_spread": 1.0}, "thrust_gain_spread"),
        ({"latency_steps": 2, "latency_steps_max": 1}, "latency_steps_max"),
        ({"latency_steps_max": 2.5}, "latency_steps_max"),
        ({"rate_model": "third_order"}, "rate_model"),
        ({"kw_rate": 0.0}, "kw_rate"),
        ({"kt_rate": 1.2}, "kt_rate"),
    ],
)
def test_bad_randomisation_values_name_the_key(kwargs, key):
    with pytest.raises(ConfigError, match=f"env.quad.{key}") as info:
        Quadrotor(1, QuadrotorParams(**kwargs))
    assert "\n" not in str(info.value)
    if key == "rate_model":
        assert "first_order, second_order, mixed, firmware" in str(info.value)


def test_a_wider_ring_without_drawn_delays_keeps_the_nominal_latency():
    """``max_steps`` > ``steps`` but no per-drone draw yet: every drone gets ``steps``."""
    latency = CommandLatency(2, torch.zeros(1), n=2, max_steps=4)
    out = [latency.push(torch.full((2, 1), float(k + 1)))[:, 0].tolist() for k in range(7)]
    assert out == [[0.0, 0.0], [0.0, 0.0]] + [[float(k - 1)] * 2 for k in range(2, 7)]
    assert latency.in_flight()[:, 0, 0].tolist() == [6.0, 7.0]


def test_randomise_draws_from_the_given_generator_in_a_fixed_order():
    """gain U(1 ± s_g), then mass U(1 ± s_m), then the latency, then the rate model: each the
    given generator's next draws (so a seeded env reproduces its vehicles), for the drones asked."""
    params = QuadrotorParams(
        mass_spread=0.1, thrust_gain_spread=0.2, latency_steps=1, latency_steps_max=3, rate_model="mixed"
    )
    quad = Quadrotor(6, params, dtype="float64")
    idx = torch.tensor([1, 4, 5])
    gen = torch.Generator().manual_seed(7)
    replay = torch.Generator().manual_seed(7)
    before = quad.thrust_scale.clone()
    quad.randomise(idx, gen)
    gain = 1.0 + 0.2 * (2.0 * torch.rand(3, dtype=torch.float64, generator=replay) - 1.0)
    mass = 1.0 + 0.1 * (2.0 * torch.rand(3, dtype=torch.float64, generator=replay) - 1.0)
    delay = torch.randint(1, 4, (3,), generator=replay)
    second = torch.rand(3, generator=replay) < 0.5
    torch.testing.assert_close(quad.thrust_scale[idx], gain / mass)
    assert torch.equal(quad.thrust_scale[[0, 2, 3]], before[[0, 2, 3]])
    assert torch.equal(quad.latency.delay[idx], delay.to(quad.latency.delay.dtype))
    assert torch.equal(quad.second_order[idx], second)
    assert torch.equal(gen.get_state(), replay.get_state())  # nothing else drawn


@pytest.mark.parametrize("rate_model", ["first_order", "firmware"])
def test_behind_a_trimmed_map_the_commanded_thrust_is_produced_and_the_vehicle_moves_only_its_ceiling(rate_model):
    """``thrust_map_trimmed`` with an exact trim: a hovering command holds every drone's height,
    whatever its mass and gain (without the trim it accelerates at (gain / mass − 1) g), and the
    most each drone's map commands is ``max_thrust_mps2 · gain / mass``; a command above a weak
    drone's ceiling gives its ceiling, not the command."""
    n, ceiling = 6, 12.92
    params = QuadrotorParams(
        mass_spread=0.1,
        thrust_gain_spread=0.1,
        thrust_map_trimmed=True,
        latency_steps=0,
        rate_model=rate_model,
        max_thrust_mps2=ceiling,
    )
    quad = Quadrotor(n, params, dtype="float64")
    quad.randomise(torch.arange(n), torch.Generator().manual_seed(2))
    scale = quad.thrust_scale
    assert scale.min() < 0.97 and scale.max() > 1.15  # weak and strong drones among them
    torch.testing.assert_close(quad.map_scale, scale)
    torch.testing.assert_close(quad.command_ceiling_mps2, ceiling * scale)
    quad.reset(pos_m=torch.zeros(n, 3, dtype=torch.float64))
    for _ in range(100):  # 2 s: the actuators settle from their reset thrust
        quad.step(hover(n))
    before = quad.state.vel_mps[:, 2].clone()
    for _ in range(25):
        quad.step(hover(n))
    acc = (quad.state.vel_mps[:, 2] - before) / (25 * quad.dt_s)
    assert acc.abs().max() < 1e-3, acc
    # full command to each drone: it produces its own ceiling (the commanded units' ceiling, exactly)
    full = hover(n)
    full[:, 0] = 40.0
    for _ in range(50):
        quad.step(full)
    before = quad.state.vel_mps[:, 2].clone()
    quad.step(full)
    acc = (quad.state.vel_mps[:, 2] - before) / quad.dt_s
    tol = 0.02 if rate_model == "firmware" else 1e-9  # the firmware loop truncates to whole commands
    torch.testing.assert_close(acc, ceiling * scale - G, atol=tol, rtol=0.0)


def test_a_trims_error_is_drawn_on_both_sides_and_without_bias():
    """``trim_error_spread`` s: the trimmed map's gain / mass is the true one times U(1 − s, 1 + s):
    both tails reached, the mean 1, nothing beyond; the vehicle then produces the command divided
    by that error."""
    n, s = 20000, 0.02
    params = QuadrotorParams(mass_spread=0.1, thrust_gain_spread=0.1, thrust_map_trimmed=True, trim_error_spread=s)
    quad = Quadrotor(n, params, dtype="float64")
    quad.randomise(torch.arange(n), torch.Generator().manual_seed(4))
    error = quad.map_scale / quad.thrust_scale
    assert error.min() >= 1 - s and error.max() <= 1 + s
    assert error.min() < 1 - 0.98 * s and error.max() > 1 + 0.98 * s
    assert abs(float(error.mean()) - 1.0) < 0.0005
    assert abs(float((error < 1).double().mean()) - 0.5) < 0.02
    # a trim error alone (a nominal vehicle): the map's scale is the error itself
    alone = Quadrotor(n, QuadrotorParams(thrust_map_trimmed=True, trim_error_spread=s), dtype="float64")
    alone.randomise(torch.arange(n), torch.Generator().manual_seed(4))
    assert alone.thrust_scale is None and alone.map_scale.min() >= 1 - s and alone.map_scale.max() <= 1 + s
    alone.reset(pos_m=torch.zeros(n, 3, dtype=torch.float64))
    alone.params.k_thrust = 1.0
    alone.state.thrust_mps2.fill_(G)
    cmd = hover(n)
    for _ in range(alone.params.latency_steps + 1):
        alone.step(cmd)
    torch.testing.assert_close(alone.state.thrust_mps2, G / alone.map_scale)


def test_without_the_trim_flag_the_map_scales_nothing():
    quad = Quadrotor(3, QuadrotorParams(mass_spread=0.1, trim_error_spread=0.05))
    quad.randomise(torch.arange(3), torch.Generator().manual_seed(0))
    assert quad.map_scale is None and quad.command_ceiling_mps2 is None
