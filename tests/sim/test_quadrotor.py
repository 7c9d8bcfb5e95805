"""Dynamics against analytic cases (free fall, hover, pure rotation, actuator delay)."""

import math

import pytest
import torch

from datt.errors import ConfigError
from datt.sim import Quadrotor, QuadrotorParams
from datt.sim.frames import quat_body_z, quat_yaw

G = 9.81


def cmd(n, thrust, rates=(0.0, 0.0, 0.0), dtype=torch.float32):
    c = torch.tensor([thrust, *rates], dtype=dtype)
    return c.expand(n, 4).clone()


@pytest.mark.parametrize("dtype", ["float32", "float64"])
@pytest.mark.parametrize("latency", [0, 1, 3])
def test_free_fall_matches_analytic(dtype, latency):
    quad = Quadrotor(4, QuadrotorParams(initial_thrust_mps2=0.0, latency_steps=latency), dtype=dtype)
    quad.reset(pos_m=torch.zeros(4, 3))
    dt = quad.dt_s
    for k in range(1, 151):
        quad.step(cmd(4, 0.0, dtype=quad.dtype))
        t = k * dt
        expect = -G * t * t / 2
        z = quad.state.pos_m[:, 2]
        assert torch.allclose(z, torch.full_like(z, expect), rtol=1e-4, atol=0), (k, z[0].item(), expect)
    assert torch.allclose(quad.state.vel_mps[:, 2], torch.full((4,), -G * 150 * dt, dtype=quad.dtype), rtol=1e-5)
    assert quad.state.pos_m[:, :2].abs().max() == 0


def test_zero_initial_thrust_idles_until_the_first_command_arrives():
    """The authors' start (their ``QuadSim`` rebuilt at reset, an empty command queue): with
    ``initial_thrust_mps2 = 0`` and one step of latency, the first step falls freely and the
    first command reaches the thrust filter one step later, 0.4 of it."""
    quad = Quadrotor(1, QuadrotorParams(initial_thrust_mps2=0.0, latency_steps=1), dtype="float64")
    quad.reset(pos_m=torch.zeros(1, 3))
    quad.step(cmd(1, 2 * G, dtype=torch.float64))
    assert quad.state.thrust_mps2.item() == 0.0
    assert quad.state.vel_mps[0, 2].item() == pytest.approx(-G * quad.dt_s)
    quad.step(cmd(1, 2 * G, dtype=torch.float64))
    assert quad.state.thrust_mps2.item() == pytest.approx(0.4 * 2 * G)


def test_hover_start_holds_hover_before_the_first_command_arrives():
    quad = Quadrotor(1, QuadrotorParams(latency_steps=2), dtype="float64")
    quad.reset(pos_m=torch.zeros(1, 3))
    for _ in range(2):  # the two in-flight slots hold hover, whatever is sent now
        quad.step(cmd(1, 0.0, dtype=torch.float64))
        assert quad.state.thrust_mps2.item() == pytest.approx(G)
    quad.step(cmd(1, 0.0, dtype=torch.float64))
    assert quad.state.thrust_mps2.item() == pytest.approx(0.6 * G)


def test_hover_holds_position_for_ten_seconds():
    quad = Quadrotor(3)
    start = torch.tensor([[0.3, -0.2, 1.0], [0.0, 0.0, 0.0], [-1.0, 2.0, 0.5]])
    quad.reset(pos_m=start)
    for _ in range(500):
        quad.step(cmd(3, G))
    assert torch.allclose(quad.state.pos_m, start, atol=1e-6)
    assert quad.state.vel_mps.abs().max() < 1e-6


def test_hover_fails_without_enough_thrust():
    quad = Quadrotor(1)
    for _ in range(50):
        quad.step(cmd(1, 0.9 * G))
    assert quad.state.pos_m[0, 2] < -0.05  # the hover test can fail: thrust matters


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_pure_yaw_rotation_keeps_unit_norm_and_matches_angle(dtype):
    rate = 1.3  # rad/s about body z
    quad = Quadrotor(2, QuadrotorParams(k_rate=1.0, latency_steps=0), dtype=dtype)
    steps = 10_000
    for _ in range(steps):
        quad.step(cmd(2, G, (0.0, 0.0, rate), dtype=quad.dtype))
    q = quad.state.quat
    assert torch.allclose(torch.linalg.vector_norm(q, dim=-1), torch.ones(2, dtype=q.dtype), atol=1e-6)
    expect = math.remainder(rate * steps * quad.dt_s, 2 * math.pi)
    tol = 2e-3 if dtype == "float32" else 1e-9
    assert abs(quat_yaw(q)[0].item() - expect) < tol
    # still level and hovering: yaw does not tilt the thrust axis
    assert torch.allclose(quat_body_z(q), torch.tensor([0.0, 0.0, 1.0], dtype=q.dtype).expand(2, 3), atol=1e-5)
    assert quad.state.pos_m.abs().max() < 1e-4


