"""The calibration flight's analysis (datt.deploy.calibration.fit_calibration) on a plant whose
hover command, slope and dead time are known: a vehicle whose vertical acceleration between the
states read at ticks k and k + 1 is ``slope * (c[k - d] - hover)`` for the command c sent d ticks
earlier. The flight itself is flown in tests/deploy/test_flight.py."""

from __future__ import annotations

import math

import pytest

from datt.deploy.calibration import CALIBRATION_KEYS, excitation_half_period, fit_calibration, square_wave


def plant(
    hover: float, slope: float, dead_ticks: int, rate_hz: float, n: int, excitation: float = 400.0, wander: float = 90.0
):
    """(vertical velocities read at ticks 0..n-1, commands sent at ticks 0..n-1): a hover-holding
    controller's slow wander (a sine of 90 units, period 37 ticks) plus the calibration's square
    wave of ±``excitation`` units; the velocity integrates the acceleration the command sent
    ``dead_ticks`` earlier gives (the commands before tick 0 are at hover)."""
    half = excitation_half_period(rate_hz)
    cmds = [
        hover + 150.0 + wander * math.sin(2 * math.pi * k / 37) + excitation * square_wave(k, half) for k in range(n)
    ]
    vel = [0.3]
    for k in range(n - 1):
        sent = cmds[k - dead_ticks] if k >= dead_ticks else hover
        vel.append(vel[-1] + slope * (sent - hover) / rate_hz)
    return vel, cmds


@pytest.mark.parametrize("rate_hz, dead_ticks", [(50.0, 2), (50.0, 4), (100.0, 2)])
def test_a_linear_plant_with_a_dead_time_gives_its_hover_command_slope_and_latency(rate_hz, dead_ticks):
    """Noise-free: the least-squares line is exact only with the commands paired with the
    accelerations they caused, so hover and slope come back to rounding. The latency is
    response_lag_ticks' definition on a pure dead time: the acceleration over a tick is the step's
    from the tick after ``dead_ticks``, so half of the jump lies half a tick before: d − 0.5 ticks
    (to a fifth of a tick: the controller's wander moves the acceleration a little around a step)."""
    hover, slope = 55_600.0, 1.9e-4
    vel, cmds = plant(hover, slope, dead_ticks, rate_hz, n=int(4 * rate_hz))
    fit = fit_calibration(vel, cmds, rate_hz)
    assert list(fit) == list(CALIBRATION_KEYS)
    assert fit["hover_command"] == pytest.approx(hover, abs=1e-6)
    assert fit["slope_mps2_per_command"] == pytest.approx(slope, rel=1e-9)
    assert fit["response_latency_ms"] == pytest.approx(
        (dead_ticks - 0.5) / rate_hz * 1000.0, abs=0.2 / rate_hz * 1000.0
    )


@pytest.mark.parametrize("rate_hz, dead_ticks", [(50.0, 3), (100.0, 5)])
def test_the_latency_of_a_pure_dead_time_is_exact(rate_hz, dead_ticks):
    """Without the controller's wander every step of the wave is the same clean jump: the latency
    is (d − 0.5) ticks to rounding, in ms at the loop's rate."""
    vel, cmds = plant(50_000.0, 2e-4, dead_ticks, rate_hz, n=int(3 * rate_hz), wander=0.0)
    fit = fit_calibration(vel, cmds, rate_hz)
    assert fit["response_latency_ms"] == pytest.approx((dead_ticks - 0.5) * 1000.0 / rate_hz, abs=1e-9)


def test_commands_paired_with_the_wrong_tick_bias_the_fit():
    """What the pairing buys: the same plant's samples fitted as if the dead time were one tick
    shorter give a slope several per cent off (the fit is not insensitive to the shift)."""
    from datt.deploy.thrust import fit_hover

    rate_hz, d, hover, slope = 50.0, 2, 55_600.0, 1.9e-4
    vel, cmds = plant(hover, slope, d, rate_hz, n=200)
    acc = [(b - a) * rate_hz for a, b in zip(vel, vel[1:])]
    _, off_by_one = fit_hover(cmds[: len(acc) - (d - 1)], acc[d - 1 :])
    assert abs(off_by_one / slope - 1.0) > 0.03
    assert fit_calibration(vel, cmds, rate_hz)["slope_mps2_per_command"] == pytest.approx(slope, rel=1e-9)


def test_a_heavier_vehicle_s_hover_command_is_found_whatever_the_controller_flew_at():
    """The hover point comes from the line's zero, not from the mean command: a controller that
    sat 2,000 units above or below hover during the hold still yields the plant's hover."""
    rate_hz, hover, slope = 50.0, 48_000.0, 2.2e-4
    for offset in (-2000.0, 2000.0):
        vel, cmds = plant(hover, slope, 2, rate_hz, n=200)
        cmds = [c + offset for c in cmds]
        vel = [0.0]
        for k in range(199):
            sent = cmds[k - 2] if k >= 2 else hover
            vel.append(vel[-1] + slope * (sent - hover) / rate_hz)
        fit = fit_calibration(vel, cmds, rate_hz)
        assert fit["hover_command"] == pytest.approx(hover, abs=1e-6)


def test_the_excitation_is_a_1_hz_square_wave_starting_low():
    assert excitation_half_period(50.0) == 25 and excitation_half_period(100.0) == 50
    assert excitation_half_period(49.9) == 24  # whole ticks, rounded down
    wave = [square_wave(k, 25) for k in range(100)]
    assert wave == [-1.0] * 25 + [1.0] * 25 + [-1.0] * 25 + [1.0] * 25


def test_samples_that_cannot_give_a_fit_are_refused():
    vel, cmds = plant(50_000.0, 2e-4, 2, 50.0, n=200)
    with pytest.raises(ValueError, match="^calibration: one vertical velocity per thrust command is needed$"):
        fit_calibration(vel[:-1], cmds, 50.0)
    with pytest.raises(ValueError, match="^latency: needs an excitation with steps"):
        fit_calibration(vel[:20], cmds[:20], 50.0)  # no step of the wave within the samples
    flat = [0.0] * 200  # the vehicle never answered: acceleration does not rise with the command
    with pytest.raises(ValueError, match="^latency: |^calibration: "):
        fit_calibration(flat, cmds, 50.0)
