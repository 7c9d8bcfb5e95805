"""The off-board state predictor against closed-form motions."""

import math

import pytest

from datt.deploy.predictor import PredictorParams, StatePredictor
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
    assert p._command_at(0.5, 0.25) is not None  # sent at 0.25, acting from 0.25 + 0.25
    assert p._command_at(0.4999, 0.25) is None
    p.record(0.3, [G + 3.0, 0.0, 0.0, 0.0])
    assert float(p._command_at(0.54, 0.25)[0]) == G + 1.0 and float(p._command_at(0.55, 0.25)[0]) == G + 3.0


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
    ("overrides", "trained", "noted"),
    [
        ((), True, True),  # off-board without the predictor it was trained behind
        (("deploy.predictor.enabled=true",), True, False),
        (("deploy.onboard=true",), True, False),  # onboard: nothing in flight to predict
        (("deploy.mode=calibrate",), True, False),  # the calibration flies the PID only
        ((), False, False),
    ],
)
def test_a_policy_trained_behind_the_predictor_says_so_when_flown_off_board_without_it(overrides, trained, noted):
    from datt.configuration import compose
    from datt.deploy.schema import deploy_params
    from datt.tasks.deploy import predictor_note

    params = deploy_params(compose("deploy", list(overrides)).deploy)[0]
    note = predictor_note(params, trained)
    assert (note is not None) == noted
    if noted:
        assert "deploy.predictor.enabled=true" in note and "env.obs.predict_latency" in note
