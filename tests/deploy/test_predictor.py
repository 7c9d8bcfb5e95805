"""The off-board state predictor against closed-form motions."""

import math

import pytest

from datt.deploy.predictor import PredictorParams, StatePredictor, _acting_at
from datt.errors import ConfigError

LEVEL = (1.0, 0.0, 0.0, 0.0)
G = 9.81


def predictor(latency_s=0.04, policy_delay_s=0.0, k_rate=1.0, **kw) -> StatePredictor:
    params = PredictorParams(enabled=True, latency_s=latency_s, policy_delay_s=policy_delay_s, **kw)
    return StatePredictor(params, G, k_rate, 0.02)


def test_free_flight_under_constant_thrust_is_the_parabola():
    """Thrust g + 2 along z for the whole horizon: z = z0 + v T + a T^2 / 2 with a = 2 m/s²."""
    p = predictor(latency_s=0.06, policy_delay_s=0.02)
    p.record(0.0, [G + 2.0, 0.0, 0.0, 0.0])
    pos, vel, quat = p.predict(1.0, 0.99, (0.0, 0.0, 1.0), (0.5, 0.0, 0.1), LEVEL, (0.0, 0.0, 0.0))
    horizon = 0.01 + 0.06 - 0.02
    assert pos == pytest.approx((0.5 * horizon, 0.0, 1.0 + 0.1 * horizon + horizon**2), abs=1e-9)
    assert vel == pytest.approx((0.5, 0.0, 0.1 + 2.0 * horizon), abs=1e-9)
    assert quat == pytest.approx(LEVEL)


def test_a_yaw_rate_turns_the_attitude_by_rate_times_time():
    p = predictor(latency_s=0.1)
    p.record(0.0, [G, 0.0, 0.0, 1.5])
    _, _, q = p.predict(1.0, 1.0, (0, 0, 1), (0, 0, 0), LEVEL, (0, 0, 0))
    assert 2 * math.atan2(q[3], q[0]) == pytest.approx(1.5 * 0.1, rel=1e-6)


def test_each_command_acts_from_when_it_reaches_the_vehicle():
    """A command sent at t acts from t + latency / 2; before that the previous one does: a step
    from hover to g + 4 sent 10 ms before the estimate arrived acts for the last part only."""
    p = predictor(latency_s=0.04)
    p.record(0.0, [G, 0.0, 0.0, 0.0])
    p.record(0.99, [G + 4.0, 0.0, 0.0, 0.0])
    # the estimate describes t = 1.0 - 0.02; the horizon runs to now + 0.02 = 1.02: 40 ms
    _, vel, _ = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))
    acting_s = 1.02 - (0.99 + 0.02)  # the step acts from 1.01
    assert vel[2] == pytest.approx(4.0 * acting_s, abs=4.0 * 0.005 + 1e-9)  # within one substep


def test_the_disturbance_estimate_is_part_of_the_model():
    p = predictor(latency_s=0.05)
    p.record(0.0, [G, 0.0, 0.0, 0.0])
    _, vel, _ = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (1.0, 0.0, -0.5))
    assert vel == pytest.approx((0.05, 0.0, -0.025), abs=1e-9)


def test_disabled_or_no_commands_returns_the_estimate():
    off = StatePredictor(PredictorParams(enabled=False, latency_s=0.05), G, 0.4, 0.02)
    off.record(0.0, [G + 5, 0, 0, 0])
    assert off.predict(1.0, 0.9, (1, 2, 3), (4, 5, 6), LEVEL, (0, 0, 0)) == ((1, 2, 3), (4, 5, 6), LEVEL)
    empty = predictor()
    assert empty.predict(1.0, 0.9, (1, 2, 3), (0, 0, 0), LEVEL, (0, 0, 0))[0] == (1, 2, 3)


