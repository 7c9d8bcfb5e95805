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


def test_an_episode_diverged_when_its_last_second_averages_above_the_limit_or_it_crashed():
    """The paper's "failed: the drone diverges from the reference", from its definition: the
    last second (50 steps of 0.02 s) of the error against the limit, or a crash."""
    from datt.eval.metrics import diverged_episodes

    t = 120
    err = torch.zeros(5, t)
    err[0, -50:] = 1.01  # the last second just above 1 m
    err[1, -50:] = 0.99  # just below
    err[2, :-50] = 50.0  # far off early, back on the track for the last second
    err[3, -49:] = 1.5  # 49 steps at 1.5 and one at 0: the mean of the window 1.47 > 1
    err[4] = 0.1  # on the track, but it crashed
    crashed_at = torch.tensor([t, t, t, t, 30])
    got = diverged_episodes(err, crashed_at, dt_s=0.02, threshold_m=1.0).tolist()
    assert got == [True, False, False, True, True]
    err[3, -50] = -100.0  # the window is exactly 50 steps: the 50th from the end counts
    assert not diverged_episodes(err, crashed_at, dt_s=0.02, threshold_m=1.0)[3]
    short = diverged_episodes(torch.full((1, 10), 2.0), torch.tensor([10]), dt_s=0.02, threshold_m=1.0)
    assert short.tolist() == [True]  # an episode shorter than the window is judged on all of it


def test_a_run_failed_when_most_of_its_episodes_diverged():
    from datt.eval.metrics import run_failed

    errors, crashed = torch.tensor([0.1, 3.0, 4.0, 5.0]), torch.zeros(4, dtype=torch.bool)
    half = summarize(errors, crashed, leave_out_crashed=False, diverged=torch.tensor([False, False, True, True]))
    most = summarize(errors, crashed, leave_out_crashed=False, diverged=torch.tensor([False, True, True, True]))
    assert half["diverged"] == 2 and half["per_episode_diverged"] == [False, False, True, True]
    assert not run_failed(half) and run_failed(most)
    assert format_error(most) == "3.025 ± 1.831 (3 diverged) failed"
    assert format_error(half) == "3.025 ± 1.831 (2 diverged)"
    # records written before the count: failed when every episode crashed
    assert run_failed({"episodes": 2, "crashes": 2}) and not run_failed({"episodes": 2, "crashes": 1})