def test_roll_rotation_tilts_thrust_axis_analytically():
    quad = Quadrotor(1, QuadrotorParams(k_rate=1.0, latency_steps=0), dtype="float64")
    rate = math.pi / 2  # 90 deg in 1 s
    for _ in range(50):
        quad.step(cmd(1, G, (rate, 0.0, 0.0), dtype=torch.float64))
    # R_x(90°) e3 = (0, -1, 0)
    assert torch.allclose(
        quat_body_z(quad.state.quat)[0], torch.tensor([0.0, -1.0, 0.0], dtype=torch.float64), atol=1e-9
    )


@pytest.mark.parametrize("latency", [0, 1, 2])
def test_first_order_delay_step_response(latency):
    k = 0.4
    quad = Quadrotor(1, QuadrotorParams(latency_steps=latency, k_thrust=k, k_rate=k), dtype="float64")
    target, rate_target = G + 10.0, 5.0
    thrusts, rates = [], []
    for _ in range(10):
        quad.step(cmd(1, target, (rate_target, 0.0, 0.0), dtype=torch.float64))
        thrusts.append(quad.state.thrust_mps2[0].item())
        rates.append(quad.state.rate_radps[0, 0].item())
    for n in range(1, 11):
        active = max(0, n - latency)
        frac = 1 - (1 - k) ** active
        assert thrusts[n - 1] == pytest.approx(G + 10.0 * frac, abs=1e-9)
        assert rates[n - 1] == pytest.approx(rate_target * frac, abs=1e-9)
    # 63 % (one time constant) is first reached `latency + 2` steps after the command
    frac = [(th - G) / 10.0 for th in thrusts]
    first = next(i + 1 for i, f in enumerate(frac) if f >= 1 - math.exp(-1))
    assert first == latency + 2


def test_thrust_clipped_to_physical_range():
    quad = Quadrotor(2, QuadrotorParams(latency_steps=0, k_thrust=1.0))
    quad.step(torch.tensor([[-5.0, 0, 0, 0], [500.0, 0, 0, 0]]))
    assert quad.state.thrust_mps2.tolist() == [0.0, quad.params.max_thrust_mps2]


def test_body_rates_are_capped_in_norm_per_drone():
    """The rate cap scales each drone's rate vector to ``max_rate_radps`` (direction kept); a drone
    under the cap is untouched by another drone above it."""
    quad = Quadrotor(2, QuadrotorParams(latency_steps=0, k_rate=1.0, max_rate_radps=10.0), dtype="float64")
    quad.step(torch.tensor([[G, 30.0, 40.0, 0.0], [G, 3.0, 0.0, -4.0]], dtype=torch.float64))
    assert quad.state.rate_radps.tolist() == [pytest.approx([6.0, 8.0, 0.0], abs=1e-12), [3.0, 0.0, -4.0]]


def test_batch_is_independent_per_drone():
    commands = torch.tensor([[G + 2, 0.5, -0.3, 0.1], [G - 1, -1.0, 0.2, 0.0], [G, 0.0, 0.0, 1.0]])
    batch = Quadrotor(3)
    singles = [Quadrotor(1) for _ in range(3)]
    for _ in range(40):
        batch.step(commands)
        for i, s in enumerate(singles):
            s.step(commands[i : i + 1])
    for i, s in enumerate(singles):
        assert torch.allclose(batch.state.pos_m[i], s.state.pos_m[0], atol=1e-6)
        assert torch.allclose(batch.state.quat[i], s.state.quat[0], atol=1e-6)