def test_without_a_set_latency_the_round_trip_and_the_trained_delay_are_the_chain():
    """latency = round trip + policy delay: the estimate is half a round trip old on arrival and a
    command acts half a round trip plus the trained delay after it is sent, so a command sent just
    before the estimate arrived does not act before the state the policy will see."""
    p = StatePredictor(PredictorParams(True, latency_s=None, policy_delay_s=0.02), G, 1.0, 0.02, round_trip_s=0.04)
    assert p.latency_s == pytest.approx(0.06) and p.up_s == pytest.approx(0.02)
    p.record(0.0, [G, 0.0, 0.0, 0.0])
    p.record(0.999, [G + 10.0, 0.0, 0.0, 0.0])  # acts from 1.039
    _, vel, _ = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))  # integrates 0.98 .. 1.02
    assert vel == pytest.approx((0.0, 0.0, 0.0), abs=1e-12)
    assert predictor(latency_s=0.03).latency_s == 0.03


def test_the_rate_follows_the_command_with_the_trained_lag():
    """k_rate per 20 ms step (a time constant of -20 ms / ln(1 - k_rate)): the yaw turned is the
    integral of the lagging rate from the moment the step reaches the vehicle."""
    p = predictor(latency_s=0.02, k_rate=0.4, substep_s=0.0005)
    p.record(0.0, [G, 0.0, 0.0, 0.0])
    p.record(0.985, [G, 0.0, 0.0, 2.0])  # reaches the vehicle at 0.995
    # the estimate describes t = 0.99; the horizon runs to 1.01: the step acts for 15 ms
    _, _, q = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))
    tau, acting = -0.02 / math.log(0.6), 0.015
    expected = 2.0 * (acting - tau * (1 - math.exp(-acting / tau)))
    assert 2 * math.atan2(q[3], q[0]) == pytest.approx(expected, rel=0.05)


@pytest.mark.parametrize("key, value", [("latency_s", math.nan), ("latency_s", -0.01), ("substep_s", 0.0)])
def test_settings_are_checked(key, value):
    with pytest.raises(ConfigError, match=f"^deploy.predictor.{key}: must be a finite number"):
        PredictorParams(**{key: value}).validate()


def _lagged(t_switch_s: float, horizon_end_s: float, before: float, after: float, k: float, dt: float) -> float:
    """∫ of a first-order lag (``k`` per ``dt``) that holds ``before`` until ``t_switch_s`` (from 0)
    and then relaxes toward ``after`` until ``horizon_end_s``: the closed form of the
    predictor's per-step lag ``x += (1 - (1 - k)^(h/dt)) (u - x)``."""
    rate = -math.log(1.0 - k) / dt
    span = horizon_end_s - t_switch_s
    return before * t_switch_s + after * span + (before - after) * (1.0 - math.exp(-rate * span)) / rate


def test_thrust_follows_the_command_with_its_lag_from_the_one_acting_when_the_estimate_was_taken():
    """k_thrust 0.5 per 20 ms: thrust starts at the command acting when the estimate was measured
    (g + 2, not hover), holds it 10 ms, then relaxes toward the next command (g − 2) for 30 ms;
    the vertical velocity is the integral of thrust − g (closed form, within the substeps' error)."""
    params = PredictorParams(enabled=True, latency_s=0.04, policy_delay_s=0.0, substep_s=0.0005)
    p = StatePredictor(params, G, 1.0, 0.02, k_thrust=0.5)
    p.record(0.0, [G + 2.0, 0.0, 0.0, 0.0])
    p.record(0.97, [G - 2.0, 0.0, 0.0, 0.0])  # acts from 0.99
    # the estimate was measured at 0.98 (up 20 ms); the horizon ends at now + down = 1.02
    _, vel, _ = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))
    expected = _lagged(0.01, 0.04, 2.0, -2.0, 0.5, 0.02)
    assert vel[2] == pytest.approx(expected, abs=1e-3)  # Euler substeps: 3e-4 off
    # from hover instead of g + 2 the first 10 ms alone would differ by ~3 mm/s
    assert abs(expected - _lagged(0.01, 0.04, 0.0, -2.0, 0.5, 0.02)) > 0.01


