"""The thrust a reference asks for (datt.deploy.feasibility) against cases with a known answer,
and the runner's thrust check before TRACK (refuse, slow, fly) with stand-ins: no vehicle, no radio."""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from datt.deploy.feasibility import SLOW_STEP, peak_ask, slow_factor, slowed, thrust_asked
from datt.deploy.outcome import Kind
from tests.deploy import bookkeeping_runner

G, DT = 9.81, 0.02


def line(v_mps: float, n: int, axis: int = 0) -> np.ndarray:
    path = np.zeros((n, 3))
    path[:, axis] = v_mps * DT * np.arange(n)
    return path


def test_a_held_point_asks_for_gravity_alone():
    np.testing.assert_allclose(thrust_asked(np.zeros((50, 3)), DT, 0.4, G), G)


def test_a_constant_acceleration_asks_for_its_norm_with_gravity_where_the_window_fits():
    """p = a t² / 2 along x: the second difference is exact for a quadratic, so every point with
    t ± w inside the path asks for sqrt(a² + g²)."""
    t = np.arange(200) * DT
    path = np.stack([0.5 * 3.0 * t**2, np.zeros_like(t), np.zeros_like(t)], axis=-1)
    w = 0.4
    inside = (t >= w - 1e-9) & (t <= t[-1] - w + 1e-9)
    np.testing.assert_allclose(thrust_asked(path, DT, w, G)[inside], math.hypot(3.0, G), rtol=1e-9)


def test_a_climb_asks_for_more_than_a_descent():
    """The vertical axis carries gravity: +a up asks for g + a, the same acceleration down for g - a."""
    t = np.arange(100) * DT
    up = np.stack([np.zeros_like(t), np.zeros_like(t), 0.5 * 2.0 * t**2], axis=-1)
    down = up * np.array([1.0, 1.0, -1.0])
    assert thrust_asked(up, DT, 0.2, G)[50] == pytest.approx(G + 2.0)
    assert thrust_asked(down, DT, 0.2, G)[50] == pytest.approx(G - 2.0)


@pytest.mark.parametrize("window_s", [0.2, 0.4])
def test_a_right_angle_corner_asks_for_the_velocity_turn_over_the_window(window_s):
    """At v along x, then v along y: the turn is sqrt(2) v, spread over the window: the peak ask is
    sqrt(2 v² / w² + g²), at the corner's time."""
    v, n = 1.5, 101
    path = line(v, n)
    path[51:] = path[50] + line(v, n - 50, axis=1)[1:]
    ask = peak_ask(path, DT, window_s, G)
    assert ask.peak_mps2 == pytest.approx(math.sqrt(2 * v**2 / window_s**2 + G**2), rel=1e-9)
    assert ask.at_s == pytest.approx(50 * DT)


def test_a_start_from_rest_at_speed_is_a_corner_at_the_start():
    """The path is held before its start: leaving at v from rest asks for v / w at t = 0."""
    ask = peak_ask(line(1.0, 60), DT, 0.4, G)
    assert ask.at_s == 0.0 and ask.peak_mps2 == pytest.approx(math.hypot(1.0 / 0.4, G))


def test_slowed_keeps_the_grid_and_divides_the_speed():
    path = line(1.2, 40)
    np.testing.assert_allclose(slowed(path, DT, 1.0), path, atol=1e-12)
    np.testing.assert_allclose(slowed(path, DT, 2.0), line(0.6, 40), atol=1e-12)


def test_the_slow_factor_is_the_first_on_its_grid_that_fits():
    """p = a t² / 2 slowed by s accelerates at a / s²: it fits a limit L once s² >= a / sqrt(L² - g²);
    the factor returned is the first of 1, 1.05, ... at or past that, None past max_factor."""
    t = np.arange(400) * DT
    a, limit = 8.0, 11.0
    path = np.stack([0.5 * a * t**2, np.zeros_like(t), np.zeros_like(t)], axis=-1)
    need = math.sqrt(a / math.sqrt(limit**2 - G**2))  # 1.27
    found = slow_factor(path, DT, 0.2, G, limit, max_factor=2.0, points=100)
    assert found is not None and need <= found < need + SLOW_STEP + 1e-9
    assert slow_factor(path, DT, 0.2, G, limit, max_factor=1.25, points=100) is None
    assert slow_factor(path, DT, 0.2, G, 20.0, max_factor=2.0, points=100) == 1.0


def test_the_points_after_the_phase_are_its_future_not_a_stop():
    """A line at 2 m/s from rest asks for g in its middle and a corner of v / w where it is held:
    its start, and its end when the end is among the points checked."""
    path, corner = line(2.0, 100), math.hypot(2.0 / 0.4, G)
    asked = thrust_asked(path, DT, 0.4, G)
    assert asked[50] == pytest.approx(G) and asked[0] == pytest.approx(corner) and asked[-1] == pytest.approx(corner)
    assert peak_ask(path, DT, 0.4, G, points=99).peak_mps2 == pytest.approx(corner)  # the start's
    assert peak_ask(path[50:], DT, 0.4, G, points=49).peak_mps2 == pytest.approx(corner)  # the start again
    assert peak_ask(path[:-1] * 0 + path[-1], DT, 0.4, G).peak_mps2 == pytest.approx(G)  # a held point


