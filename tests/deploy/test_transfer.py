"""The transfer test (issue 18): the deploy-grade policy against the strict simulated Crazyflie
with 40 ms radio round trip, motors 10 % weak, the vehicle 10 % heavy and 2 % packet loss lands,
with a star error within 1.5x of eval.py's for the same policy. Real time (~25 s): slow."""

import pytest

pytest.importorskip("cflib")

from datt.tasks.transfer import CONDITIONS, eval_star_error, fly  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.flight]


def test_deploy_grade_policy_lands_within_1_5x_of_its_eval_error(tmp_path):
    checkpoint = "checkpoints/datt_h10_deploy.pt"
    eval_err = eval_star_error(checkpoint, tmp_path / "eval")
    flight = fly(checkpoint, CONDITIONS, tmp_path / "flight", seed=0)
    assert flight["outcome"].startswith("landed"), flight["outcome"]
    assert flight["track_error_m"] <= 1.5 * eval_err, (flight["track_error_m"], eval_err)