def test_the_rate_starts_from_the_command_acting_when_the_estimate_was_taken():
    """k_rate 0.5: a yaw rate of 2 rad/s acting at the estimate's time, then a command of 0 from
    10 ms into the 40 ms horizon: the yaw turned is the integral of the lagged rate."""
    params = PredictorParams(enabled=True, latency_s=0.04, policy_delay_s=0.0, substep_s=0.0005)
    p = StatePredictor(params, G, 0.5, 0.02)
    p.record(0.0, [G, 0.0, 0.0, 2.0])
    p.record(0.97, [G, 0.0, 0.0, 0.0])
    _, _, q = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))
    assert 2 * math.atan2(q[3], q[0]) == pytest.approx(_lagged(0.01, 0.04, 2.0, 0.0, 0.5, 0.02), abs=1e-3)


def test_a_command_acts_from_the_instant_it_reaches_the_vehicle_inclusive():
    p = predictor(latency_s=0.5)
    p.record(0.25, [G + 1.0, 0.0, 0.0, 0.0])
    assert _acting_at(p._acting(0.25), 0.5) is not None  # sent at 0.25, acting from 0.25 + 0.25
    assert _acting_at(p._acting(0.25), 0.4999) is None
    p.record(0.3, [G + 3.0, 0.0, 0.0, 0.0])
    acting = p._acting(0.25)
    assert float(_acting_at(acting, 0.54)[0]) == G + 1.0 and float(_acting_at(acting, 0.55)[0]) == G + 3.0


def test_it_keeps_the_last_64_commands_of_four_values_each():
    p = predictor()
    for k in range(100):
        p.record(0.01 * k, [G + k, 0.1, 0.2, 0.3, 99.0])
    assert len(p.sent) == 64 and p.sent[0][0] == pytest.approx(0.36) and float(p.sent[0][1][0]) == G + 36
    assert all(tuple(a.shape) == (4,) for _, a in p.sent)


def test_an_estimate_from_after_the_horizon_is_returned_as_it_is():
    """Nothing to roll forward when the estimate is newer than the instant the policy's command
    acts (a negative horizon): the estimate itself, as tuples."""
    p = predictor(latency_s=0.04)
    p.record(0.0, [G + 5.0, 1.0, 1.0, 1.0])
    assert p.predict(1.0, 1.5, [1, 2, 3], [4, 5, 6], list(LEVEL), [0, 0, 0]) == ((1, 2, 3), (4, 5, 6), LEVEL)


def test_it_integrates_in_double_precision():
    """Positions of 10 km and a large disturbance lose millimetres in single precision; the
    prediction is exact to 1e-9 (constant hover thrust: z and v change by d only)."""
    p = predictor(latency_s=0.05)
    p.record(0.0, [G, 0.0, 0.0, 0.0])
    pos0, d = (10000.123456789, -10000.987654321, 3.000000001), (0.0, 0.0, 1000.1)
    pos, vel, _ = p.predict(1.0, 1.0, pos0, (0.0, 0.0, 0.0), LEVEL, d)
    assert vel[2] == pytest.approx(1000.1 * 0.05, abs=1e-9)
    assert pos == pytest.approx((pos0[0], pos0[1], pos0[2] + 0.5 * 1000.1 * 0.05**2), abs=1e-9)


def test_commands_that_reach_the_vehicle_only_within_the_horizon_act_from_then_on_from_rest():
    """No command was acting when the estimate was measured (the first one sent acts 30 ms into
    the 40 ms horizon): thrust starts at hover and the rate at zero, nothing changes until the
    command arrives, then both follow it with their lags."""
    params = PredictorParams(enabled=True, latency_s=0.04, policy_delay_s=0.0, substep_s=0.0005)
    p = StatePredictor(params, G, 0.5, 0.02, k_thrust=0.5)
    p.record(0.99, [G + 4.0, 0.0, 0.0, 1.0])  # acts from 1.01; the estimate describes 0.98
    _, vel, q = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))
    assert vel[2] == pytest.approx(_lagged(0.03, 0.04, 0.0, 4.0, 0.5, 0.02), abs=1e-3)
    assert vel[2] > 0.003  # the late command acted
    assert 2 * math.atan2(q[3], q[0]) == pytest.approx(_lagged(0.03, 0.04, 0.0, 1.0, 0.5, 0.02), abs=1e-3)


