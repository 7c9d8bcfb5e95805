"""The run-dir contract, over every entry point: a dir that holds a run is never written into."""

import json

import pytest

from datt import cli

from .test_faults import one_line, run_cli, snapshot

# each entry point with the arguments it needs to get as far as its run dir
ENTRIES = {name: (["table=ablation"] if name == "tables" else []) for name in cli.COMMANDS}


def _a_finished_run(path):
    (path / ".hydra").mkdir(parents=True)
    (path / ".hydra" / "config.yaml").write_text("seed: 0\n")
    (path / "metrics.json").write_text(json.dumps({"frames": 1}))
    return path


@pytest.mark.parametrize("entry", list(ENTRIES))
def test_no_entry_point_writes_into_a_dir_that_holds_a_run(entry, tmp_path, monkeypatch, capsys):
    run = _a_finished_run(tmp_path / "done")
    before = snapshot(run)
    result = run_cli(entry, [*ENTRIES[entry], f"hydra.run.dir={run}"], tmp_path, monkeypatch, capsys)
    one_line(result, f"error: hydra.run.dir: {run} already holds a run (.hydra, metrics.json); nothing is written")
    assert f"resume={run}" in result[1][0]
    assert snapshot(run) == before


@pytest.mark.parametrize("entry", list(ENTRIES))
def test_an_empty_run_dir_value_is_refused(entry, tmp_path, monkeypatch, capsys):
    result = run_cli(entry, [*ENTRIES[entry], "hydra.run.dir="], tmp_path, monkeypatch, capsys)
    one_line(result, "error: hydra.run.dir: empty; give a directory")
    assert list(tmp_path.iterdir()) == []


def test_a_sweep_dir_whose_jobs_hold_runs_is_refused(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "sweep"
    _a_finished_run(sweep / "0")
    before = snapshot(sweep)
    result = run_cli("eval", ["-m", "seed=0,1", f"hydra.sweep.dir={sweep}"], tmp_path, monkeypatch, capsys)
    one_line(result, f"error: hydra.sweep.dir: {sweep} already holds a run (0/.hydra, 0/metrics.json)")
    assert snapshot(sweep) == before


def test_a_dir_that_holds_other_files_but_no_run_is_used(tmp_path):
    """A user's own files (a reference csv beside the run) are not a run: the dir is used."""
    (tmp_path / "ref.csv").write_text("t,x,y,z\n")
    cli.check_run_dir([f"hydra.run.dir={tmp_path}"])
    cli.check_run_dir([f"hydra.run.dir={tmp_path / 'new'}"])
    cli.check_run_dir(["hydra.run.dir=outputs/${now:%H}"])  # interpolated: a new dir per command


def test_a_second_command_on_a_dir_in_use_is_refused_naming_the_holder(tmp_path, monkeypatch, capsys):
    """The job's lock (every entry point; training locks the dir it trains in itself)."""
    import os

    from datt.runs import RunLock

    run = tmp_path / "busy"
    with RunLock(run):
        result = run_cli("export", [f"hydra.run.dir={run}"], tmp_path, monkeypatch, capsys)
    one_line(result, f"error: run dir '{run}' is in use by pid {os.getpid()} on ")


@pytest.mark.parametrize("below", ["", "sub"])
def test_export_into_a_file_is_one_line(tmp_path, monkeypatch, capsys, below):
    afile = tmp_path / "afile"
    afile.write_text("mine\n")
    out = afile / below if below else afile
    result = run_cli("export", [f"out_dir={out}"], tmp_path, monkeypatch, capsys)
    one_line(result, f"error: out_dir: {afile} is a file, not a directory")
    assert afile.read_text() == "mine\n"


@pytest.mark.parametrize(
    "make, args, message",
    [
        (None, ["--config-dir", "{tmp}/missing"], "error: --config-dir: {tmp}/missing does not exist"),
        ("file", ["--config-dir", "{tmp}/conf"], "error: --config-dir: {tmp}/conf is a file"),
        ("broken", ["--config-dir", "{tmp}/conf"], "error: --config-dir: {tmp}/conf/traj/mine.yaml is not valid YAML"),
        (None, ["hydra/launcher=nope"], "error: hydra/launcher: unknown option 'nope'; allowed: basic, joblib"),
        (None, ["-m", "seed=0,1", "hydra/launcher=joblib", "hydra.launcher.n_jobs=0"], "error: hydra.launcher.n_jobs"),
    ],
)
def test_hydras_own_inputs_are_one_line(tmp_path, monkeypatch, capsys, make, args, message):
    conf = tmp_path / "conf"
    if make == "file":
        conf.write_text("not a dir\n")
    elif make == "broken":
        (conf / "traj").mkdir(parents=True)
        (conf / "traj" / "mine.yaml").write_text("a: [1, 2\nb: 3\n")
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    result = run_cli("eval", args, tmp_path, monkeypatch, capsys)
    one_line(result, message.replace("{tmp}", str(tmp_path)))


def test_a_flight_whose_log_cannot_be_written_whole_is_refused_before_arming(tmp_path):
    from datt.errors import ConfigError
    from datt.tasks.deploy import LOG_HEADROOM_BYTES, check_log_headroom

    check_log_headroom(tmp_path)  # this machine's test disk has room
    check_log_headroom(tmp_path, free_bytes=LOG_HEADROOM_BYTES)
    with pytest.raises(ConfigError) as info:
        check_log_headroom(tmp_path, free_bytes=LOG_HEADROOM_BYTES - 1)
    assert str(info.value) == (
        f"hydra.run.dir: {tmp_path} has 50.0 MB free; a flight's log needs 50 MB before arming: free some space "
        "or set hydra.run.dir=<another disk>"
    )


@pytest.mark.parametrize("entry", list(ENTRIES))
@pytest.mark.parametrize("multirun", [False, True])
def test_no_entry_point_starts_on_a_disk_without_room_for_its_records(entry, multirun, tmp_path, monkeypatch, capsys):
    """Hydra reports its own failed write of .hydra/ as a traceback (it never reaches the entry's
    handler), so a disk without room is refused before Hydra runs, for every entry point."""
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(10**9, 10**9 - 4096, 4096))
    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    args = [*ENTRIES[entry], *(["-m"] if multirun else []), f"{key}={tmp_path / 'r'}"]
    result = run_cli(entry, args, tmp_path, monkeypatch, capsys)
    one_line(result, f"error: {key}: {tmp_path / 'r'}: 0.00 MB free on its disk, under the 10 MB a run's records need")
    assert f"set {key}=<another disk>" in result[1][0]
    assert list(tmp_path.iterdir()) == []