def test_partial_reset_touches_only_selected_drones():
    quad = Quadrotor(3)
    for _ in range(20):
        quad.step(cmd(3, G + 3.0, (0.5, 0.0, 0.0)))
    before, sent = quad.state.pos_m.clone(), quad.latency.in_flight().clone()
    assert quad.params.latency_steps == 1 and torch.equal(sent, cmd(3, G + 3.0, (0.5, 0.0, 0.0)).unsqueeze(0))
    quad.reset(torch.tensor([1]), torch.tensor([[1.0, 2.0, 3.0]]))
    assert torch.equal(quad.state.pos_m[[0, 2]], before[[0, 2]])
    # the commands still in flight to the other drones stay; drone 1's are hover
    assert torch.equal(quad.latency.in_flight()[:, [0, 2]], sent[:, [0, 2]])
    assert torch.equal(quad.latency.in_flight()[:, 1], cmd(1, G))
    assert quad.state.pos_m[1].tolist() == [1.0, 2.0, 3.0]
    assert quad.state.vel_mps[1].abs().sum() == 0 and quad.state.thrust_mps2[1] == pytest.approx(G)


def test_new_drones_and_a_full_reset_without_positions_are_at_rest_at_the_origin():
    quad = Quadrotor(3, QuadrotorParams(rate_model="second_order"))
    assert_at_rest_at_the_origin_with_hover_in_flight(quad)
    for _ in range(20):
        quad.step(cmd(3, G + 3.0, (0.5, -0.2, 0.1)))
    quad.reset()
    assert_at_rest_at_the_origin_with_hover_in_flight(quad)


def assert_at_rest_at_the_origin_with_hover_in_flight(quad):
    s = quad.state
    assert torch.equal(s.pos_m, torch.zeros(3, 3)) and torch.equal(s.vel_mps, torch.zeros(3, 3))
    assert torch.equal(s.quat, torch.tensor([[1.0, 0.0, 0.0, 0.0]]).expand(3, 4))
    assert torch.equal(s.rate_radps, torch.zeros(3, 3)) and torch.equal(quad.rate_torque, torch.zeros(3, 3))
    assert torch.equal(s.thrust_mps2, torch.full((3,), G)) and torch.equal(quad.last_applied_cmd, cmd(3, G))
    assert torch.equal(quad.latency.in_flight(), cmd(3, G).expand(quad.params.latency_steps, 3, 4))


IN_0_1 = "must be a finite number in (0, 1], got"
HALF_WIDTH = "must be a finite number in [0, 1), got"
LATENCY_MAX = "must be null or an integer >= latency_steps (1), got"
LATENCY_RANGE = "must be an integer in [0, 100] or null, got"
REFUSED_PARAMS = [
    ({"k_thrust": 0.0}, f"k_thrust: {IN_0_1} 0.0"),
    ({"k_thrust": 1.01}, f"k_thrust: {IN_0_1} 1.01"),
    ({"k_rate": 0.0}, f"k_rate: {IN_0_1} 0.0"),
    ({"k_rate": 1.5}, f"k_rate: {IN_0_1} 1.5"),
    ({"latency_steps": -1}, "latency_steps: must be an integer in [0, 100], got -1"),
    ({"max_thrust_mps2": 0.0}, "max_thrust_mps2: must be a finite number in (0, 200], got 0.0"),
    ({"max_thrust_mps2": float("inf")}, "max_thrust_mps2: must be a finite number in (0, 200], got inf"),
    ({"max_rate_radps": 0.0}, "max_rate_radps: must be a finite number in (0, 100], got 0.0"),
    ({"mass_spread": -0.1}, f"mass_spread: {HALF_WIDTH} -0.1"),
    ({"mass_spread": 1.0}, f"mass_spread: {HALF_WIDTH} 1.0"),
    ({"thrust_gain_spread": -0.01}, f"thrust_gain_spread: {HALF_WIDTH} -0.01"),
    ({"thrust_gain_spread": 1.0}, f"thrust_gain_spread: {HALF_WIDTH} 1.0"),
    ({"latency_steps_max": 0}, f"latency_steps_max: {LATENCY_MAX} 0"),
    ({"latency_steps_max": 2.5}, f"latency_steps_max: {LATENCY_RANGE} 2.5"),
    ({"latency_steps_max": True}, f"latency_steps_max: {LATENCY_RANGE} True"),
    (
        {"rate_model": "third_order"},
        "rate_model: unknown value 'third_order'; allowed: first_order, second_order, mixed, firmware",
    ),
    ({"kw_rate": 0.0}, f"kw_rate: {IN_0_1} 0.0"),
    ({"kw_rate": 1.2}, f"kw_rate: {IN_0_1} 1.2"),
    ({"kt_rate": 0.0}, f"kt_rate: {IN_0_1} 0.0"),
    ({"kt_rate": 1.2}, f"kt_rate: {IN_0_1} 1.2"),
    ({"command_loss_max": 0.6}, "command_loss_max: must be a finite number in [0, 0.5], got 0.6"),
    ({"command_loss_max": -0.1}, "command_loss_max: must be a finite number in [0, 0.5], got -0.1"),
]