def test_a_horizon_shorter_than_a_substep_is_one_step_of_its_own_length():
    """4 ms to roll with 5 ms substeps: one step of 4 ms, flown on the command acting at its
    start; a command that arrives 1 ms into it waits for the next step (there is none)."""
    params = PredictorParams(enabled=True, latency_s=0.004, policy_delay_s=0.0, substep_s=0.005)
    p = StatePredictor(params, G, 1.0, 0.02, k_thrust=0.5)
    p.record(0.0, [G + 4.0, 0.0, 0.0, 0.0])
    p.record(0.997, [G - 4.0, 0.0, 0.0, 0.0])  # acts from 0.999; the estimate describes 0.998
    _, vel, _ = p.predict(1.0, 1.0, (0, 0, 0), (0, 0, 0), LEVEL, (0, 0, 0))
    assert vel[2] == pytest.approx(4.0 * 0.004, abs=1e-12)


def test_without_a_known_latency_the_estimate_is_returned_as_it_is():
    """No ``latency_s`` and no round trip measured yet (the link not connected): nothing to roll
    over, even with commands sent."""
    p = StatePredictor(PredictorParams(enabled=True, latency_s=None), G, 0.4, 0.02)
    p.record(0.0, [G + 5.0, 1.0, 0.0, 0.0])
    assert p.predict(1.0, 0.9, (1, 2, 3), (4, 5, 6), LEVEL, (0, 0, 0)) == ((1, 2, 3), (4, 5, 6), LEVEL)


@pytest.mark.parametrize(
    ("latency_s", "round_trip_s", "policy_delay_s", "lead_s"),
    [
        (0.08, 0.04, 0.02, 0.04),  # down = 0.08 - 0.02 = 0.06, less the trained 20 ms
        (0.06, 0.04, 0.02, 0.02),
        (0.03, 0.04, 0.02, 0.0),  # the chain within the trained delay: nothing ahead
        (None, 0.04, 0.03, 0.02),  # null latency: the round trip + the trained delay, down = 0.05
    ],
)
def test_the_reference_lead_is_the_downlink_beyond_the_trained_delay(latency_s, round_trip_s, policy_delay_s, lead_s):
    params = PredictorParams(enabled=True, latency_s=latency_s, policy_delay_s=policy_delay_s)
    pred = StatePredictor(params, G, k_rate=0.4, dt_s=0.02, round_trip_s=round_trip_s)
    assert pred.lead_s == pytest.approx(lead_s, abs=1e-12)


@pytest.mark.parametrize(
    ("overrides", "trained", "enabled", "noted"),
    [
        ((), True, True, False),  # the default (null): on for a policy trained behind it, off-board
        ((), False, False, False),  # ... and off for one trained without it (or a PID)
        (("deploy.predictor.enabled=false",), True, False, True),  # forced off: the policy's note
        (("deploy.predictor.enabled=true",), False, True, False),  # forced on for any controller
        (("deploy.onboard=true",), True, False, False),  # onboard: nothing in flight to predict
        (("deploy.mode=calibrate",), True, False, False),  # the calibration flies the PID only
    ],
)
def test_the_predictor_is_on_off_board_for_a_policy_trained_behind_it(overrides, trained, enabled, noted):
    from datt.configuration import compose
    from datt.deploy.schema import deploy_params
    from datt.tasks.deploy import predictor_enabled, predictor_note

    params = deploy_params(compose("deploy", list(overrides)).deploy)[0]
    assert predictor_enabled(params, trained) is enabled
    params.predictor.enabled = predictor_enabled(params, trained)
    note = predictor_note(params, trained)
    assert (note is not None) == noted
    if noted:
        assert "deploy.predictor.enabled=true" in note and "env.obs.predict_latency" in note


