"""The runner's checks of a reference before arming (``_check_reference_in_geofence``), the table
it checks (``_held_table``) and the takeoff phase it builds (``_takeoff``), with stand-ins for the
flight model: no vehicle, no radio."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
import torch

from datt.deploy.runner import FlightRunner, Ramp, _Abort
from tests.deploy import bookkeeping_runner

LEAVES = "the reference leaves the geofence at"
FENCE = SimpleNamespace(geofence_min_m=[-2.0, -2.0, -0.1], geofence_max_m=[2.0, 2.0, 2.5])


def table_model(points, episode_steps: int = 4, dt_s: float = 0.02):
    """A flight model whose reference table (controller frame) is ``points``."""
    table = torch.tensor([points], dtype=torch.float32)
    return SimpleNamespace(
        env=SimpleNamespace(ref_table=table, params=SimpleNamespace(episode_steps=episode_steps), dt_s=dt_s)
    )


def fenced_runner(tmp_path, origin_xy=(0.5, 0.0), height_m: float = 1.0):
    p = SimpleNamespace(rate_hz=50.0, origin_m=list(origin_xy), takeoff_height_m=height_m)
    return bookkeeping_runner(tmp_path, p=p, safety=FENCE)


def test_the_held_table_is_the_first_points_and_then_its_last_point():
    """The table's first ``points`` points (float64); a flight longer than the table holds its last."""
    model = table_model([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.2, 0.0, 0.5]])
    np.testing.assert_allclose(FlightRunner._held_table(model, 2), [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]], rtol=1e-6)
    held = FlightRunner._held_table(model, 5)
    assert held.dtype == np.float64 and held.shape == (5, 3)
    np.testing.assert_allclose(held[2:], [[0.2, 0.0, 0.5]] * 3, rtol=1e-6)


def test_a_reference_inside_the_fence_passes(tmp_path):
    runner = fenced_runner(tmp_path)
    runner._check_reference_in_geofence(table_model([[1.4, 1.9, 1.4]] * 5), None)  # at (1.9, 1.9, 2.4)
    assert runner.log.events == []


@pytest.mark.parametrize(
    "points, text",
    [
        (
            [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [-2.6, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, 0.0, 0.0]],
            "geofence_min_m: " + LEAVES + " t=0.04 s (x=-2.10 m; fence -2.00..2.00 m)",
        ),
        (
            [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.6], [0.0, 0.0, 0.0]],
            "geofence_max_m: " + LEAVES + " t=0.06 s (z=2.60 m; fence -0.10..2.50 m)",
        ),
        (
            [[0.0, 0.0, 0.0], [0.0, 2.1, -1.2], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]],
            "geofence_max_m: " + LEAVES + " t=0.02 s (y=2.10 m; fence -2.00..2.00 m)",
        ),
    ],
    ids=["below_x", "above_z", "first_axis_out"],
)
def test_a_reference_leaving_the_fence_is_refused_where_it_first_leaves(tmp_path, points, text):
    """The path (table + the hover point (0.5, 0, 1)) is checked point by point: the first point
    outside, and its first axis outside, are named with the bound it crosses."""
    runner = fenced_runner(tmp_path)
    with pytest.raises(_Abort):
        runner._check_reference_in_geofence(table_model(points), None)
    assert runner.outcome.text == f"preflight failed: deploy.safety.{text}"


@pytest.mark.parametrize("last_out, refused", [(4, True), (5, False)])
def test_the_check_covers_the_flight_up_to_its_last_tick(tmp_path, last_out, refused):
    """A phase of 4 ticks flies the table's points 0..4 (the reference after its last tick is where
    it ends): a point outside at 4 is refused, at 5 (never flown) is not; None is the reference's
    episode (here 4 steps), a duration its ticks at the flight's rate."""
    points = [[0.0, 0.0, 0.0]] * 6
    points[last_out] = [0.0, 0.0, 2.0]
    for duration_s in (None, 0.08):
        runner = fenced_runner(tmp_path)
        if refused:
            with pytest.raises(_Abort):
                runner._check_reference_in_geofence(table_model(points), duration_s)
            assert "at t=0.08 s (z=3.00 m" in runner.outcome.text
        else:
            runner._check_reference_in_geofence(table_model(points), duration_s)


def test_the_takeoff_ramps_the_pid_from_the_start_to_the_hover_point(tmp_path):
    """``_takeoff``: the PID flies a ramp from the vehicle's start (controller frame) to the hover
    point over ``takeoff_s``; the phase lasts that and ``hover_s`` more."""
    built = []
    runner = bookkeeping_runner(tmp_path, p=SimpleNamespace(takeoff_s=2.5, hover_s=1.5), pid_factory=lambda: "pid")
    runner._model = lambda controller, family: built.append((controller, family)) or "model"
    assert runner._takeoff(np.array([0.1, -0.2, -0.95])) == ("TAKEOFF", "model", 4.0)
    ((controller, ramp),) = built
    assert controller == "pid" and isinstance(ramp, Ramp) and ramp.duration_s == 2.5
    assert ramp.start.tolist() == pytest.approx([0.1, -0.2, -0.95]) and ramp.end.tolist() == [0.0, 0.0, 0.0]
