"""The thrust map against its definition (the firmware's battery-compensated linear map: per motor
F = c / 65535 * THRUST_MAX, so a = k c with k = 4 THRUST_MAX / (65535 m); calibrated: through the
measured hover point with the measured slope), the simulated vehicle's own motors against the
firmware's code, and the rate conventions, value by value."""

import math

import pytest

from datt.configuration import compose
from datt.deploy.schema import deploy_params
from datt.deploy.sim.motors import FirmwareMotors, MotorParams
from datt.deploy.thrust import ThrustMap, ThrustParams, fit_hover, hover_command_from_hover
from datt.errors import ConfigError
from datt.sim.vehicles import CF21

P = ThrustParams()
K = 4 * 0.12 / (65535 * 0.034)  # m/s² per command unit for the default 34 g vehicle, THRUST_MAX 0.12 N


def test_uncalibrated_map_is_the_firmware_line_through_zero():
    tm = ThrustMap()
    assert tm.slope == pytest.approx(K, rel=1e-12) and tm.firmware_slope == tm.slope
    assert tm.hover_command == pytest.approx(9.81 / K, rel=1e-12)  # 45,539 for 34 g
    for c in (1, 10000, 45539, 60000):
        assert tm.thrust_mps2(c) == pytest.approx(K * c, rel=1e-9)
    assert tm.ceiling_mps2 == pytest.approx(K * 60000, rel=1e-9)
    assert tm.ceiling_mps2 == pytest.approx(12.92, abs=0.01)


def test_firmware_version_changes_the_slope():
    old = ThrustMap(ThrustParams(thrust_max_n=0.1125))
    assert old.slope == pytest.approx(K * 0.1125 / 0.12, rel=1e-12)
    assert old.hover_command == pytest.approx(9.81 / old.slope, rel=1e-12)


@pytest.mark.parametrize("a", [0.5, 2.0, 9.81, 12.0])
def test_command_inverts_the_map(a):
    tm = ThrustMap()
    c = tm.command(a)
    assert c == round(tm.hover_command + (a - 9.81) / K) and isinstance(c, int)
    assert tm.thrust_mps2(c) == pytest.approx(a, abs=K)


def test_calibrated_map_runs_through_the_measured_hover_point_with_the_measured_slope():
    tm = ThrustMap(ThrustParams(hover_command=42000.0, slope_mps2_per_command=3.0e-4))
    assert tm.command(9.81) == 42000
    assert tm.command(9.81 + 3.0) == 42000 + 10000
    assert tm.thrust_mps2(32000) == pytest.approx(9.81 - 3.0)
    assert tm.thrust_mps2(5000) == 0.0  # below the line's zero: no negative thrust
    # a calibrated hover command alone keeps the firmware slope
    assert ThrustMap(ThrustParams(hover_command=42000.0)).slope == pytest.approx(K)


def test_a_calibrated_slope_alone_keeps_the_firmware_hover_point():
    """Each calibrated value falls back to the firmware map's own on its own: a measured slope
    with no measured hover command runs through the firmware's hover point g / k (not g / slope)."""
    tm = ThrustMap(ThrustParams(slope_mps2_per_command=3.0e-4))
    assert tm.hover_command == pytest.approx(9.81 / K, rel=1e-12) and tm.slope == 3.0e-4
    assert tm.firmware_slope == pytest.approx(K, rel=1e-12)
    assert tm.command(9.81 + 3.0) == round(9.81 / K + 10000)
    assert tm.thrust_mps2(round(9.81 / K) - 10000) == pytest.approx(9.81 - 3.0, abs=3e-4)


def test_commands_out_of_range():
    tm = ThrustMap()
    assert tm.command(0.0) == 0 and tm.command(-3.0) == 0
    assert tm.command(float("nan")) == 0 and tm.command(float("inf")) == 0  # motors off, never full power
    assert tm.command(25.0) == 60000 and tm.thrust_mps2(60000) < 25.0  # the policy may ask g + 30
    assert ThrustMap(ThrustParams(max_command=50000)).command(1000.0) == 50000
    assert tm.thrust_mps2(0) == 0.0 and tm.thrust_mps2(-5) == 0.0


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
    assert asdict(from_yaml) == asdict(deploy_params(compose("deploy", ["deploy=crazyflie"]).deploy)[3])