@pytest.mark.parametrize("value", ["maybe", 1, "yes"])
def test_the_predictor_switch_takes_true_false_or_null_only(value):
    from datt.configuration import compose
    from datt.deploy.schema import deploy_params
    from datt.errors import ConfigError

    with pytest.raises(ConfigError) as info:
        deploy_params(compose("deploy", [f"deploy.predictor.enabled={value}"]).deploy)
    assert str(info.value) == f"deploy.predictor.enabled: must be true, false or null, got {value!r}"


def test_the_default_policy_is_the_modes_own_and_off_board_it_flies_behind_the_predictor():
    """``python deploy.py`` at its defaults (``checkpoint: null``): off-board the smooth predictor
    policy, which the null switch then flies behind the predictor; onboard the predictor policy
    (the predictor off there), which the export builds for the app by default; a checkpoint
    given is kept."""
    from datt.configuration import compose
    from datt.control.factory import build_controller
    from datt.deploy.schema import deploy_params
    from datt.tasks.deploy import resolve_checkpoint, resolve_predictor

    cfg = compose("deploy", [])
    assert cfg.checkpoint is None
    resolve_checkpoint(cfg)
    assert cfg.checkpoint == "checkpoints/datt_h10_radio.pt"
    params = deploy_params(cfg.deploy)[0]
    assert params.predictor.enabled is None
    _, merged, labels = build_controller(cfg)
    assert labels["predict_latency"] is True  # read from the checkpoint's training config
    resolve_predictor(params, labels["predict_latency"])
    assert params.predictor.enabled is True

    onboard = compose("deploy", ["deploy.onboard=true"])
    resolve_checkpoint(onboard)
    assert onboard.checkpoint == compose("export", []).checkpoint == "checkpoints/datt_h10_radio.pt"
    onboard_params = deploy_params(onboard.deploy)[0]
    resolve_predictor(onboard_params, build_controller(onboard)[2]["predict_latency"])
    assert onboard_params.predictor.enabled is False
    for mode in ("deploy.onboard=true", "deploy.onboard=false"):
        given = compose("deploy", ["checkpoint=checkpoints/datt_h10_firmware.pt", mode])
        resolve_checkpoint(given)
        assert given.checkpoint == "checkpoints/datt_h10_firmware.pt"


def ticked(tick_s=0.02, latency_s=0.06, round_trip_s=0.04, policy_delay_s=0.02) -> StatePredictor:
    """A vehicle whose loop picks up setpoints every ``tick_s``; its clock reads 0 at host time
    100.0 - transit (an estimate stamped v arrives at 100 + v + 0.02: the radio's one way)."""
    params = PredictorParams(enabled=True, latency_s=latency_s, policy_delay_s=policy_delay_s, vehicle_tick_s=tick_s)
    p = StatePredictor(params, G, 1.0, 0.02, round_trip_s=round_trip_s)
    p.observe(100.0 + 0.5 + 0.02 + 0.003, 0.5)  # a late one (3 ms of jitter) ...
    p.observe(100.0 + 0.52 + 0.02, 0.52)  # ... and the least transit: the clock is the minimum
    return p


def test_estimates_are_placed_by_the_vehicles_clock_and_its_least_transit():
    p = ticked()
    assert p.measured_at(0.6) == pytest.approx(100.6, abs=1e-12)  # 0.6 s on the vehicle: measured at 100.6
    assert p.measured_at(0.0) == pytest.approx(100.0, abs=1e-12)


@pytest.mark.parametrize(
    "arrives, picked",
    [(100.601, 100.62), (100.619, 100.62), (100.62, 100.62), (100.6201, 100.64), (100.6, 100.6)],
)
def test_a_setpoint_is_picked_up_at_the_vehicles_next_loop_tick_inclusive(arrives, picked):
    assert ticked().picked_up(arrives) == pytest.approx(picked, abs=1e-9)


def test_without_a_tick_or_a_clock_a_setpoint_acts_when_it_arrives():
    assert ticked(tick_s=0.0).picked_up(100.613) == 100.613
    no_clock = StatePredictor(PredictorParams(enabled=True, latency_s=0.06, vehicle_tick_s=0.02), G, 1.0, 0.02)
    assert no_clock.picked_up(100.613) == 100.613


