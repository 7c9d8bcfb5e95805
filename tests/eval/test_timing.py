"""Inference timing: the warm-up steps are excluded; what is timed is the controller side."""

import pytest

from datt.control.base import HoverController
from datt.eval.timing import step_times_ms, summarize_ms


class FakeClock:
    """Advances 1 ms per reading, plus whatever a controller adds (no wall-clock involved)."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t


class SlowStart(HoverController):
    """Costs 100 ms on its first 5 calls after reset (compilation, caches), then 1 ms."""

    def __init__(self, clock):
        self.clock, self.calls = clock, 0

    def reset(self, env):
        self.calls = 0

    def act(self, env, td):
        self.calls += 1
        self.clock.t += 0.1 if self.calls <= 5 else 0.001
        return super().act(env, td)


def test_warmup_is_excluded(make_tracking_env):
    clock = FakeClock()
    env = make_tracking_env(["disturbance=none"], n=1)
    times = step_times_ms(env, SlowStart(clock), steps=10, warmup_steps=4, clock=clock)
    # the act() inside reset is call 1, so timed calls 2..5 are warm-up steps 0..3: all excluded
    assert times == pytest.approx([1.0] * 10)
    times = step_times_ms(env, SlowStart(clock), steps=10, warmup_steps=2, clock=clock)
    assert times[:2] == pytest.approx([100.0, 100.0]) and times[2:] == pytest.approx([1.0] * 8)
    stats = summarize_ms(times)
    assert stats["median_ms"] == pytest.approx(1.0) and stats["steps"] == 10


def test_bad_arguments(make_tracking_env):
    env = make_tracking_env(n=1)
    with pytest.raises(ValueError, match="steps"):
        step_times_ms(env, HoverController(), steps=0)
