"""The transfer test (issue 18): policies against the strict simulated Crazyflie with 40 ms radio
round trip, motors 10 % weak, the vehicle 10 % heavy and 2 % packet loss, compared with eval.py's
star error for the same policy. Real time (~25 s a flight): slow.

What they pin (docs/deploy.md has the figures): the deploy-grade policy lands off-board, where the
shipped one is KILLed, within 4x of its eval error (the issue's 1.5x is not met off-board:
2.3-2.9x measured); after a calibration flight both policies pass 1.5x onboard."""

import pytest

pytest.importorskip("cflib")

from datt.tasks.transfer import CONDITIONS, calibrate, eval_star_error, fly  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.flight]


def test_deploy_grade_policy_lands_off_board(tmp_path):
    checkpoint = "checkpoints/datt_h10_deploy.pt"
    eval_err = eval_star_error(checkpoint, tmp_path / "eval")
    flight = fly(checkpoint, CONDITIONS, tmp_path / "flight", seed=0)
    assert flight["outcome"] == "landed", flight["outcome"]
    assert flight["track_error_m"] <= 4.0 * eval_err, (flight["track_error_m"], eval_err)


@pytest.mark.parametrize(
    "checkpoint",
    ["checkpoints/datt_h10_iid.pt", "checkpoints/datt_h10_deploy.pt"],
    ids=["former_shipped", "deploy_grade"],
)
def test_onboard_after_a_calibration_flight_passes(tmp_path, checkpoint):
    """The deploy procedure (calibration flight, then the policy in the vehicle's app) under the
    transfer conditions: it lands within 1.5x of eval.py's star error."""
    eval_err = eval_star_error(checkpoint, tmp_path / "eval")
    fitted = calibrate(CONDITIONS, tmp_path / "calibration")
    flight = fly(checkpoint, CONDITIONS, tmp_path / "flight", seed=0, extra=("deploy.onboard=true", *fitted))
    assert flight["outcome"] == "landed (onboard)", flight["outcome"]
    assert flight["track_error_m"] <= 1.5 * eval_err, (flight["track_error_m"], eval_err)
