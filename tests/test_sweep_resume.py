"""``train.py resume=<sweep dir>`` carries a whole multirun on: finished jobs are kept as they are,
a job stopped before its end resumes, a job that never ran trains; nothing else may change."""

import json
import re

import pytest
import yaml

from datt.cli import sweep_resume_argv
from datt.errors import ConfigError

from .test_faults import one_line, run_cli
from .train.test_training import TINY


def _record(sweep, task, hydra, sweeper="hydra._internal.core_plugins.basic_sweeper.BasicSweeper"):
    """A sweep's ``multirun.yaml`` as Hydra writes it (the parts read here)."""
    sweep.mkdir(parents=True, exist_ok=True)
    record = {"hydra": {"sweeper": {"_target_": sweeper}, "overrides": {"hydra": list(hydra), "task": list(task)}}}
    (sweep / "multirun.yaml").write_text(yaml.safe_dump(record))


def test_the_sweeps_own_command_line_in_its_own_dir(tmp_path, capsys):
    sweep = tmp_path / "s"
    _record(sweep, ["seed=0,1", "budget=0.01", "resume=own"], ["hydra.mode=MULTIRUN", "hydra/launcher=joblib"])
    argv = sweep_resume_argv("train", [f"resume={sweep}", "hydra.launcher.n_jobs=2"])
    assert argv == [
        "-m", "seed=0,1", "budget=0.01", "resume=own", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
        f"hydra.sweep.dir={sweep}",
    ]  # fmt: skip
    assert "carrying on sweep" in capsys.readouterr().out


def test_a_run_dir_or_another_entry_point_is_not_a_sweep(tmp_path):
    assert sweep_resume_argv("train", [f"resume={tmp_path}"]) is None  # no multirun.yaml: a run's resume
    assert sweep_resume_argv("train", ["resume=true"]) is None
    _record(tmp_path, ["seed=0,1"], [])
    assert sweep_resume_argv("eval", [f"resume={tmp_path}"]) is None


@pytest.mark.parametrize("extra", ["seed=3", "algo.lr=1e-3", "+sweep=ablation", "horizon=5"])
def test_what_a_sweep_trains_cannot_change_on_its_resume(tmp_path, extra):
    _record(tmp_path, ["seed=0,1"], [])
    with pytest.raises(ConfigError, match=rf"^resume: {tmp_path} is a sweep: .* drop '{re.escape(extra)}'"):
        sweep_resume_argv("train", [f"resume={tmp_path}", extra])


def test_a_search_is_not_carried_on(tmp_path):
    """An Optuna search's next trials depend on its study, which is not stored: refused."""
    _record(tmp_path, ["+search=lr"], [], sweeper="hydra_plugins.hydra_optuna_sweeper.optuna_sweeper.OptunaSweeper")
    with pytest.raises(ConfigError, match=r"^resume: .* is a search \(OptunaSweeper\), not a grid"):
        sweep_resume_argv("train", [f"resume={tmp_path}"])


def test_a_damaged_sweep_record_is_one_line(tmp_path):
    (tmp_path / "multirun.yaml").write_text("hydra: [1, 2\n")
    with pytest.raises(ConfigError, match=r"^resume: .*multirun.yaml is not a Hydra sweep record"):
        sweep_resume_argv("train", [f"resume={tmp_path}"])


def test_a_stopped_sweep_carries_on_with_one_command(tmp_path, monkeypatch, capsys):
    """Three jobs: job 0 finished, job 1 stopped after training but before its evaluation (no
    metrics.json), job 2 never started. ``resume=<sweep>``: job 0 is untouched, job 1 keeps its
    checkpoint and writes its evaluation, job 2 trains; the sweep exits 0."""
    sweep = tmp_path / "sweep"
    args = ["-m", *TINY, "train.total_frames=1024", "eval.plots=false", "seed=0,1,2", f"hydra.sweep.dir={sweep}"]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    kept = {name: (sweep / "0" / name).read_bytes() for name in ("last.pt", "metrics.json", "metrics.csv")}
    stopped_ckpt = (sweep / "1" / "last.pt").read_bytes()
    (sweep / "1" / "metrics.json").unlink()
    for path in sorted((sweep / "2").rglob("*"), reverse=True):
        path.unlink() if path.is_file() else path.rmdir()
    (sweep / "2").rmdir()

    code, lines, out = run_cli("train", [f"resume={sweep}"], tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    assert {name: (sweep / "0" / name).read_bytes() for name in kept} == kept
    assert (sweep / "1" / "last.pt").read_bytes() == stopped_ckpt  # not trained again
    assert json.loads((sweep / "1" / "metrics.json").read_text())["frames"] == 1024
    assert json.loads((sweep / "2" / "metrics.json").read_text())["frames"] == 1024
    assert f"run {sweep / '0'} is finished" in out


def test_a_sweep_dir_is_still_refused_without_resume(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "sweep"
    args = ["-m", *TINY, "train.total_frames=1024", "eval.plots=false", "seed=0", f"hydra.sweep.dir={sweep}"]
    assert run_cli("train", args, tmp_path, monkeypatch, capsys)[0] == 0
    one_line(run_cli("train", args, tmp_path, monkeypatch, capsys), "error: hydra.sweep.dir:")


def test_a_job_that_errored_and_then_finishes_is_finished_and_its_old_record_kept(tmp_path, monkeypatch, capsys):
    """A job's state is its latest attempt's: job 1 errored after training (its failed.json, no
    metrics.json, as a full disk at the evaluation leaves it); ``resume=<sweep>`` evaluates it, and
    the sweep, the table and the exit status read it as done; the earlier record is kept beside it."""
    from datt.eval.tables import read_job

    sweep = tmp_path / "sweep"
    args = ["-m", *TINY, "train.total_frames=1024", "eval.plots=false", "seed=0,1", f"hydra.sweep.dir={sweep}"]
    assert run_cli("train", args, tmp_path, monkeypatch, capsys)[0] == 0
    (sweep / "1" / "metrics.json").unlink()
    record = {"status": "errored", "message": "OSError: [Errno 28] No space left on device"}
    (sweep / "1" / "failed.json").write_text(json.dumps(record))
    assert read_job(sweep / "1").status == "errored"

    code, lines, out = run_cli("train", [f"resume={sweep}"], tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    assert read_job(sweep / "1").status == "finished" and not (sweep / "1" / "failed.json").exists()
    assert json.loads((sweep / "1" / "failed.previous.json").read_text()) == record
    assert "2 jobs: 2 done" in out + "\n".join(lines)