def test_a_thrust_step_acts_from_the_tick_after_it_arrives_and_the_horizon_ends_on_a_tick():
    """Thrust g + 4 sent at 100.585 reaches the vehicle at 100.605, is picked up at its tick 100.62,
    acts 20 ms later (the actuation left of the 60 ms chain: 60 - 20 radio - 20 the policy's own).
    The estimate stamped 0.60 was measured at 100.60; the command sent now (100.631) reaches the
    vehicle at 100.651, is picked up at 100.66 and acts from 100.68: the policy's 20 ms earlier,
    100.66, is where the prediction ends. Closed form: v_z = 4 (100.66 - 100.64)."""
    p = ticked()
    p.record(99.0, [G, 0.0, 0.0, 0.0])
    p.record(100.585, [G + 4.0, 0.0, 0.0, 0.0])
    pos, vel, _ = p.predict(100.631, 100.62, (0, 0, 1), (0, 0, 0), LEVEL, (0, 0, 0), vehicle_s=0.60)
    assert vel[2] == pytest.approx(4.0 * 0.02, abs=4.0 * 0.005 + 1e-9)  # within one substep of when it acts
    assert pos[2] == pytest.approx(1.0 + 0.5 * 4.0 * 0.02**2, abs=2e-4)
    assert p.lead_at(100.631) == pytest.approx(100.66 - 100.631, abs=1e-9)
    # the same with a vehicle that acts on arrival: from 100.625, the horizon to 100.651 + 0.02 - 0.02
    free = ticked(tick_s=0.0)
    free.record(99.0, [G, 0.0, 0.0, 0.0])
    free.record(100.585, [G + 4.0, 0.0, 0.0, 0.0])
    _, vel_free, _ = free.predict(100.631, 100.62, (0, 0, 1), (0, 0, 0), LEVEL, (0, 0, 0), vehicle_s=0.60)
    assert vel_free[2] == pytest.approx(4.0 * (100.651 - 100.625), abs=4.0 * 0.005 + 1e-9)
    assert free.lead_at(100.631) == pytest.approx(free.lead_s, abs=1e-12) == pytest.approx(0.02, abs=1e-12)


def test_the_vehicle_tick_is_the_simulated_vehicle_s_step_and_zero_for_a_real_crazyflie():
    """The simulated vehicle picks setpoints up at its 20 ms step; a real Crazyflie's stabilizer
    at 1 kHz: a command acts on arrival (0)."""
    from datt.configuration import compose
    from datt.deploy.schema import deploy_params
    from datt.tasks.deploy import _flight_model_config, _predictor

    for overrides, tick in (
        ([], 0.02),
        (["deploy=crazyflie"], 0.0),
        (["deploy.predictor.vehicle_tick_s=0.01"], 0.01),
    ):
        cfg = compose("deploy", ["deploy.predictor.enabled=true", *overrides])
        params = deploy_params(cfg.deploy)[0]
        assert _predictor(params, _flight_model_config(params, cfg)).vehicle_tick_s == tick


