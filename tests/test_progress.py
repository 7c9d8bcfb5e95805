"""Progress lines (datt.progress): when a line is due, what it says, and that a run's lines
reach its log file. The clock is the test's: nothing here waits or depends on the machine."""

import logging

import pytest

from datt.progress import ProgressReport, duration


class Clock:
    def __init__(self):
        self.now = 1000.0

    def __call__(self):
        return self.now


def report(clock, **kw):
    kw.setdefault("every_s", 30.0)
    return ProgressReport("train", 10_000, "frames", clock=clock, **kw)


def lines_of(caplog):
    return [r.getMessage() for r in caplog.records if r.name == "datt.progress"]


def test_a_line_at_the_first_step_then_one_per_interval_and_the_last(caplog):
    caplog.set_level(logging.INFO)
    clock = Clock()
    progress = report(clock)
    progress.update(1_000)  # first: due
    for done, dt in ((2_000, 10.0), (3_000, 19.9), (4_000, 0.1), (5_000, 29.9), (6_000, 0.1)):
        clock.now += dt
        progress.update(done)
    clock.now += 1.0
    progress.update(10_000)  # the last: due whatever the interval
    lines = lines_of(caplog)
    assert [line.split(", ")[0] for line in lines] == [
        "train: 1,000 / 10,000 frames (10.0 %)",
        "train: 4,000 / 10,000 frames (40.0 %)",  # 30.0 s after the first line
        "train: 6,000 / 10,000 frames (60.0 %)",  # 30.0 s after that one
        "train: 10,000 / 10,000 frames (100.0 %)",
    ]
    assert progress.lines == 4


def test_rate_and_eta_count_what_this_process_did(caplog):
    """A resumed run at 4,000 frames: its rate is its own frames over its own time."""
    caplog.set_level(logging.INFO)
    clock = Clock()
    progress = report(clock, every_s=0.0)
    progress.update(4_000)
    clock.now += 10.0
    progress.update(6_000, err="0.086 m")
    assert lines_of(caplog)[-1] == "train: 6,000 / 10,000 frames (60.0 %), 200 frames/s, ETA 20 s, err 0.086 m"


def test_the_first_line_has_no_rate_and_a_finished_one_no_eta(caplog):
    caplog.set_level(logging.INFO)
    clock = Clock()
    progress = report(clock, every_s=0.0)
    progress.update(0)
    clock.now += 4.0
    progress.update(10_000)
    first, last = lines_of(caplog)
    assert first == "train: 0 / 10,000 frames (0.0 %)"
    assert last == "train: 10,000 / 10,000 frames (100.0 %), 2,500 frames/s"


def test_a_slow_loop_shows_its_rate_with_decimals(caplog):
    caplog.set_level(logging.INFO)
    clock = Clock()
    progress = ProgressReport("eval", 3, "seeds", every_s=0.0, clock=clock)
    progress.update(1)
    clock.now += 40.0
    progress.update(2, seed="1")
    assert lines_of(caplog)[-1] == "eval: 2 / 3 seeds (66.7 %), 0.03 seeds/s, ETA 40 s, seed 1"


def test_switched_off_it_writes_nothing(caplog):
    caplog.set_level(logging.INFO)
    progress = report(Clock(), enabled=False)
    progress.update(1)
    progress.update(10_000)
    assert lines_of(caplog) == [] and progress.lines == 0


@pytest.mark.parametrize(
    "seconds, text", [(0, "0 s"), (12.4, "12 s"), (59.6, "1 min 00 s"), (348, "5 min 48 s"), (3720, "1 h 02 min")]
)
def test_durations_read_as_a_person_writes_them(seconds, text):
    assert duration(seconds) == text


def test_a_runs_lines_reach_its_log_file_and_the_console_unwrapped(tmp_path, monkeypatch, capsys):
    """train.py: every line it prints (the run dir, progress, the evaluation table) is also in
    ``<run dir>/train.log`` with its time; on the console a line is never cut at 80 columns."""
    from .test_faults import run_cli
    from .train.test_training import TINY

    run = tmp_path / "r"
    args = [*TINY, "train.progress=true", "train.progress_every_s=0", "train.total_frames=2048", f"hydra.run.dir={run}"]
    args = [a for a in args if a != "train.progress=false"]
    code, lines, out = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    log = (run / "train.log").read_text()
    progress = [line for line in out.splitlines() if line.startswith("train: ")]
    assert [p.split(", ")[0] for p in progress] == [
        "train: 1,024 / 2,048 frames (50.0 %)",
        "train: 2,048 / 2,048 frames (100.0 %)",
    ]
    printed = [line for line in out.splitlines() if line.strip()]
    assert f"run dir: {run}" in printed
    assert any(len(line) > 80 for line in printed)  # the evaluation table, whole
    for line in printed:
        assert line in log, line
