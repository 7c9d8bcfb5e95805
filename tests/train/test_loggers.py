"""The run loggers on their own: metrics.csv rows and columns, a resume's truncation, the logger
settings' rules, the evaluation's summary keys and table rows, and wandb's defaults."""

from __future__ import annotations

import csv
import inspect
import math
import os

import pytest
import torch

from datt.configuration import structured
from datt.errors import ConfigError
from datt.train.loggers import (
    RESULT_COLUMNS,
    CsvLogger,
    LoggerParams,
    MultiLogger,
    WandbLogger,
    eval_summary,
    result_rows,
)


def _read(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_csv_rows_carry_their_step_and_every_column_ever_logged(tmp_path):
    log = CsvLogger(tmp_path)
    log.log({"a": 1.5, "b": torch.tensor(2.0)}, step=10)  # a tensor is written as its number
    log.log({"b": 3.0, "c": float("nan")}, step=20)  # a new column later: the header grows
    rows = _read(tmp_path / "metrics.csv")
    assert list(rows[0]) == ["step", "a", "b", "c"]
    assert rows[0] == {"step": "10", "a": "1.5", "b": "2.0", "c": ""}
    assert rows[1]["step"] == "20" and rows[1]["a"] == "" and rows[1]["b"] == "3.0" and rows[1]["c"] == "nan"
    assert CsvLogger(tmp_path, "other.csv").rows == [] and not (tmp_path / "other.csv").exists()


def test_a_resumed_csv_keeps_its_rows_up_to_the_checkpoint_and_appends(tmp_path):
    first = CsvLogger(tmp_path)
    for step in (10, 20, 30):
        first.log({"x": step / 10}, step=step)
    again = CsvLogger(tmp_path)  # a resume reads the file back
    assert [r["step"] for r in again.rows] == ["10", "20", "30"]
    again.keep_until(20)  # the checkpoint was written at step 20: row 30 is trained again
    assert [r["step"] for r in _read(tmp_path / "metrics.csv")] == ["10", "20"]
    again.log({"x": 3.5}, step=35)
    assert [r["step"] for r in _read(tmp_path / "metrics.csv")] == ["10", "20", "35"]
    mtime = (tmp_path / "metrics.csv").stat().st_mtime_ns
    again.keep_until(100)  # nothing after it: the file is left alone
    assert (tmp_path / "metrics.csv").stat().st_mtime_ns == mtime


def test_multi_logger_passes_every_call_to_each_logger(tmp_path):
    a, b = CsvLogger(tmp_path, "a.csv"), CsvLogger(tmp_path, "b.csv")
    both = MultiLogger([a, b])
    both.log({"x": 1.0}, step=5)
    both.results({"frames": 5})
    both.close()
    assert _read(tmp_path / "a.csv") == _read(tmp_path / "b.csv") == [{"step": "5", "x": "1.0"}]


@pytest.mark.parametrize(
    "node, message",
    [
        ({"wandb": True, "mode": None, "project": "datt"}, "logger.mode: must be one of offline, online, disabled"),
        ({"wandb": True, "mode": "offline", "project": ""}, "logger.project: must name the wandb project"),
        ({"wandb": False, "mode": "sometimes", "project": "datt"}, "logger.mode: "),
    ],
    ids=["wandb_without_mode", "wandb_without_project", "unknown_mode"],
)
def test_bad_logger_settings_are_one_line(node, message):
    with pytest.raises(ConfigError, match="^" + message.replace("(", r"\(").replace(")", r"\)")):
        structured(LoggerParams, node, "logger")


def test_csv_only_needs_none_of_the_wandb_keys():
    params = structured(LoggerParams, {"wandb": False}, "logger")
    assert params.mode is None and params.project is None and params.tags == []


def test_the_evaluation_becomes_summary_keys_and_table_rows():
    conditions = {
        "clean": {"groups": {"zigzag": {"mean_m": 0.05, "std_m": 0.01, "crashes": 0, "episodes": 10}}},
        "brownian": {
            "groups": {
                "star": {"mean_m": math.nan, "std_m": math.nan, "crashes": 10, "episodes": 10},
                "smooth": {"mean_m": 0.02, "episodes": 10},
            }
        },
        "empty": {},
    }
    summary = eval_summary(conditions)
    assert summary == {
        "eval/clean/zigzag/mean_m": 0.05,
        "eval/clean/zigzag/std_m": 0.01,
        "eval/clean/zigzag/crashes": 0,
        "eval/clean/zigzag/episodes": 10,
        "eval/brownian/star/mean_m": None,  # every episode crashed: no mean, null as in metrics.json
        "eval/brownian/star/std_m": None,
        "eval/brownian/star/crashes": 10,
        "eval/brownian/star/episodes": 10,
        "eval/brownian/smooth/mean_m": 0.02,
        "eval/brownian/smooth/episodes": 10,
    }
    assert list(eval_summary(conditions, prefix="final"))[0] == "final/clean/zigzag/mean_m"
    assert RESULT_COLUMNS == ["condition", "group", "mean_m", "std_m", "crashes", "episodes"]
    rows = result_rows(conditions)
    assert rows[0] == ["clean", "zigzag", 0.05, 0.01, 0, 10]
    assert rows[2] == ["brownian", "smooth", 0.02, None, None, 10]
    assert len(rows) == 3


def test_wandb_runs_default_to_the_datt_project_offline():
    params = inspect.signature(WandbLogger).parameters
    assert params["project"].default == "datt" and params["mode"].default == "offline"
    assert params["job_type"].default == "train" and params["run_id"].default is None


def test_a_wandb_run_keeps_the_console_quiet(tmp_path, monkeypatch):
    """wandb's own banner and sync lines would interleave with the progress bar: silent unless the
    user sets WANDB_SILENT themselves."""
    pytest.importorskip("wandb")
    monkeypatch.delenv("WANDB_SILENT", raising=False)
    run = WandbLogger(tmp_path, {"seed": 0}, mode="offline", name="quiet")
    try:
        assert os.environ["WANDB_SILENT"] == "true"
    finally:
        run.close()
    monkeypatch.setenv("WANDB_SILENT", "false")
    WandbLogger(tmp_path / "b", {}, mode="disabled").close()
    assert os.environ["WANDB_SILENT"] == "false"  # the user's choice stands


def test_a_closed_wandb_run_has_written_its_whole_record(tmp_path):
    """When ``close`` returns the offline ``.wandb`` file holds the run and everything logged
    (``run.finish`` alone leaves it at its 7-byte header until wandb's service closes the stream):
    a job that reports done has a record ``wandb sync`` and the table generator can read."""
    pytest.importorskip("wandb")
    from .wandb_record import run_info, summary_and_history

    run = WandbLogger(tmp_path, {"seed": 3}, mode="offline", name="whole")
    run.log({"loss": 1.5}, step=1)
    run.results({"eval/mean_m": 0.25})
    run.close()
    from wandb.sdk import wandb_setup

    assert wandb_setup._singleton is None  # the service is stopped: the stream was closed, not just left to flush
    (info,) = run_info(tmp_path)
    summary, history, _ = summary_and_history(tmp_path)
    assert info["name"] == "whole" and info["config"]["seed"] == 3
    assert "train/loss" in history and summary["eval/mean_m"] == 0.25  # a training metric, in its section


def test_a_wandb_login_is_a_netrc_entry_for_the_api_host(tmp_path, monkeypatch):
    """``logger.mode=online`` is refused in one line without a login: ``wandb login`` writes the
    key to ~/.netrc under the API host (``WANDB_BASE_URL``, else api.wandb.ai)."""
    from datt.train.loggers import _wandb_logged_in

    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("WANDB_BASE_URL", raising=False)
    assert not _wandb_logged_in()  # no ~/.netrc
    netrc = tmp_path / ".netrc"
    netrc.write_text("machine api.wandb.ai\n  login user\n  password abc123\n")
    netrc.chmod(0o600)
    assert _wandb_logged_in()
    monkeypatch.setenv("WANDB_BASE_URL", "https://wandb.example.org/")
    assert not _wandb_logged_in()  # a login for another host
    netrc.write_text("machine wandb.example.org\n  login user\n  password abc123\n")
    assert _wandb_logged_in()
    monkeypatch.setenv("WANDB_BASE_URL", "wandb.example.org")  # no scheme: the host as given
    assert _wandb_logged_in()
    netrc.write_text("machine\n")  # unreadable: not logged in
    assert not _wandb_logged_in()


def test_online_without_a_login_is_refused_in_one_line_before_wandb_starts(tmp_path, monkeypatch):
    pytest.importorskip("wandb")
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.netrc
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.delenv("WANDB_BASE_URL", raising=False)
    message = (
        "logger.mode: online needs a wandb login (`wandb login` or WANDB_API_KEY); "
        "or use logger.mode=offline and `wandb sync` later"
    )
    with pytest.raises(ConfigError) as refused:
        WandbLogger(tmp_path, {}, mode="online")
    assert str(refused.value) == message
    assert not (tmp_path / "wandb").exists()  # refused before wandb made anything


def test_a_wandb_run_records_the_project_group_tags_name_and_job_it_was_given(tmp_path):
    pytest.importorskip("wandb")
    from .wandb_record import run_info

    run = WandbLogger(tmp_path, {"seed": 1}, project="proj-x", group="g/1", tags=["a", "b"], name="n1", job_type="eval")
    run.close()
    (info,) = run_info(tmp_path)
    assert {k: info[k] for k in ("project", "group", "tags", "name", "job_type")} == {
        "project": "proj-x",
        "group": "g/1",
        "tags": ["a", "b"],
        "name": "n1",
        "job_type": "eval",
    }


@pytest.mark.parametrize("run_id, resume", [("run-7", "allow"), (None, None)], ids=["with_id", "without_id"])
def test_a_wandb_run_resumes_its_id_and_keeps_wandb_off_the_console_and_the_cpu(tmp_path, run_id, resume):
    """A resumed training run logs into the run of its id (``resume="allow"``: the same id online
    continues that run instead of failing as a duplicate); wandb's console capture (it would
    interleave with the progress bar) and its system-metrics sampler (a thread per run) are off."""
    pytest.importorskip("wandb")
    run = WandbLogger(tmp_path, {}, run_id=run_id)
    try:
        settings = run.run.settings
        assert settings.resume == resume and (run_id is None or run.run.id == run_id)
        assert settings.console == "off" and settings.x_disable_stats is True
    finally:
        run.close()


def test_online_with_an_api_key_and_no_netrc_login_goes_on_to_start_wandb(tmp_path, monkeypatch):
    """``WANDB_API_KEY`` alone is a login: the run is not refused, wandb is asked to start (here it
    cannot: no network in a test, which is the other one-line error)."""
    wandb = pytest.importorskip("wandb")
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.netrc
    monkeypatch.setenv("WANDB_API_KEY", "k" * 40)
    monkeypatch.delenv("WANDB_BASE_URL", raising=False)

    def offline_here(**kwargs):
        raise wandb.errors.UsageError("no network in this test")

    monkeypatch.setattr(wandb, "init", offline_here)
    with pytest.raises(ConfigError) as failed:
        WandbLogger(tmp_path, {}, mode="online")
    assert str(failed.value) == "logger: wandb could not start the run (logger.mode=online: no network in this test)"


@pytest.mark.parametrize(
    "body, problem",
    [
        ("step,x\n1,0.5\nabc,0.4\n", "line 3 has step 'abc', not a number"),
        ("step,x\n1,0.5\n2,0.4,9\n", "line 3 has not as many cells as the header"),
        ("step,x\n1\n", "line 2 has not as many cells as the header"),
    ],
)
def test_a_hand_edited_metrics_csv_is_one_line_naming_the_line_and_is_kept(tmp_path, body, problem):
    from datt.errors import ConfigError
    from datt.train.loggers import CsvLogger

    path = tmp_path / "metrics.csv"
    path.write_text(body)
    with pytest.raises(ConfigError) as info:
        CsvLogger(tmp_path).keep_until(1)
    assert str(info.value).startswith(f"{path}: {problem}; a resume keeps the rows") and "\n" not in str(info.value)
    assert path.read_text() == body
