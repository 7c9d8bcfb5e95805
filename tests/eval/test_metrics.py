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


def test_crash_at_the_first_step_is_that_steps_error():
    err = torch.tensor([[0.75, 5.0, 5.0]])
    assert episode_errors(err, torch.tensor([0])).tolist() == [0.75]


def test_summary_statistics_and_records():
    errors = torch.tensor([1.0, 3.0, 0.12345678, 9.0])
    crashed = torch.tensor([False, False, True, True])
    row = summarize(errors, crashed)
    assert row["mean_m"] == 2.0 and row["std_m"] == 1.0  # population std of the non-crashed [1, 3]
    assert row["crashes"] == 2 and row["episodes"] == 4
    assert row["per_episode_m"] == [1.0, 3.0, 0.123457, 9.0]
    assert row["per_episode_crashed"] == [False, False, True, True]
    assert all(type(c) is bool for c in row["per_episode_crashed"])
    one = summarize(torch.tensor([0.5, 2.0]), torch.tensor([False, True]))
    assert one["mean_m"] == 0.5 and one["std_m"] == 0.0
    none = summarize(torch.tensor([0.5]), torch.tensor([True]))
    assert math.isnan(none["mean_m"]) and math.isnan(none["std_m"])


def test_format_error_reads_as_the_tables_do():
    assert format_error({"mean_m": 0.05, "std_m": 0.01, "crashes": 0, "episodes": 10}) == "0.050 ± 0.010"
    assert format_error({"mean_m": 0.05, "std_m": 0.01, "crashes": 2, "episodes": 10}) == "0.050 ± 0.010 (2 crashed)"
    assert format_error({"mean_m": math.nan, "std_m": math.nan, "crashes": 3, "episodes": 3}) == "failed"