@pytest.mark.parametrize("log_first", [True, False])
def test_the_simulated_vehicle_logs_before_or_after_its_step_as_set(log_first):
    """log_before_step: the estimate of now leaves before the step computes the next dt_s."""
    import time

    from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams

    from . import ports

    server = SimCrazyflie(SimCrazyflieParams(port=next(ports), log_before_step=log_first))
    calls = []
    step = server._physics_step
    server._send_logs = lambda: calls.append("log")
    server._physics_step = lambda: (calls.append("step"), step())
    with server:
        time.sleep(0.1)
    assert len(calls) >= 4
    first = ["log", "step"] if log_first else ["step", "log"]
    assert calls[: 2 * (len(calls) // 2)] == first * (len(calls) // 2)


def test_the_float_attitude_step_is_the_simulators_quaternion_algebra():
    """The plain-float attitude step the predictor (and the simulated vehicle's stabilizer) uses
    against datt.sim.frames' tensor algebra: q * exp(rotvec), normalised, the body z axis and world
    up in the body frame, for
    tilted attitudes and small and large turns."""
    import torch

    from datt.sim.frames import body_z_floats as _body_z
    from datt.sim.frames import (
        quat_body_z,
        quat_exp_rotvec,
        quat_mul,
        quat_normalize,
        quat_rotate_inverse,
        world_up_floats,
    )
    from datt.sim.frames import quat_turned_floats as _turned

    g = torch.Generator().manual_seed(0)
    for scale in (1e-6, 1e-3, 0.3, 2.0):
        q = quat_normalize(torch.randn(4, generator=g, dtype=torch.float64))
        rotvec = scale * torch.randn(3, generator=g, dtype=torch.float64)
        expected = quat_normalize(quat_mul(q, quat_exp_rotvec(rotvec)))
        assert _turned(q.tolist(), rotvec.tolist()) == pytest.approx(expected.tolist(), abs=1e-12)
        assert _body_z(q.tolist()) == pytest.approx(quat_body_z(q).tolist(), abs=1e-12)
        up = quat_rotate_inverse(q.unsqueeze(0), torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))[0]
        assert world_up_floats(q.tolist()) == pytest.approx(up.tolist(), abs=1e-12)  # the ceiling guard's


@pytest.mark.parametrize("earliest", [100.6, 100.6049, 100.605, 100.6051, 100.619, 100.63])
def test_the_host_tick_is_placed_so_its_command_lands_half_way_between_vehicle_ticks(earliest):
    """Vehicle ticks at 100.00 + k 0.02 on the host's clock; a tick started at t sends at t + 3 ms,
    the command arrives 20 ms later: t + 0.023 must be 100.01 + k 0.02, the first such t >= earliest."""
    p = ticked()
    slot = p.send_slot(earliest)
    assert earliest <= slot < earliest + 0.02
    arrives = slot + p.p.compute_s + p.up_s
    assert ((arrives - 100.0) / 0.02) % 1.0 == pytest.approx(0.5, abs=1e-6)
    assert ticked(tick_s=0.0).send_slot(earliest) == earliest


def test_before_the_first_recorded_command_acts_the_vehicle_coasts_at_hover_thrust():
    """The only command recorded acts after the horizon ends: the 51 ms from the estimate's
    measurement (100.60) to the horizon's end (sent 100.631, arrives 100.651, acts 20 ms later,
    less the policy's 20 ms) pass at hover thrust with no rates: the position moves with the
    velocity, nothing else changes (the time is not skipped)."""
    p = ticked(tick_s=0.0)
    p.record(100.631, [G + 4.0, 2.0, -1.0, 0.5])
    pos, vel, quat = p.predict(100.631, 100.62, (0.0, 0.0, 1.0), (1.0, -0.5, 0.2), LEVEL, (0, 0, 0), vehicle_s=0.60)
    assert pos == pytest.approx((1.0 * 0.051, -0.5 * 0.051, 1.0 + 0.2 * 0.051), abs=1e-9)
    assert vel == pytest.approx((1.0, -0.5, 0.2), abs=1e-12) and quat == pytest.approx(LEVEL, abs=1e-12)


def test_an_estimate_is_placed_by_its_timestamp_not_by_its_arrival():
    """The estimate stamped 0.62 arrives 10 ms later than the least transit (at 100.65, not 100.64):
    it was measured at 100.62 all the same, so the horizon to the same end (100.681: sent 100.661,
    arrives 100.681, acts 20 ms later, less the policy's 20 ms) is 61 ms, not 51 ms."""
    p = ticked(tick_s=0.0)
    p.record(99.0, [G, 0.0, 0.0, 0.0])
    pos, _, _ = p.predict(100.661, 100.65, (0.0, 0.0, 1.0), (1.0, 0.0, 0.0), LEVEL, (0, 0, 0), vehicle_s=0.62)
    assert pos[0] == pytest.approx(0.061, abs=1e-9)


@pytest.mark.parametrize(("tick_s", "round_trip_s"), [(0.02, 0.03), (0.015, 0.04)])
def test_ticks_and_slots_follow_the_vehicles_clock_for_any_tick_and_round_trip(tick_s, round_trip_s):
    """Ticks that do not divide a second and a one-way leg that is not a whole number of half
    ticks: the estimates (transit 20 ms) place the vehicle's tick 0 at 100.02 − up on the host's
    clock; a setpoint is picked up at the next tick, and the host tick's command arrives half-way."""
    params = PredictorParams(enabled=True, latency_s=0.06, policy_delay_s=0.02, vehicle_tick_s=tick_s)
    p = StatePredictor(params, G, 1.0, 0.02, round_trip_s=round_trip_s)
    for v in (0.5, 0.52, 0.54):
        p.observe(100.0 + v + 0.02, v)
    anchor = 100.02 - round_trip_s / 2
    assert p.measured_at(0.0) == pytest.approx(anchor, abs=1e-12)
    for arrives in (100.3, 100.3071, 100.61):
        picked = p.picked_up(arrives)
        assert arrives <= picked + 1e-9 < arrives + tick_s
        ticks = (picked - anchor) / tick_s
        assert ticks == pytest.approx(round(ticks), abs=1e-6)  # on the vehicle's tick grid
    for earliest in (100.6, 100.6049, 100.61):
        slot = p.send_slot(earliest)
        assert earliest <= slot < earliest + tick_s
        arrives = slot + p.p.compute_s + round_trip_s / 2
        assert ((arrives - anchor) / tick_s) % 1.0 == pytest.approx(0.5, abs=1e-6)


@pytest.mark.parametrize("rate_hz", [50.0, 100.0])
def test_the_runner_hands_the_controller_the_prediction_and_its_reference_lead(rate_hz):
    """Behind the predictor a tick's controller sees the predicted state (relative to the origin)
    and reads its reference window ``lead_at(now)`` ahead, in ticks of the flight's rate; the
    measured state still goes with it (for the adaptation). Without it: the measurement, no lead."""
    from types import SimpleNamespace

    import numpy as np

    from datt.deploy.runner import FlightRunner

    runner = FlightRunner.__new__(FlightRunner)  # the tick's wiring alone: no link, no vehicle
    runner.p = SimpleNamespace(rate_hz=rate_hz)
    runner._excitation = None
    runner.predictor = predictor(latency_s=0.07)
    runner.predictor.round_trip_s = 0.04  # the lead is the down-link: 70 - 20 ms
    runner.predictor.record(0.0, [12.0, 0.5, 0.0, 0.0])
    calls = []
    model = SimpleNamespace(d_hat=[0.0, 0.0, 0.0], act=lambda *a: calls.append(a) or np.zeros(4), last_state_t=None)
    state = SimpleNamespace(
        t_s=0.01, pos_m=(1.0, 2.0, 1.5), vel_mps=(0.2, 0.0, 0.0), quat=(1.0, 0.0, 0.0, 0.0), vehicle_s=None
    )
    origin = np.array([1.0, 1.0, 0.0])
    runner._act(model, state, 0.03, origin, 0, predict=True)
    pos, vel, quat, predicted, lead_steps = calls[-1]
    assert pos.tolist() == [0.0, 1.0, 1.5] and vel == state.vel_mps and quat == state.quat
    want = runner.predictor.predict(0.03, state.t_s, state.pos_m, state.vel_mps, state.quat, [0.0] * 3, None)
    assert np.allclose(predicted[0], np.array(want[0]) - origin) and predicted[0][0] != pos[0]
    assert lead_steps == pytest.approx(runner.predictor.lead_at(0.03) * rate_hz) and lead_steps > 0
    fresh = SimpleNamespace(**{**vars(state), "t_s": 0.03})  # the same one again would be held (FlightModel.hold)
    runner._act(model, fresh, 0.05, origin, 1, predict=False)
    assert calls[-1][3:] == (None, 0.0)
