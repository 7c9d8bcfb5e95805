"""The transfer test: policies against the strict simulated Crazyflie with 40 ms radio round
trip, motors 10 % weak, the vehicle 10 % heavy and 2 % packet loss, compared with eval.py's star
error for the same policy. Real time (~25 s a flight): slow.

What they pin (docs/results/deploy_studies.md has the figures of benchmarks/transfer.py, on the simulated
vehicle's real timing; a flight's error is eval.py's, each estimate against the reference when
it was measured): the smooth policy (what ``deploy.py`` flies off-board) lands behind the state
predictor within 1.5x of its eval error; the firmware-grade
policy lands off-board without it (its error there varies too much to pin) and flies onboard
within 1.3x of its eval error without a calibration flight (the hover trim: 1.20-1.31x measured)
and within 2x after one; the deploy-grade and the shipped policy land onboard after a
calibration flight too."""

import pytest

pytest.importorskip("cflib")

from datt.tasks.transfer import CONDITIONS, calibrate, eval_star_error, fly  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.flight]

FIRMWARE_GRADE = "checkpoints/datt_h10_firmware.pt"


def test_the_firmware_grade_policy_lands_off_board_without_the_predictor(tmp_path):
    """It lands; its error is not pinned (5.4-7.6x landed, 1 of 3 KILLed, on the real timing)."""
    flight = fly(FIRMWARE_GRADE, CONDITIONS, tmp_path / "flight", seed=0, extra=("deploy.predictor.enabled=false",))
    # a landing (an early one too: a 2-core machine can stall the host's streams for ~250 ms)
    assert flight["outcome"].startswith("landed"), flight["outcome"]


def test_the_off_board_policy_lands_behind_the_predictor_within_1_5x(tmp_path):
    """What ``deploy.py`` flies off-board at its defaults (the policy trained on a radio that loses
    setpoints, behind the state predictor): it lands, within 1.5x of its eval error
    (docs/results/transfer_grid.md)."""
    checkpoint = "checkpoints/datt_h10_radio.pt"
    eval_err = eval_star_error(checkpoint, tmp_path / "eval")
    flight = fly(checkpoint, CONDITIONS, tmp_path / "flight", seed=0)
    assert flight["outcome"] == "landed", flight["outcome"]
    assert flight["track_error_m"] <= 1.5 * eval_err, (flight["track_error_m"], eval_err)


def test_onboard_without_a_calibration_flight_within_1_3x(tmp_path):
    """``deploy.onboard=true`` at the defaults on the heavy, weak vehicle: the hover trim rescales
    the map the app flies; within 1.3x of eval.py's star error."""
    eval_err = eval_star_error(FIRMWARE_GRADE, tmp_path / "eval")
    flight = fly(FIRMWARE_GRADE, CONDITIONS, tmp_path / "flight", seed=0, extra=("deploy.onboard=true",))
    assert flight["outcome"] == "landed (onboard)", flight["outcome"]
    assert flight["track_error_m"] <= 1.3 * eval_err, (flight["track_error_m"], eval_err)


@pytest.mark.parametrize(
    "checkpoint, bound",
    # 1.17-1.44x measured alone; two flights beside each other on 2 cores reached past 1.5x
    [(FIRMWARE_GRADE, 2.0), ("checkpoints/datt_h10_deploy.pt", None), ("checkpoints/datt_h10.pt", None)],
    ids=["firmware_grade", "deploy_grade", "shipped"],
)
def test_onboard_after_a_calibration_flight(tmp_path, checkpoint, bound):
    """The deploy procedure with a calibration flight, then the policy in the vehicle's app, under
    the transfer conditions: it lands; the firmware-grade policy within 2x of eval.py's star error."""
    eval_err = eval_star_error(checkpoint, tmp_path / "eval")
    fitted = calibrate(CONDITIONS, tmp_path / "calibration")
    flight = fly(checkpoint, CONDITIONS, tmp_path / "flight", seed=0, extra=("deploy.onboard=true", *fitted))
    assert flight["outcome"] == "landed (onboard)", flight["outcome"]
    if bound is not None:
        assert flight["track_error_m"] <= bound * eval_err, (flight["track_error_m"], eval_err)