CLAMP = " (the firmware clamps a legacy setpoint's thrust to MAX_THRUST 60000: crtp_commander_rpyt.c, 2026.08)"
APP_CAP = (
    " (the onboard app's setpoint thrust is a uint16; the power distribution caps each motor at UINT16_MAX: "
    "power_distribution_quadrotor.c, 2026.08)"
)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"mass_kg": 0.0}, "deploy.thrust.mass_kg: must be a finite number in (0.005, 5], got 0.0"),
        ({"thrust_max_n": 0.0}, "deploy.thrust.thrust_max_n: must be a finite number in (0, 10], got 0.0"),
        (
            {"max_command": 0},
            "deploy.thrust.max_command: must be in (0, 60000], got 0" + CLAMP,
        ),
        (
            {"max_command": 60001},
            "deploy.thrust.max_command: must be in (0, 60000], got 60001" + CLAMP,
        ),
        ({"app_max_command": 0}, "deploy.thrust.app_max_command: must be in (0, 65535], got 0" + APP_CAP),
        ({"app_max_command": 65536}, "deploy.thrust.app_max_command: must be in (0, 65535], got 65536" + APP_CAP),
        (
            {"app_max_command": 45000},
            "deploy.thrust: a 34.0 g vehicle needs command 45539 to hover with thrust_max_n=0.12 N, "
            "above app_max_command=45000",
        ),
        ({"hover_command": 0.0}, "deploy.thrust.hover_command: must be a finite number in (0, 65535] or null, got 0.0"),
        ({"mass_kg": float("inf")}, "deploy.thrust.mass_kg: must be a finite number in (0.005, 5], got inf"),
        ({"hover_command": 60000.0}, "deploy.thrust.hover_command: must be in (0, max_command), got 60000.0"),
        (
            {"slope_mps2_per_command": -1.0},
            "deploy.thrust.slope_mps2_per_command: must be a finite number in (0, 0.01] or null, got -1.0",
        ),
        (
            {"mass_kg": 0.05},
            "deploy.thrust: a 50.0 g vehicle needs command 66969 to hover with thrust_max_n=0.12 N, "
            "above max_command=60000",
        ),
    ],
)
def test_thrust_params_validation(kwargs, message):
    with pytest.raises(ConfigError) as info:
        ThrustMap(ThrustParams(**kwargs))
    assert str(info.value) == message
    ThrustParams(hover_command=59999.0).validate()


def test_hover_fit_is_the_least_squares_line():
    cmds = [38000.0, 40000.0, 42000.0, 45000.0]
    acc = [0.002 * (c - 41000.0) + e for c, e in zip(cmds, (0.01, -0.02, 0.015, -0.005))]
    n = len(cmds)
    mc, ma = sum(cmds) / n, sum(acc) / n
    slope = sum((c - mc) * (a - ma) for c, a in zip(cmds, acc)) / sum((c - mc) ** 2 for c in cmds)
    hover, fitted_slope = fit_hover(cmds, acc)
    assert hover == pytest.approx(mc - ma / slope, rel=1e-12) and fitted_slope == pytest.approx(slope, rel=1e-12)
    message = "calibration needs at least two distinct commands with one acceleration each"
    for bad in (([40000.0], [0.0]), ([40000.0, 41000.0], [0.0]), ([40000.0, 40000.0], [0.0, 1.0])):
        with pytest.raises(ValueError, match=f"^{message}$"):
            fit_hover(*bad)
    with pytest.raises(ValueError, match="^calibration: acceleration does not increase with the command$"):
        fit_hover([40000.0, 42000.0], [1.0, -1.0])
    with pytest.raises(ValueError, match="^calibration: acceleration does not increase"):
        fit_hover([40000.0, 42000.0], [1.0, 1.0])


