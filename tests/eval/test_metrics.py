import math

import torch

from datt.eval.metrics import episode_errors, format_error, summarize


def test_episode_error_hand_computed_with_crash():
    err = torch.tensor([[0.1, 0.2, 0.3, 0.4], [1.0, 1.0, 5.0, 9.0]])
    crashed_at = torch.tensor([4, 1])  # drone 0 flew all 4 steps, drone 1 crashed at step 1
    e = episode_errors(err, crashed_at)
    assert torch.allclose(e, torch.tensor([0.25, 1.0]))
    s = summarize(e, crashed_at < 4)
    assert s["crashes"] == 1 and s["episodes"] == 2
    assert math.isclose(s["mean_m"], 0.25) and s["std_m"] == 0.0
    assert format_error(s) == "0.250 ± 0.000 (1 crashed)"


def test_all_crashed_is_failed():
    s = summarize(torch.tensor([1.0, 2.0]), torch.tensor([True, True]))
    assert math.isnan(s["mean_m"]) and format_error(s) == "failed"


def test_the_crash_step_counts_in_the_episode_error():
    """``crashed_at`` is the step at which the drone terminated; that step's error counts."""
    e = episode_errors(torch.tensor([[1.0, 3.0, 100.0]]), torch.tensor([1]))
    assert e.item() == 2.0
