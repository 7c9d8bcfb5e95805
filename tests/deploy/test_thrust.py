"""The thrust map against its definition (Bitcraze motor model f(c) = k2 c² + k1 c + k0 per motor,
a = 4 s f(c) / m with s fixing the hover point) and the rate conventions, value by value."""

import math

import pytest

from datt.configuration import compose
from datt.deploy.schema import deploy_params
from datt.deploy.thrust import ThrustMap, ThrustParams, fit_hover_command
from datt.errors import ConfigError

P = ThrustParams()


def test_force_is_the_bitcraze_quadratic():
    tm = ThrustMap()
    for c in (0.0, 10000.0, 40000.0, 65535.0):
        assert tm.force_n(c) == P.k2 * c * c + P.k1 * c + P.k0
    assert tm.force_n(0.0) == P.k0


def test_model_hover_point_without_calibration():
    """Uncalibrated, s = 1 and the hover command is the root of 4 f(c) = m g."""
    tm = ThrustMap()
    assert tm.scale == pytest.approx(1.0, rel=1e-12)
    assert 4 * tm.force_n(tm.hover_command) == pytest.approx(P.mass_kg * P.gravity_mps2, rel=1e-9)
    assert 30000 < tm.hover_command < 50000


def test_calibrated_hover_scales_the_model():
    tm = ThrustMap(ThrustParams(hover_command=42000.0))
    assert tm.hover_command == 42000.0
    assert tm.scale == pytest.approx(P.mass_kg * P.gravity_mps2 / (4 * tm.force_n(42000.0)))
    assert tm.thrust_mps2(42000) == pytest.approx(P.gravity_mps2, rel=1e-12)
    heavier = ThrustMap(ThrustParams(mass_kg=0.040, hover_command=42000.0))
    assert heavier.thrust_mps2(42000) == pytest.approx(P.gravity_mps2, rel=1e-12)


@pytest.mark.parametrize("a", [0.5, 2.0, 9.81, 14.0])
def test_command_inverts_the_model(a):
    """command(a) is the rounded root c of 4 s f(c) / m = a."""
    tm = ThrustMap()
    c = tm.command(a)
    exact = (-P.k1 + math.sqrt(P.k1**2 - 4 * P.k2 * (P.k0 - P.mass_kg * a / (4 * tm.scale)))) / (2 * P.k2)
    assert c == round(exact) and isinstance(c, int)
    assert tm.thrust_mps2(c) == pytest.approx(4 * tm.scale * tm.force_n(float(c)) / P.mass_kg)


def test_commands_at_and_below_the_motor_floor():
    tm = ThrustMap()
    floor_a = 4 * tm.scale * P.k0 / P.mass_kg  # the thrust of command 0 (the model's k0)
    assert tm.command(floor_a) == 0 and tm.command(floor_a * 0.5) == 0
    assert tm.command(floor_a * 1.5) > 0
    assert tm.thrust_mps2(0) == 0.0 and tm.thrust_mps2(-5) == 0.0
    assert tm.thrust_mps2(1) > 0.0
    assert tm.command(float("inf")) == 0  # non-finite: motors off, never full power


def test_max_command_clips():
    tm = ThrustMap(ThrustParams(max_command=50000))
    assert tm.command(1000.0) == 50000
    assert ThrustMap(ThrustParams(max_command=65535)).command(1000.0) == 65535


def test_rates_and_limits():
    tm = ThrustMap(ThrustParams(max_rate_degps=[100.0, 200.0, 50.0]))
    assert tm.rates_deg(1.0, -1.0, 0.5) == pytest.approx((math.degrees(1.0), -math.degrees(1.0), -math.degrees(0.5)))
    assert tm.rates_deg(10.0, 10.0, 10.0) == (100.0, 200.0, -50.0)
    assert tm.rates_deg(-10.0, -10.0, -10.0) == (-100.0, -200.0, 50.0)
    assert ThrustMap.body_rates_from_wire(90.0, 45.0, 30.0) == pytest.approx((math.pi / 2, -math.pi / 4, -math.pi / 6))


def test_thrust_params_are_the_deploy_config_defaults():
    from dataclasses import asdict

    _, _, _, from_yaml = deploy_params(compose("deploy", []).deploy)
    assert asdict(from_yaml) == asdict(ThrustParams())


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mass_kg": 0.0}, "deploy.thrust.mass_kg: must be > 0, got 0.0"),
        ({"max_command": 0}, "deploy.thrust.max_command: must be in (0, 65535], got 0"),
        ({"max_command": 65536}, "deploy.thrust.max_command: must be in (0, 65535], got 65536"),
        ({"hover_command": 0.0}, "deploy.thrust.hover_command: must be in (0, max_command), got 0.0"),
        ({"hover_command": 60000.0}, "deploy.thrust.hover_command: must be in (0, max_command), got 60000.0"),
    ],
)
def test_thrust_params_validation(kwargs, message):
    with pytest.raises(ConfigError) as info:
        ThrustMap(ThrustParams(**kwargs))
    assert str(info.value) == message
    ThrustParams(hover_command=59999.0).validate()


def test_hover_fit_is_the_zero_of_the_least_squares_line():
    cmds = [38000.0, 40000.0, 42000.0, 45000.0]
    acc = [0.002 * (c - 41000.0) + e for c, e in zip(cmds, (0.01, -0.02, 0.015, -0.005))]
    n = len(cmds)
    mc, ma = sum(cmds) / n, sum(acc) / n
    slope = sum((c - mc) * (a - ma) for c, a in zip(cmds, acc)) / sum((c - mc) ** 2 for c in cmds)
    assert fit_hover_command(cmds, acc) == pytest.approx(mc - ma / slope, rel=1e-12)
    message = "calibration needs at least two distinct commands with one acceleration each"
    for bad in (([40000.0], [0.0]), ([40000.0, 41000.0], [0.0]), ([40000.0, 40000.0], [0.0, 1.0])):
        with pytest.raises(ValueError, match=f"^{message}$"):
            fit_hover_command(*bad)
    with pytest.raises(ValueError, match="^calibration: acceleration does not increase with the command$"):
        fit_hover_command([40000.0, 42000.0], [1.0, -1.0])
    with pytest.raises(ValueError, match="^calibration: acceleration does not increase"):
        fit_hover_command([40000.0, 42000.0], [1.0, 1.0])