class TableEnv:
    """The parts of the flight model's env the thrust check reads and writes."""

    def __init__(self, table: np.ndarray, episode_steps: int) -> None:
        self.ref_table = torch.tensor(table, dtype=torch.float32).unsqueeze(0)
        self.params = SimpleNamespace(episode_steps=episode_steps)
        self.dt_s = DT
        self.replaced = None

    def replace_reference(self, table):
        self.replaced = table
        self.ref_table = table.to(torch.float32)


def checking_runner(tmp_path, infeasible: str = "refuse", max_slow: float = 2.0):
    p = SimpleNamespace(
        rate_hz=50.0,
        track_s=None,
        infeasible=infeasible,
        thrust_window_s=0.4,
        thrust_reserve_mps2=0.5,
        max_slow_factor=max_slow,
    )
    thrust = SimpleNamespace(p=SimpleNamespace(gravity_mps2=G))
    return bookkeeping_runner(tmp_path, p=p, thrust=thrust, summary_extra={}, _track_table=None)


def corner_model(v_mps: float = 1.5):
    path = line(v_mps, 81)
    path[41:] = path[40] + line(v_mps, 41, axis=1)[1:]
    env = TableEnv(path, episode_steps=60)  # float32, as the env's table: the check reads that
    return SimpleNamespace(env=env), peak_ask(env.ref_table[0].double().numpy(), DT, 0.4, G, points=61).peak_mps2


def test_a_reference_within_the_ceiling_is_flown_and_says_so(tmp_path):
    runner = checking_runner(tmp_path)
    model, ask = corner_model()
    assert runner._thrust_check(model, ask + 0.5 + 1e-9, can_slow=True) is None  # at ceiling - reserve
    (event,) = runner.log.events
    assert event["kind"] == "thrust check" and event["text"].endswith(": flown")
    assert runner.summary_extra["thrust_check"]["ask_mps2"] == pytest.approx(ask)
    assert model.env.replaced is None


def test_a_reference_past_the_ceiling_is_refused_naming_both_figures_and_the_option(tmp_path):
    runner = checking_runner(tmp_path)
    model, ask = corner_model()
    ceiling = ask + 0.49
    refusal = runner._thrust_check(model, ceiling, can_slow=True)
    (event,) = runner.log.events
    assert event["kind"] == "LAND"
    text = event["text"]
    assert f"asks for {ask:.2f} m/s²" in text and f"ceiling is {ceiling:.2f} m/s²" in text
    assert "deploy.flight.infeasible=slow" in text and "deploy.flight.thrust_window_s 0.4 s" in text
    assert refusal == text and model.env.replaced is None


def test_slow_flies_the_reference_slower_by_the_first_factor_that_fits(tmp_path):
    runner = checking_runner(tmp_path, infeasible="slow")
    model, ask = corner_model()
    original = model.env.ref_table[0].double().numpy().copy()
    ceiling = G + 0.5 + 0.8 * (ask - G)  # a corner's ask falls as 1 / s: somewhat slower fits
    assert runner._thrust_check(model, ceiling, can_slow=True) is None
    factor = runner.summary_extra["thrust_check"]["slow_factor"]
    assert 1.0 < factor <= 2.0
    np.testing.assert_allclose(model.env.replaced[0].numpy(), slowed(original, DT, factor), atol=1e-12)
    slower = model.env.replaced[0].numpy()
    assert peak_ask(slower, DT, 0.4, G, points=61).peak_mps2 <= ceiling - 0.5
    assert peak_ask(slowed(original, DT, factor - SLOW_STEP), DT, 0.4, G, points=61).peak_mps2 > ceiling - 0.5
    # a second check (after the next trim) slows the reference as drawn, not the slowed one
    assert runner._thrust_check(model, ceiling, can_slow=True) is None
    assert runner.summary_extra["thrust_check"]["slow_factor"] == factor


@pytest.mark.parametrize("infeasible, can_slow", [("slow", False), ("slow", True), ("refuse", True)])
def test_a_reference_that_no_allowed_slowing_fits_is_refused(tmp_path, infeasible, can_slow):
    runner = checking_runner(tmp_path, infeasible=infeasible, max_slow=1.2)
    model, ask = corner_model()
    assert runner._thrust_check(model, G + 0.6, can_slow=can_slow) is not None
    text = runner.log.events[-1]["text"]
    if infeasible == "slow" and can_slow:
        assert "not even 1.2 times slower (deploy.flight.max_slow_factor)" in text
    else:
        assert "deploy.flight.infeasible=slow flies it slower" in text


def test_a_refused_reference_lands_as_its_own_outcome_exit_2():
    from datt.deploy.outcome import Outcome

    outcome = Outcome(Kind.REFUSED_REFERENCE, "the reference asks for ...")
    assert outcome.exit_code == 2 and outcome.text.startswith("landed without tracking: ")
    assert not outcome.landed