@pytest.mark.parametrize("kwargs, message", REFUSED_PARAMS, ids=[f"case{i}" for i in range(len(REFUSED_PARAMS))])
def test_each_bad_param_is_refused_in_one_line_naming_its_key_and_rule(kwargs, message):
    with pytest.raises(ConfigError) as info:
        Quadrotor(1, QuadrotorParams(**kwargs))
    assert str(info.value) == f"env.quad.{message}"
    with pytest.raises(ConfigError) as info:
        QuadrotorParams(**kwargs).validate("deploy.quad")
    assert str(info.value) == f"deploy.quad.{message}"


def test_the_params_at_the_edges_of_their_rules_are_accepted():
    edges = [
        {"k_thrust": 1.0, "k_rate": 1.0, "kw_rate": 1.0, "kt_rate": 1.0, "latency_steps": 0},
        {"max_thrust_mps2": 0.5, "max_rate_radps": 0.5},
        {"mass_spread": 0.0, "thrust_gain_spread": 0.0},
        {"mass_spread": 0.99, "thrust_gain_spread": 0.99},
        {"latency_steps": 1, "latency_steps_max": 1},
        {"latency_steps": 1, "latency_steps_max": 3.0},
        {"command_loss_max": 0.0},
        {"command_loss_max": 0.5},
        *({"rate_model": m} for m in ("first_order", "second_order", "mixed")),
    ]
    for kwargs in edges:
        QuadrotorParams(**kwargs).validate()


@pytest.mark.parametrize("dt_s", [-0.01, 0.0])
def test_a_step_that_is_not_positive_is_rejected(dt_s):
    with pytest.raises(ConfigError) as info:
        Quadrotor(1, dt_s=dt_s)
    assert str(info.value) == f"env.dt_s: must be > 0, got {dt_s}"


def test_unknown_dtype_rejected():
    with pytest.raises(ValueError, match="float16"):
        Quadrotor(1, dtype="float16")


def test_rotations_compose_in_body_order():
    """Roll 1 rad/s for 0.5 s, then yaw 2 rad/s for 0.5 s: R = Rx(0.5) Rz(1), so body z ends at
    Rx(0.5) e3 = (0, -sin 0.5, cos 0.5). Integrating in the world frame would give
    Rz(1) Rx(0.5) e3 = (0.403, -0.259, 0.878)."""
    quad = Quadrotor(1, QuadrotorParams(k_rate=1.0, latency_steps=0), dtype="float64")
    steps = round(0.5 / quad.dt_s)
    for rates in ((1.0, 0.0, 0.0), (0.0, 0.0, 2.0)):
        for _ in range(steps):
            quad.step(cmd(1, G, rates, dtype=quad.dtype))
    expect = torch.tensor([[0.0, -math.sin(0.5), math.cos(0.5)]], dtype=torch.float64)
    assert torch.allclose(quat_body_z(quad.state.quat), expect, atol=1e-9)


def test_height_after_a_thrust_step_matches_the_actuator_model():
    """From hover, command g + 2 m/s² with no latency and k_thrust = 1: the vertical acceleration
    is 2 m/s² from the first step, so after k steps z = 2 (k dt)² / 2 exactly."""
    quad = Quadrotor(1, QuadrotorParams(k_thrust=1.0, latency_steps=0), dtype="float64")
    quad.reset(pos_m=torch.zeros(1, 3, dtype=torch.float64))
    dt = quad.dt_s
    for k in range(1, 11):
        quad.step(cmd(1, G + 2.0, dtype=quad.dtype))
        assert quad.state.pos_m[0, 2].item() == pytest.approx(0.5 * 2.0 * (k * dt) ** 2, abs=1e-12), k