def test_the_room_a_run_needs_is_checked_against_the_disk_it_writes_to(tmp_path, monkeypatch):
    import shutil
    from collections import namedtuple

    usage, seen = namedtuple("usage", "total used free"), []
    monkeypatch.setattr(shutil, "disk_usage", lambda path: seen.append(path) or usage(1, 0, cli.RUN_MIN_FREE_BYTES))
    cli.check_output_dir([f"hydra.run.dir={tmp_path / 'a' / 'b'}"])  # exactly the room needed: accepted
    assert seen == [tmp_path]  # the nearest existing parent


def test_hydras_own_write_on_a_full_disk_is_one_line(tmp_path, monkeypatch, capsys):
    """Hydra writes .hydra/ before the task runs: a full disk there is the same one line as in a task."""
    import errno

    import hydra

    def full_disk(*args, **kwargs):
        def main_decorator(fn):
            def run():
                raise OSError(errno.ENOSPC, "No space left on device", str(tmp_path / "r" / ".hydra" / "config.yaml"))

            return run

        return main_decorator

    monkeypatch.setattr(hydra, "main", full_disk)
    monkeypatch.setitem(cli.COMMANDS, "eval", cli.hydra_main("eval", lambda cfg: None))  # built on the full disk
    result = run_cli("eval", ["hydra.run.dir=r"], tmp_path, monkeypatch, capsys)
    one_line(result, f"error: {tmp_path / 'r' / '.hydra' / 'config.yaml'}: No space left on device; free some space")


def test_a_trace_is_written_whole_or_not_at_all(tmp_path, monkeypatch):
    """The evaluation's trace goes through a temporary file: a write that fails leaves no partial file."""
    import errno

    from datt.checkpoint import write_torch

    write_torch(tmp_path / "trace.pt", {"x": 1})
    assert (tmp_path / "trace.pt").stat().st_size > 0

    class FullDisk:
        def __init__(self, *args):
            raise OSError(errno.ENOSPC, "No space left on device")

    import datt.runs

    monkeypatch.setattr(datt.runs.os, "fdopen", FullDisk)
    with pytest.raises(OSError) as info:
        write_torch(tmp_path / "trace2.pt", {"x": 2})
    assert info.value.filename == str(tmp_path / "trace2.pt")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["trace.pt"]
