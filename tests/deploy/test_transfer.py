"""The transfer test: policies against the strict simulated Crazyflie with 40 ms radio round
trip, motors 10 % weak, the vehicle 10 % heavy and 2 % packet loss, compared with eval.py's star
error for the same policy. Real time (~25 s a flight): slow.

What they pin (docs/deploy.md has the figures of benchmarks/transfer.py): the deploy-grade policy
lands off-board (its error there varies too much to pin: 1.5x is not met off-board) and, after a
calibration flight, flies onboard within 1.5x (1.41-1.44x measured); the shipped policy, trained
without the thrust ceiling or latency, lands onboard after a calibration flight too."""

import pytest

pytest.importorskip("cflib")

from datt.tasks.transfer import CONDITIONS, calibrate, eval_star_error, fly  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.flight]


def test_deploy_grade_policy_lands_off_board(tmp_path):
    """It lands (11 of 11 flights landed on 2026-12-02); its error is not pinned: 8 of those 11
    were 0.13-0.20 m, two drifted to 0.44-0.46 m and one sank to the ground (1.09 m)."""
    flight = fly("checkpoints/datt_h10_deploy.pt", CONDITIONS, tmp_path / "flight", seed=0)
    # a landing (an early one too: a 2-core machine can stall the host's streams for ~250 ms)
    assert flight["outcome"].startswith("landed"), flight["outcome"]


@pytest.mark.parametrize(
    "checkpoint, bound",
    [("checkpoints/datt_h10_deploy.pt", 1.5), ("checkpoints/datt_h10.pt", None)],
    ids=["deploy_grade", "shipped"],
)
def test_onboard_after_a_calibration_flight(tmp_path, checkpoint, bound):
    """The deploy procedure (calibration flight, then the policy in the vehicle's app) under the
    transfer conditions: it lands; the deploy-grade policy within 1.5x of eval.py's star error."""
    eval_err = eval_star_error(checkpoint, tmp_path / "eval")
    fitted = calibrate(CONDITIONS, tmp_path / "calibration")
    flight = fly(checkpoint, CONDITIONS, tmp_path / "flight", seed=0, extra=("deploy.onboard=true", *fitted))
    assert flight["outcome"] == "landed (onboard)", flight["outcome"]
    if bound is not None:
        assert flight["track_error_m"] <= bound * eval_err, (flight["track_error_m"], eval_err)