@pytest.mark.parametrize("steps", [0, 1, 3])
def test_commands_in_flight_are_the_last_ones_sent_oldest_first(steps):
    from datt.sim.quadrotor import CommandLatency

    fill = torch.zeros(4)
    latency = CommandLatency(steps, fill, n=2)
    assert latency.in_flight().shape == (steps, 2, 4)
    sent = [torch.full((2, 4), float(k + 1)) for k in range(5)]
    applied = [latency.push(cmd) for cmd in sent]
    # after 5 pushes the queue wrapped (head != 0 for 3 slots): still the last `steps`, oldest first
    flight = latency.in_flight()
    assert flight.shape == (steps, 2, 4)
    assert [row[0, 0].item() for row in flight] == [float(k) for k in range(6 - steps, 6)]
    # what comes out is what went in `steps` pushes earlier (zeros before that)
    expect = [0.0] * steps + [float(k + 1) for k in range(5 - steps)]
    assert [a[0, 0].item() for a in applied] == expect
    for k in range(6, 9):  # the head passes every slot: the order holds at each
        latency.push(torch.full((2, 4), float(k)))
        assert [row[0, 0].item() for row in latency.in_flight()] == [float(j) for j in range(k + 1 - steps, k + 1)]


def test_compile_passes_its_options_to_torch_compile(monkeypatch):
    """``compile(**options)`` hands the integrator and the options to ``torch.compile`` (through
    ``compile_or_eager``) and returns the simulator."""
    from datt.sim.quadrotor import integrate

    seen = {}

    def fake_compile(fn, **kwargs):
        seen.update(fn=fn, **kwargs)
        return lambda *args: fn(*args)

    monkeypatch.setattr("datt.compile.compile_or_eager", fake_compile)
    quad = Quadrotor(2)
    assert quad.compile(backend="eager", mode="reduce-overhead") is quad
    assert seen == {"fn": integrate, "backend": "eager", "mode": "reduce-overhead"}
    assert quad._integrate is not integrate


def _lossy(n: int, loss: float, latency_steps: int = 1) -> Quadrotor:
    """``n`` drones losing each command with probability ``loss`` (drawn, then pinned)."""
    quad = Quadrotor(n, QuadrotorParams(command_loss_max=0.5, latency_steps=latency_steps))
    quad.randomise(torch.arange(n), torch.Generator().manual_seed(0))
    quad.command_loss.fill_(loss)
    return quad


def test_a_lost_command_leaves_the_actuators_on_the_one_before_and_the_sender_unaware():
    """Every command lost: the actuators keep the idle (hover) command; the latency buffer, what the
    sender and the training predictor know, holds the commands sent."""
    quad = _lossy(3, 1.0, latency_steps=2)
    for k in range(5):
        quad.step(cmd(3, G + 1.0 + k))
    assert torch.equal(quad.last_applied_cmd, quad.idle_cmd.expand(3, 4))
    assert quad.state.thrust_mps2 == pytest.approx([G] * 3)
    assert [row[0, 0].item() for row in quad.latency.in_flight()] == pytest.approx([G + 4.0, G + 5.0])


def test_commands_are_lost_at_each_drones_drawn_rate():
    """A command differing from the last at every step: the share of steps whose applied command
    is the previous one is the drone's loss probability (4000 draws: 3 sigma is 0.02)."""
    quad = _lossy(2, 0.0, latency_steps=0)
    quad.command_loss.copy_(torch.tensor([0.0, 0.3]))
    held = torch.zeros(2)
    steps = 4000
    for k in range(steps):
        before = quad.last_applied_cmd.clone()
        quad.step(cmd(2, G + float(k % 7) - 3.0))
        held += (quad.last_applied_cmd[:, 0] == before[:, 0]).float()
    assert held[0].item() == 0.0
    assert held[1].item() / steps == pytest.approx(0.3, abs=0.02)


def test_each_drone_draws_its_loss_within_the_configured_bound():
    quad = Quadrotor(1000, QuadrotorParams(command_loss_max=0.2))
    quad.randomise(torch.arange(1000), torch.Generator().manual_seed(1))
    assert 0.0 <= quad.command_loss.min().item() and quad.command_loss.max().item() < 0.2
    assert quad.command_loss.mean().item() == pytest.approx(0.1, abs=0.01)
    assert Quadrotor(2).command_loss is None  # off by default: nothing drawn, nothing lost
