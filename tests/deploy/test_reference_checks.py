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


def test_a_runner_holds_what_it_was_built_with(tmp_path):
    """The constructor's arguments, each where the flight reads it: the track's family (not the
    config's: the flight model is built on it), the settings, the hover command before any trim,
    the log at the flight's rate and late-tick limit with the console, the battery filter's time constant, a copy
    of the summary's extra keys; an e-stop of its own when none is given; nothing flown yet."""
    import threading

    from datt.deploy.outcome import Kind
    from datt.deploy.runner import FlightParams
    from datt.deploy.safety import SafetyParams

    family, extra = Ramp([0.0, 0.0, 0.0], [1.0, 0.0, 0.0], 2.0), {"policy": "p.pt"}
    params, safety = FlightParams(rate_hz=100.0, late_tick_ms=3.0), SafetyParams(battery_filter_s=2.5)
    thrust, stop, predictor = SimpleNamespace(hover_command=41000.0), SimpleNamespace(signal=None), object()
    console = SimpleNamespace(print=lambda *a: None)
    runner = FlightRunner(
        "link", "mocap", "make_env", "policy", "pid", family, params, safety, thrust, tmp_path / "run",
        console=console, stop_request=stop, summary_extra=extra, predictor=predictor,
    )  # fmt: skip
    assert (runner.link, runner.mocap, runner.make_env) == ("link", "mocap", "make_env")
    assert (runner.track_controller, runner.pid_factory, runner.track_family) == ("policy", "pid", family)
    assert (runner.p, runner.safety, runner.thrust, runner.predictor) == (params, safety, thrust, predictor)
    assert runner.stop_request is stop and runner.configured_hover_command == 41000.0
    assert (
        runner.run_dir == tmp_path / "run" and runner.log.run_dir == tmp_path / "run" and runner.log.console is console
    )
    assert (runner.log.rate_hz, runner.log.late_tick_ms) == (100.0, 3.0) and runner.battery.tau_s == 2.5
    assert runner.summary_extra == extra and runner.summary_extra is not extra
    assert isinstance(runner.estop, threading.Event) and not runner.estop.is_set()
    assert runner.outcome.kind is Kind.INCOMPLETE and runner._excitation is None and not runner._forwarding
    assert runner._mocap_sent_t is None and runner._pending_frame is None and not runner._frame_ready.is_set()
    estop = threading.Event()
    given = FlightRunner("l", None, None, None, None, family, params, safety, thrust, tmp_path, estop=estop)
    assert given.estop is estop and given.summary_extra == {} and given.predictor is None


def test_a_flight_model_is_built_on_the_family_the_ceiling_and_the_guard_and_starts_fresh(tmp_path):
    """``_model``: the env is made for the given family, the command is capped at the thrust
    map's ceiling, the configured ceiling guard is bound; the warm-up step (which traces a
    policy) leaves nothing behind: the last command is the hover command and the controller was
    reset after it."""
    import functools

    from datt.configuration import compose
    from datt.control.pid import PidController
    from datt.deploy.ceiling_guard import keep_altitude_at_ceiling
    from datt.envs.factory import make_env
    from datt.refs import Polygon

    cfg = compose("sim", ["adaptation=l1"])
    families, resets = [], []

    class Pid(PidController):
        def reset(self, env):
            resets.append((len(families), env))
            super().reset(env)

    def make(family):
        families.append(family)
        return make_env(cfg, num_envs=1, seed=0, traj=family)

    p = SimpleNamespace(ceiling_guard=True, ceiling_climb_reserve_mps2=0.5, ceiling_level_gain_per_s=3.0)
    thrust = SimpleNamespace(ceiling_mps2=12.5, p=SimpleNamespace(gravity_mps2=9.8))
    runner = bookkeeping_runner(tmp_path, p=p, thrust=thrust, make_env=make)
    family = Polygon()
    model = runner._model(Pid(), family)
    assert families == [family] and float(model.command_high[0]) == 12.5
    assert isinstance(model.guard, functools.partial) and model.guard.func is keep_altitude_at_ceiling
    assert model.guard.keywords == {"gravity_mps2": 9.8, "climb_reserve_mps2": 0.5, "level_gain_per_s": 3.0}
    assert resets == [(1, model.env), (1, model.env)] and model.last_cmd.tolist() == model.env.hover_action.tolist()


def test_a_reference_on_the_fence_is_inside_it(tmp_path):
    """The fence's bounds are inside (the check is strict): a path touching x = −2, y = ±2 and
    z = 2.5 exactly passes; a point on one bound and outside another names the axis outside."""
    runner = fenced_runner(tmp_path)
    on_fence = [[-2.5, 0.0, 0.0], [-0.5, 2.0, 0.0], [-0.5, -2.0, 1.5], [1.5, 0.0, 0.0], [0.0, 0.0, 0.0]]
    runner._check_reference_in_geofence(table_model(on_fence), None)  # x −2 and +2, y ±2, z 2.5
    for point, text in (
        ([-2.5, 2.1, 0.0], "geofence_max_m: " + LEAVES + " t=0.00 s (y=2.10 m; fence -2.00..2.00 m)"),
        ([1.5, -2.1, 0.0], "geofence_min_m: " + LEAVES + " t=0.00 s (y=-2.10 m; fence -2.00..2.00 m)"),
    ):
        with pytest.raises(_Abort):
            runner._check_reference_in_geofence(table_model([point] * 5), None)
        assert runner.outcome.text == f"preflight failed: deploy.safety.{text}"


class Recording:
    """A controller that records the observation and the state it is given and asks for
    ``action`` ([1, 4]: thrust m/s², body rates rad/s)."""

    def __init__(self, action, builds_observation: bool):
        self.action, self.builds_observation, self.seen = action, builds_observation, []

    def reset(self, env) -> None:
        pass

    def act(self, env, td):
        self.seen.append((td, env.sim.state.pos_m[0].tolist()))
        return self.action.clone()


@pytest.mark.parametrize("builds_observation", [False, True])
def test_a_flight_model_hands_the_controller_the_observation_it_needs_and_clamps_its_command(builds_observation):
    """``FlightModel.act``: a controller that does not build its own observation gets the env's
    (one that does gets None); it sees the predicted state when there is one; no reference lead
    unless asked for; the command below the env's lower bounds is clamped to them and returned
    as floats."""
    import torch

    from datt.configuration import compose
    from datt.deploy.runner import FlightModel
    from datt.envs.factory import make_env
    from datt.refs import Polygon

    cfg = compose("sim", ["adaptation=none"])
    controller = Recording(torch.tensor([[-5.0, -50.0, 50.0, 0.0]]), builds_observation)
    model = FlightModel(lambda family: make_env(cfg, num_envs=1, seed=0, traj=family), controller, Polygon())
    low, high = model.env.action_low, model.command_high
    sent = model.act([0.1, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])
    ((td, pos),) = controller.seen
    assert (td is None) is builds_observation and pos == pytest.approx([0.1, 0.0, 0.0])
    assert model.env._ref_lead_steps == 0.0
    assert sent.dtype == np.float64 and sent.tolist() == pytest.approx(
        [float(low[0]), float(low[1]), float(high[2]), 0.0]
    )
    model.act(
        [0.1, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], predicted=([0.3, 0.0, 0.0], [0, 0, 0], [1.0, 0, 0, 0])
    )
    assert controller.seen[-1][1] == pytest.approx([0.3, 0.0, 0.0])