# -- the simulated vehicle's motors (datt.deploy.sim.motors) against motors.c -------------------
def test_simulated_motors_follow_the_firmware_line_with_a_full_battery():
    m = FirmwareMotors(MotorParams(mass_kg=0.034))
    for c in (10000, 30000, 45539, 60000, 65535):
        assert m.motor_force_n(c, 4.1) == pytest.approx(c / 65535 * 0.12, rel=1e-12)
        assert m.thrust_mps2(c, 4.1) == pytest.approx(K * c, rel=1e-9)


def test_simulated_motors_stop_below_thrust_min_and_without_a_battery():
    m = FirmwareMotors()
    floor = math.ceil(0.012817578393224994 / 0.12 * 65535)  # the firmware's THRUST_MIN as a command
    assert m.motor_force_n(floor - 1, 4.1) == 0.0 and m.motor_force_n(floor, 4.1) > 0.0
    assert m.motor_force_n(40000, 1.9) == 0.0  # < 2 V: the firmware's sanity floor


def test_a_low_battery_caps_the_force_at_the_cubic_fit():
    m = FirmwareMotors()
    p0, p1, p2, p3 = CF21.vmotor2thrust
    at_3v = p0 + p1 * 3.0 + p2 * 9.0 + p3 * 27.0  # 0.1128 N < THRUST_MAX
    assert m.motor_force_n(65535, 3.0) == pytest.approx(at_3v, rel=1e-12)
    assert m.motor_force_n(30000, 3.0) == pytest.approx(30000 / 65535 * 0.12, rel=1e-12)  # within reach


def test_simulated_motors_are_the_vehicles_not_the_controllers():
    weak = FirmwareMotors(MotorParams(mass_kg=0.034, thrust_gain=0.9))
    heavy = FirmwareMotors(MotorParams(mass_kg=0.0374))
    c = ThrustMap().hover_command  # the controller's hover point for the nominal vehicle
    assert weak.thrust_mps2(round(c), 4.1) == pytest.approx(0.9 * 9.81, rel=1e-4)
    assert heavy.thrust_mps2(round(c), 4.1) == pytest.approx(9.81 / 1.1, rel=1e-4)
    with pytest.raises(
        ConfigError, match=r"^deploy.server.thrust_gain: must be a finite number in \(0, 10\], got 0.0$"
    ):
        FirmwareMotors(MotorParams(thrust_gain=0.0))


@pytest.mark.parametrize("lag", [1.0, 2.0, 3.4, 5.75])
def test_response_lag_recovers_a_delay_between_excitation_and_acceleration(lag):
    """Acceleration = the excitation delayed by ``lag`` ticks (linear interpolation between
    ticks), minus a slower feedback term, plus noise: the lag comes back within 0.25 tick, less
    the half tick by which a sampled jump is placed between its last low and first high sample."""
    import random

    from datt.deploy.thrust import response_lag_ticks

    rng = random.Random(0)
    exc = [1.0 if (k // 25) % 2 else -1.0 for k in range(200)]

    def delayed(k):
        t = k - lag
        i = math.floor(t)
        if i < 0:
            return exc[0]
        f = t - i
        return exc[i] * (1 - f) + exc[min(i + 1, len(exc) - 1)] * f

    acc, fb = [], 0.0
    for k in range(len(exc)):
        fb += 0.1 * (delayed(k) - fb)  # the controller's slower reaction
        acc.append(delayed(k) - 0.8 * fb + rng.gauss(0.0, 0.05))
    assert response_lag_ticks(exc, acc) == pytest.approx(lag - 0.5, abs=0.25)
    with pytest.raises(ValueError, match="^latency: needs an excitation with steps"):
        response_lag_ticks([1.0] * 50, acc[:50])


@pytest.mark.parametrize("direction", [1.0, -1.0])
def test_response_lag_of_one_step_up_or_down_by_hand(direction):
    """One excitation step at tick 3 (the first tick with three samples before it); the
    acceleration jumps by 2 between samples 5 and 6: half of the jump is reached at 5.5, so the
    lag is 5.5 - 3 = 2.5 ticks, whichever way the step goes."""
    from datt.deploy.thrust import response_lag_ticks

    exc = [0.0] * 3 + [direction] * 15
    acc = [0.0] * 6 + [2.0 * direction] * 12
    assert response_lag_ticks(exc, acc) == pytest.approx(2.5)
    # a record that ends within the window after the step has no measurable step
    with pytest.raises(ValueError, match="^latency: needs"):
        response_lag_ticks(exc[:13], acc[:13])


@pytest.mark.parametrize("tail", ["held", "back_at_window_end"])
def test_response_lag_needs_a_crossing_from_below_after_the_step(tail):
    """The acceleration already sits at half of its jump at the tick before the step (-1, 0, 1
    around base 0, then 2): that step has no measurable lag, whether the acceleration holds or
    drops back by the end of the window, so a record with only that step has none."""
    from datt.deploy.thrust import response_lag_ticks

    exc = [0.0] * 3 + [1.0] * 15
    acc = [-1.0, 0.0, 1.0] + [2.0] * 15
    if tail == "back_at_window_end":
        acc[12:] = [0.0] * 6
    with pytest.raises(ValueError, match="^latency: needs"):
        response_lag_ticks(exc, acc)


def test_response_lag_is_the_median_over_steps():
    """Three steps (up, down, up) whose acceleration jumps 1 + delay samples later, delays 1, 2
    and 4: lags 1.5, 2.5 and 4.5 ticks; the median is 2.5 (the mean would be 2.83)."""
    from datt.deploy.thrust import response_lag_ticks

    exc, acc = [0.0] * 60, [0.0] * 60
    for start, delay, level in ((5, 1, 1.0), (25, 2, 0.0), (45, 4, 1.0)):
        for k in range(start, 60):
            exc[k] = level
        for k in range(start + 1 + delay, 60):
            acc[k] = level * 2.0
    assert response_lag_ticks(exc, acc) == pytest.approx(2.5)


def test_response_lag_interpolates_and_takes_the_middle_two_of_an_even_count():
    """Four steps (up, down, up, down at ticks 5, 25, 45, 65) whose acceleration moves
    1 + delay samples later by a quarter of the jump (half of it for the third step) and then
    the rest. With the jump 2: the crossing of half the jump is interpolated a third of the way
    into the second sample (lag = delay + 1 + 1/3), or lands on the half-way sample itself
    (lag = delay + 1). Delays 1, 2, 3, 5 give 2.333, 3.333, 4.0, 6.333: the median of an even
    count is the mean of the middle two, 3.667."""
    from datt.deploy.thrust import response_lag_ticks

    n = 90
    exc, acc = [0.0] * n, [0.0] * n
    for start, delay, level, ramp in ((5, 1, 1.0, 0.25), (25, 2, 0.0, 0.25), (45, 3, 1.0, 0.5), (65, 5, 0.0, 0.25)):
        old = 2.0 * (1.0 - level)
        for k in range(start, n):
            exc[k] = level
        acc[start + 1 + delay] = old + ramp * (2.0 * level - old)
        for k in range(start + 2 + delay, n):
            acc[k] = 2.0 * level
    assert response_lag_ticks(exc, acc) == pytest.approx((10 / 3 + 4.0) / 2)


def test_a_calibrated_map_with_an_offset_keeps_zero_at_zero():
    """Hover 50,000 at 1.5e-4 m/s² per unit puts the line's zero at command ~-15,400: a tiny thrust
    asks for command 0 (not 1), and command 0 is motors off, 0 m/s² (not the line's 2.31)."""
    tm = ThrustMap(ThrustParams(hover_command=50000.0, slope_mps2_per_command=1.5e-4))
    assert tm.command(0.001) == 0 and tm.command(-3.0) == 0
    assert tm.thrust_mps2(0) == 0.0 and tm.thrust_mps2(1) == pytest.approx(9.81 - 1.5e-4 * 49999)


def test_response_lag_of_an_instant_response_and_of_a_ramp_by_hand():
    """An acceleration that jumps in the step's own tick crosses half between the tick before and
    it: -0.5 ticks. A ramp of 1 per tick from the tick before the step: the default 10-tick window
    sees a jump of 10, half is 5, reached 5 ticks after the tick before: 4.0 ticks."""
    from datt.deploy.thrust import response_lag_ticks

    k = 5
    exc = [0.0] * k + [1.0] * 20
    assert response_lag_ticks(exc, exc) == -0.5
    ramp = [max(0.0, float(t - (k - 1))) for t in range(len(exc))]
    assert response_lag_ticks(exc, ramp) == 4.0
    assert response_lag_ticks(exc, ramp, window=12) == 5.0  # jump 12, half 6


def test_hover_command_from_a_steady_hover_is_the_mean_command():
    """Velocity unchanged over the stretch: the vehicle held its height on average, whatever the
    commands did around it."""
    t = [0.02 * k for k in range(25)]
    commands = [50000 + (300 if k % 2 else -300) + 7 * k for k in range(25)]
    got = hover_command_from_hover(t, [-0.1] * 25, commands)
    assert got == pytest.approx(sum(commands[:-1]) / 24, abs=1e-6)  # the last acts after the stretch
    # uneven ticks: each command weighs as long as it acted
    uneven = [0.0, 0.01, 0.05, 0.06]
    got = hover_command_from_hover(uneven, [0.2] * 4, [40000, 50000, 60000, 1])
    assert got == pytest.approx((40000 * 0.01 + 50000 * 0.04 + 60000 * 0.01) / 0.06, rel=1e-12)


@pytest.mark.parametrize("dead_ticks", [2, 3, 4])
def test_the_hover_trim_pairs_velocities_with_the_commands_that_acted_on_them(dead_ticks):
    """A vehicle with thrust ``k c`` acting ``dead_ticks`` after the command is sent (radio and
    actuation), caught by a controller whose command rises and wobbles through the stretch: the
    commands sent one latency before the velocities give its hover command exactly; the ones sent
    at the same ticks are off by the rise over the latency (here over 0.5 %)."""
    from datt.deploy.thrust import commands_acting

    dt, g, k = 0.02, 9.81, 9.81 / 55000.0
    sent_t = [dt * i for i in range(80)]
    sent = [50000.0 + 160.0 * i + (400.0 if i % 3 else -800.0) for i in range(80)]
    vel = [0.0]
    for i in range(79):  # the command sent at tick i acts over [i + dead, i + dead + 1)
        acting = sent[i - dead_ticks] if i >= dead_ticks else sent[0]
        vel.append(vel[-1] + dt * (k * acting - g))
    window = slice(50, 76)
    t = sent_t[window]
    paired = commands_acting(t, sent_t, sent, dead_ticks * dt)
    assert paired == pytest.approx(sent[50 - dead_ticks : 76 - dead_ticks], rel=1e-12)
    assert hover_command_from_hover(t, vel[window], paired, g) == pytest.approx(55000.0, rel=1e-9)
    same_tick = hover_command_from_hover(t, vel[window], sent[window], g)
    assert same_tick / 55000.0 - 1 > 0.005
    # half a tick of lag: the commands half-way between two sends
    half = commands_acting([0.05], sent_t, sent, 0.02)
    assert half == pytest.approx([(sent[2] + sent[1]) / 2], rel=1e-12)
    # before the first send: the first command
    assert commands_acting([0.0], sent_t, sent, 0.1) == [sent[0]]


def test_commands_acting_needs_the_commands_sent_with_their_times():
    from datt.deploy.thrust import commands_acting

    for sent_t, sent in (([], []), ([0.0, 0.02], [1.0])):
        with pytest.raises(ValueError, match="^commands_acting: needs the commands sent, each with its time$"):
            commands_acting([0.0], sent_t, sent, 0.05)


@pytest.mark.parametrize("acc_mps2", [0.5, -0.8])
@pytest.mark.parametrize("mass_kg, thrust_gain", [(0.034, 1.0), (0.0374, 0.9)])
def test_hover_command_from_hover_is_the_simulated_vehicles_own(acc_mps2, mass_kg, thrust_gain):
    """The simulated vehicle (its own motors, mass and gain) flown at the constant command that
    accelerates it by ``acc``: the stretch's velocities give back its true hover command, for a
    vehicle the map is right about and for one 10 % heavier with motors 10 % weaker."""
    vehicle = FirmwareMotors(MotorParams(mass_kg=mass_kg, thrust_gain=thrust_gain))
    k = vehicle.thrust_mps2(40000, 4.1) / 40000
    command = (9.81 + acc_mps2) / k
    acc = vehicle.thrust_mps2(round(command), 4.1) - 9.81
    t = [1.0 + 0.02 * i for i in range(26)]  # 0.5 s
    vel = [0.3 + acc * (tk - 1.0) for tk in t]
    got = hover_command_from_hover(t, vel, [round(command)] * 26)
    assert got == pytest.approx(9.81 / k, rel=1e-9)
    # only the ends of the velocity count: a bump in between changes nothing
    bumped = vel[:10] + [v + 0.5 for v in vel[10:20]] + vel[20:]
    assert hover_command_from_hover(t, bumped, [round(command)] * 26) == pytest.approx(9.81 / k, rel=1e-9)
    # on another planet the same stretch says another hover command
    assert hover_command_from_hover(t, vel, [round(command)] * 26, g_mps2=3.71) != pytest.approx(9.81 / k, rel=1e-3)


def test_hover_command_from_a_vehicle_falling_at_g_is_not_a_number():
    t = [0.0, 0.5]
    assert math.isnan(hover_command_from_hover(t, [0.0, -0.5 * 9.81], [40000, 40000]))
    assert math.isnan(hover_command_from_hover(t, [0.0, -0.5 * 12.0], [40000, 40000]))
    # falling a little slower than g: thrust 0.5 m/s² from the mean command, so hover at 9.81 / 0.5 of it
    assert hover_command_from_hover(t, [0.0, -0.5 * 9.31], [2000, 2000]) == pytest.approx(2000 * 9.81 / 0.5)


@pytest.mark.parametrize(
    "t, vel, cmds",
    [
        ([0.0], [0.0], [1.0]),
        ([0.0, 0.0], [0.0, 0.0], [1.0, 1.0]),
        ([0.0, 0.1], [0.0], [1.0, 1.0]),
        ([], [], []),
        ([0.0, 0.1, 0.0], [0.0] * 3, [1.0] * 3),  # ends where it began
    ],
)
def test_hover_command_from_hover_needs_two_samples_over_a_positive_time(t, vel, cmds):
    with pytest.raises(ValueError, match="^hover trim: needs at least two samples over a positive time$"):
        hover_command_from_hover(t, vel, cmds)


@pytest.mark.parametrize("scale", [1.23, 0.9])
def test_rescaling_the_map_scales_every_command_and_keeps_zero_at_zero(scale):
    """A vehicle that needs ``scale`` times the commands: every thrust's command is ``scale``
    times the old one (the line through zero stays through zero), the ceiling drops by ``scale``."""
    m = ThrustMap()
    before = {a: m.hover_command + (a - 9.81) / m.slope for a in (2.0, 9.81, 12.0)}
    ceiling = m.ceiling_mps2
    m.rescale(scale)
    for a, c in before.items():
        assert m.hover_command + (a - 9.81) / m.slope == pytest.approx(scale * c, rel=1e-12)
    assert m.hover_command == pytest.approx(scale * 9.81 / K, rel=1e-12)
    assert m.command(9.81) == round(scale * 9.81 / K)
    assert m.ceiling_mps2 == pytest.approx(ceiling / scale, rel=1e-12)


@pytest.mark.parametrize("scale", [0.0, -1.0, math.nan, math.inf])
def test_rescaling_the_map_refuses_a_scale_that_is_not_finite_and_positive(scale):
    m = ThrustMap()
    with pytest.raises(ValueError, match="must be finite and positive"):
        m.rescale(scale)
    assert m.hover_command == pytest.approx(9.81 / K)


def test_what_is_sent_is_the_clipped_command_in_si():
    """The predictor rolls forward what the vehicle is asked for: above the ceiling the thrust the
    map expects of max_command, rates clipped to max_rate_degps (roll, pitch, yaw), signs kept."""
    m = ThrustMap(ThrustParams(max_command=50000, max_rate_degps=(720.0, 360.0, 400.0)))
    ceiling = m.thrust_mps2(50000)
    thrust, wx, wy, wz = m.as_sent(ceiling + 5.0, math.radians(800.0), math.radians(-400.0), math.radians(-500.0))
    assert thrust == pytest.approx(ceiling) and ceiling < 14.0
    assert (math.degrees(wx), math.degrees(wy), math.degrees(wz)) == pytest.approx((720.0, -360.0, -400.0))
    inside = m.as_sent(9.0, 0.5, -0.25, 0.75)
    assert inside[0] == pytest.approx(m.thrust_mps2(m.command(9.0))) and inside[0] == pytest.approx(9.0, abs=0.01)
    assert inside[1:] == pytest.approx([0.5, -0.25, 0.75])


def test_the_thrust_settings_take_their_bounds_exactly():
    """``max_command`` in (0, 60000] (the legacy commander's MAX_THRUST): 1 and 60000 are ceilings
    (0 and 60001 are not); ``app_max_command`` in (0, 65535] (the app's setpoint skips that clamp);
    ``hover_command`` in (0,
    max_command): 1 is a hover command, 0 and max_command are not (the map refuses a hover at
    its ceiling too)."""
    from datt.errors import ConfigError

    ThrustParams(max_command=1).validate()
    ThrustParams(max_command=60000).validate()
    ThrustParams(app_max_command=1).validate()
    ThrustParams(app_max_command=65535).validate()  # above the legacy 60000: the app's own ceiling
    ThrustParams(hover_command=1.0).validate()
    for bad in (
        {"max_command": 0},
        {"max_command": 60001},
        {"app_max_command": 0},
        {"app_max_command": 65536},
        {"hover_command": 0.0},
        {"hover_command": 60000.0, "max_command": 60000},
    ):
        with pytest.raises(ConfigError, match="^deploy.thrust."):
            ThrustParams(**bad).validate()
    with pytest.raises(ConfigError, match="deploy.thrust"):
        ThrustMap(ThrustParams(mass_kg=0.1, max_command=int(round(ThrustMap(ThrustParams(mass_kg=0.1)).hover_command))))
    # a hover exactly at the app's ceiling leaves the app nothing to climb with: refused too
    with pytest.raises(ConfigError, match="above app_max_command=50000$"):
        ThrustMap(ThrustParams(hover_command=50000.0, app_max_command=50000))
    ThrustMap(ThrustParams(hover_command=50000.0, app_max_command=50001))


def test_no_thrust_is_command_zero_whatever_the_map():
    """Zero thrust asked is the motors' zero command, also on a steep calibrated map whose line
    would cross zero thrust far above command 0."""
    steep = ThrustMap(ThrustParams(hover_command=55000.0, slope_mps2_per_command=3e-4))
    assert 55000.0 - 9.81 / 3e-4 > 20000  # the line's zero thrust sits at command ~22,300
    assert steep.command(0.0) == 0 and steep.command(-1.0) == 0 and steep.command(float("nan")) == 0
    assert steep.command(1e-6) > 20000  # just above zero thrust: on the line
