"""Fault catalogue: every bad-input and fault case found by trying the entry points as a
new user would, one test each, the reproduction as its body. Each must end in one line naming the
key (exit 2), a clear non-zero exit, or work that is kept; never a traceback or lost files.

Most cases run the entry points in this process (the same code path as the scripts, without ~3 s
of imports each); the signal cases run them as real processes.
"""

import csv
import json
import os
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from datt import cli
from datt.checkpoint import load_checkpoint, save_checkpoint
from datt.errors import ConfigError
from datt.refs.csv import load_csv_reference
from datt.runs import RunLock, write_json
from datt.tasks.resume import resume_dir

from .deploy import SHORT_FLIGHT, ports
from .train.test_training import TINY as TRAIN_TINY

ROOT = Path(__file__).resolve().parents[1]
# a few-second training run, nothing written but the run dir
TINY = [*TRAIN_TINY, "curriculum.fixed_ref_frames=0", "train.eval_at_end=false", "eval.plots=false"]
RESUME = ["logger=csv", "train.progress=false"]  # a resume repeats nothing of the run's own settings
FLIGHT = SHORT_FLIGHT


def run_cli(entry, args, cwd, monkeypatch, capsys):
    """``<entry>.py args`` in this process: (exit status, stderr lines without warnings, stdout)."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.hydra_config import HydraConfig

    monkeypatch.chdir(cwd)
    monkeypatch.setattr(sys, "argv", [f"{entry}.py", *args])
    capsys.readouterr()
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # a library's warning is not the error line under test
            cli.COMMANDS[entry]()
        code = 0
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    finally:  # leave no Hydra job state (nor the exiting command's ignored signals) behind
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        HydraConfig.instance().cfg = None
        GlobalHydra.instance().clear()
    out = capsys.readouterr()
    lines = [ln for ln in out.err.splitlines() if ln.strip() and "warn" not in ln.lower()]
    return code, lines, out.out


def one_line(result, start, status=2):
    """``result`` of :func:`run_cli` is one stderr line starting with ``start``, exit ``status``."""
    code, lines = result[0], result[1]
    assert code == status, lines
    assert len(lines) == 1 and lines[0].startswith(start), lines


def train_run(run_dir, monkeypatch, capsys, *extra):
    code, lines, _ = run_cli("train", [*TINY, *extra, f"hydra.run.dir={run_dir}"], run_dir.parent, monkeypatch, capsys)
    assert code == 0, lines
    return run_dir


def ablation_table(sweep, tmp_path, monkeypatch, capsys):
    """``tables.py ablation runs=<sweep>``: the Markdown it writes."""
    args = ["ablation", f"runs={sweep}", f"out_dir={tmp_path / 't'}", "plots=false"]
    code, lines, _ = run_cli("tables", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    return (tmp_path / "t" / "ablation.md").read_text()


def snapshot(path):
    return {p.name: (p.stat().st_size, p.stat().st_mtime_ns) for p in sorted(path.rglob("*")) if p.is_file()}


def write_csv(path, rows, delimiter=",", bom=False):
    with open(path, "w", newline="", encoding="utf-8-sig" if bom else "utf-8") as f:
        w = csv.writer(f, delimiter=delimiter)
        w.writerow(["t", "x", "y", "z"])
        w.writerows(rows)
    return path


SMALL_CSV = [[0.0, 0.0, 0.0, 0.0], [1.0, 0.2, 0.0, 0.0], [2.0, 0.2, 0.2, 0.0], [3.0, 0.0, 0.0, 0.0]]


# -- 1-4: data loss and aborted work ------------------------------------------------------------
def test_01_resume_trains_on_with_the_runs_own_config(tmp_path, monkeypatch, capsys):
    run = train_run(tmp_path / "R", monkeypatch, capsys, "train.total_frames=2048", "algo.num_envs=32")
    code, lines, out = run_cli(
        "train", [*RESUME, f"resume={run}", "train.total_frames=4096"], tmp_path, monkeypatch, capsys
    )
    assert code == 0, lines
    assert "resuming" in out and "of 4,096 frames" in out
    ckpt = load_checkpoint(run / "last.pt")
    assert ckpt["frames"] == 4096
    assert "num_envs: 32" in (run / "config.yaml").read_text()  # not the command's 64 nor the default 1024
    assert "total_frames: 4096" in (run / "config.yaml").read_text()
    assert not list(tmp_path.glob("outputs/*/*"))  # the resume command left no run dir of its own


def test_01_resume_of_a_run_written_before_a_config_key_existed(tmp_path, monkeypatch, capsys):
    """A run's config.yaml from before ``eval.protocol``, ``curriculum.fixed_ref`` and
    ``env.obs.timing`` existed resumes with today's values for them (the values that keep what
    the code did then), and its config.yaml then records them; one written with retired keys
    (``train.threads``, ``env.num_envs``) resumes in today's keys (the threads moved)."""
    run = train_run(tmp_path / "R", monkeypatch, capsys, "train.total_frames=2048", "algo.num_envs=32")
    text = (run / "config.yaml").read_text()
    for line in ("  protocol: project\n", "  fixed_ref: steps\n", "    timing: project\n", "\nthreads: null\n"):
        assert line in text
        text = text.replace(line, "\n" if line.startswith("\n") else "", 1)
    text = text.replace("env:\n", "env:\n  num_envs: 1024\n", 1).replace("train:\n", "train:\n  threads: 1\n", 1)
    (run / "config.yaml").write_text(text)
    code, lines, out = run_cli(
        "train", [*RESUME, f"resume={run}", "train.total_frames=4096"], tmp_path, monkeypatch, capsys
    )
    assert code == 0, lines
    assert load_checkpoint(run / "last.pt")["frames"] == 4096
    saved = (run / "config.yaml").read_text()
    assert "  protocol: project\n" in saved and "  fixed_ref: steps\n" in saved and "    timing: project\n" in saved
    saved_cfg = OmegaConf.load(run / "config.yaml")
    assert saved_cfg.threads == 1 and "threads" not in saved_cfg.train and "num_envs" not in saved_cfg.env


def test_01_resume_refuses_an_override_that_changes_the_run(tmp_path, monkeypatch, capsys):
    run = train_run(tmp_path / "R", monkeypatch, capsys, "train.total_frames=1024")
    before = snapshot(run)
    result = run_cli("train", [*RESUME, f"resume={run}", "algo.num_envs=128"], tmp_path, monkeypatch, capsys)
    one_line(result, "error: resume: algo.num_envs=128 changes what the run trains (it used 64)")
    result = run_cli("train", [*RESUME, f"resume={run}", "traj=star"], tmp_path, monkeypatch, capsys)
    one_line(result, "error: resume: traj=star changes what the run trains (it used traj=train_mix_fast)")
    assert snapshot(run) == before


def test_01_resume_of_a_finished_run_writes_nothing(tmp_path, monkeypatch, capsys):
    run = train_run(tmp_path / "R", monkeypatch, capsys, "train.total_frames=1024")
    before = snapshot(run)
    code, lines, out = run_cli("train", [*RESUME, f"resume={run}"], tmp_path, monkeypatch, capsys)
    assert code == 0 and not lines
    assert "is finished (1,024 frames); nothing to do" in " ".join(out.split())
    assert snapshot(run) == before


def test_02_failing_and_diverging_jobs_do_not_stop_the_sweep(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "sweep"
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_text("not a checkpoint")  # passes the up-front checks (it exists), fails to load
    args = [*TINY, "train.total_frames=1024", "algo.lr=1e-3,10", f"train.init_from=null,{corrupt}"]
    code, lines, _ = run_cli("train", [*args, f"hydra.sweep.dir={sweep}", "-m"], tmp_path, monkeypatch, capsys)
    assert code == 3  # the number of jobs that did not finish
    assert lines[-1] == f"sweep {sweep}: 4 jobs: 1 done, 1 diverged, 2 errored"
    assert (sweep / "0" / "metrics.json").is_file()
    assert json.loads((sweep / "2" / "failed.json").read_text())["status"] == "diverged"
    errored = json.loads((sweep / "1" / "failed.json").read_text())
    assert errored["status"] == "errored" and errored["message"].startswith("train.init_from: ")
    # the table lists every job: the done one as a number, the diverged one as failed, the errored ones with why
    md = ablation_table(sweep, tmp_path, monkeypatch, capsys)
    assert "algo.lr=0.001" in md and "| failed |" in md
    assert f"- failed (diverged): `{sweep / '2'}`" in md
    assert f"- errored: `{sweep / '1'}` train.init_from: " in md


def test_02_a_bad_value_in_any_variant_refuses_the_sweep_before_any_job(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "sweep"
    args = [*TINY, "train.total_frames=1024", "algo.lr=1e-3,10,abc", f"hydra.sweep.dir={sweep}", "-m"]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 2
    assert lines == ["error: algo.lr: Value 'abc' of type 'str' could not be converted to Float"]
    assert not sweep.exists()


def test_02_a_job_that_never_started_is_listed_as_missing(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "sweep"
    run_cli(
        "train",
        [*TINY, "train.total_frames=1024", "seed=0,1", f"hydra.sweep.dir={sweep}", "-m"],
        tmp_path,
        monkeypatch,
        capsys,
    )
    import shutil

    shutil.rmtree(sweep / "1")  # as if the sweep had been killed before job 1
    md = ablation_table(sweep, tmp_path, monkeypatch, capsys)
    assert "- missing: job 1 never started (" in md and "seed=1" in md.split("- missing:")[1]


def test_03_runs_started_together_get_their_own_dirs(tmp_path):
    cmd = [sys.executable, str(ROOT / "train.py"), *TINY, "train.total_frames=1024"]
    procs = [subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE) for _ in range(2)]
    for p in procs:
        assert p.wait(timeout=300) == 0, p.stderr.read().decode()[-2000:]
    runs = sorted((tmp_path / "outputs" / "train").iterdir())
    assert len(runs) == 2 and all((r / "last.pt").is_file() and (r / "metrics.csv").is_file() for r in runs)


def test_03_a_run_dir_in_use_is_refused(tmp_path, monkeypatch, capsys):
    run = tmp_path / "R"
    with RunLock(run):
        result = run_cli(
            "train", [*TINY, "train.total_frames=1024", f"hydra.run.dir={run}"], tmp_path, monkeypatch, capsys
        )
    one_line(result, f"error: run dir '{run}' is in use by pid {os.getpid()} on ")
    assert not (run / "last.pt").exists()


def test_03_resume_true_skips_a_run_in_use(tmp_path, monkeypatch):
    old, new = tmp_path / "outputs" / "train" / "a", tmp_path / "outputs" / "train" / "b"
    for run in (old, new):
        save_checkpoint(run / "last.pt", {"frames": 1})
        time.sleep(0.01)
    monkeypatch.chdir(tmp_path)
    assert resume_dir(True) == new
    with RunLock(new):
        assert resume_dir(True) == old


def _popen(cmd, cwd):
    """A real process whose output lines arrive as printed (a pipe is block-buffered otherwise)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    return subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _read_until(proc, text, timeout_s):
    deadline = time.monotonic() + timeout_s
    seen = []
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        seen.append(line)
        if text in line:
            return seen
    raise AssertionError(f"{text!r} not seen: {''.join(seen)[-2000:]}")


def _wait_for_file(path, timeout_s):
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        assert time.monotonic() < deadline, f"{path} not written"
        time.sleep(0.01)


@pytest.mark.parametrize(
    "signals, second_after, reason",
    [
        ((signal.SIGINT, signal.SIGINT), "0.3 s", "Ctrl-C"),
        ((signal.SIGINT, signal.SIGINT), "log", "Ctrl-C"),
        ((signal.SIGTERM,), None, "SIGTERM"),
    ],
    ids=["ctrl_c_twice", "ctrl_c_again_after_the_log", "sigterm"],
)
def test_04_interrupted_flight_keeps_its_log(tmp_path, signals, second_after, reason):
    """Two Ctrl-C 0.3 s apart during TRACK (the second used to cut the log short), a second one
    once the log is written (it used to land after the cleanup's ignore block: exit by SIGINT
    with a traceback instead of 4), or a SIGTERM."""
    pytest.importorskip("cflib")
    port = next(ports)
    cmd = [sys.executable, str(ROOT / "deploy.py"), *FLIGHT, f"deploy.uri=udp://127.0.0.1:{port}", "hydra.run.dir=."]
    proc = _popen(cmd, tmp_path)
    _read_until(proc, "phase: TRACK", 120)
    proc.send_signal(signals[0])
    if len(signals) > 1:
        if second_after == "log":
            _wait_for_file(tmp_path / "flight.csv", 60)
        else:
            time.sleep(0.3)
        proc.send_signal(signals[1])
    proc.wait(timeout=60)
    events = json.loads((tmp_path / "events.json").read_text())
    assert events["outcome"] == f"killed: operator interrupt ({reason})"
    assert (tmp_path / "flight.csv").stat().st_size > 100
    assert proc.returncode == 4 and "Traceback" not in proc.stderr.read()


# -- 5-7: silently wrong -------------------------------------------------------------------------
def test_05_eval_flies_the_given_traj(tmp_path, monkeypatch, capsys):
    ref = write_csv(tmp_path / "mine.csv", SMALL_CSV)
    args = [
        "controller=pid",
        "traj=csv",
        f"traj.path={ref}",
        "eval.timing.steps=0",
        "eval.plots=false",
        "hydra.run.dir=e",
    ]
    code, lines, _ = run_cli("eval", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    (cond,) = json.loads((tmp_path / "e" / "metrics.json").read_text())["conditions"].values()
    assert list(cond["groups"]) == ["csv"] and cond["groups"]["csv"]["episodes"] == 1


def test_04_a_signal_during_an_evaluation_keeps_the_finished_seeds(tmp_path, monkeypatch, capsys):
    """SIGTERM (as the entry point raises it) after seed 0 of three finished: seed 0 is in a strict,
    whole metrics.json marked incomplete, the line says so, exit 130; ``tables.py`` reads the run as
    incomplete, not as a result."""
    import datt.tasks.eval as eval_task
    from datt.eval.tables import read_job

    real = eval_task.evaluate_conditions
    calls = []

    def stopped_at_the_second(*args, **kwargs):
        calls.append(kwargs["seed"])
        if len(calls) == 2:
            raise KeyboardInterrupt("SIGTERM")
        return real(*args, **kwargs)

    monkeypatch.setattr(eval_task, "evaluate_conditions", stopped_at_the_second)
    ref = write_csv(tmp_path / "mine.csv", SMALL_CSV)
    args = ["controller=pid", "traj=csv", f"traj.path={ref}", "eval.timing.steps=0", "eval.plots=false"]
    result = run_cli("eval", [*args, "eval.seeds=[0,1,2]", "hydra.run.dir=e"], tmp_path, monkeypatch, capsys)
    metrics_path = tmp_path / "e" / "metrics.json"
    one_line(
        result, f"error: interrupted by SIGTERM: seeds [0] of [0, 1, 2] are in {metrics_path} (complete: false)", 130
    )
    metrics = json.loads(metrics_path.read_text(), parse_constant=lambda c: pytest.fail(f"not strict JSON: {c}"))
    assert metrics["complete"] is False and metrics["seeds_done"] == [0] and len(metrics["conditions"]) == 1
    assert not [p for p in (tmp_path / "e").iterdir() if p.name.endswith(".tmp")]
    job = read_job(tmp_path / "e")
    assert job.status == "incomplete" and job.metrics is None


def test_05_eval_of_a_missing_csv_is_one_line(tmp_path, monkeypatch, capsys):
    result = run_cli(
        "eval", ["traj=csv", "traj.path=/nonexistent.csv", "hydra.run.dir=e"], tmp_path, monkeypatch, capsys
    )
    one_line(result, "error: traj.path: file '/nonexistent.csv' not found")


@pytest.mark.parametrize(
    "args, message",
    [
        (["seed=1.5"], "error: seed: Value '1.5' of type 'float' could not be converted to Integer"),
        (["algo.lr_final_frac=-5"], "error: algo.lr_final_frac: must be a finite number in [0, 1], got -5.0"),
        (
            ["ablation=h5", "horizon=15"],
            "error: horizon: 15 contradicts ablation=h5 (which sets horizon=5); drop one of the two",
        ),
        (
            ["ablation=no_body_frame", "env.obs.body_frame=true"],
            "error: env.obs.body_frame: True contradicts ablation=no_body_frame (which sets env.obs.body_frame=False)",
        ),
    ],
    ids=["seed_not_integer", "lr_final_frac_negative", "ablation_contradicted", "nested_ablation_key_contradicted"],
)
def test_06_values_that_would_train_something_else(tmp_path, monkeypatch, capsys, args, message):
    result = run_cli(
        "train", [*TINY, "train.total_frames=1024", *args, "hydra.run.dir=r"], tmp_path, monkeypatch, capsys
    )
    one_line(result, message)
    assert not (tmp_path / "r" / "last.pt").exists()


def test_06_csv_reference_far_from_the_origin(tmp_path, monkeypatch, capsys):
    ref = write_csv(tmp_path / "big.csv", [[0.0, 0.0, 0.0, 0.0], [1.0, 1e6, 0.0, 0.0]])
    args = [*TINY, "train.total_frames=1024", "traj=csv", f"traj.path={ref}", "hydra.run.dir=r"]
    one_line(run_cli("train", args, tmp_path, monkeypatch, capsys), "error: traj.max_abs_m: big.csv line 3 is 1e+06 m")


def test_06_reference_outside_the_geofence_is_refused_before_arming(tmp_path, monkeypatch, capsys):
    pytest.importorskip("cflib")
    args = [
        *FLIGHT,
        f"deploy.uri=udp://127.0.0.1:{next(ports)}",
        "deploy.safety.geofence_max_m=[0.3,0.3,2.5]",
        "hydra.run.dir=f",
    ]
    code, lines, _ = run_cli("deploy", args, tmp_path, monkeypatch, capsys)
    one_line((code, lines), "error: deploy.safety.geofence_max_m: the reference leaves the geofence at t=")
    events = json.loads((tmp_path / "f" / "events.json").read_text())
    assert "ARM" not in [e["text"] for e in events["events"] if e["kind"] == "phase"]


def test_07_resume_bookkeeping(tmp_path, monkeypatch, capsys):
    os.umask(0o022)
    run = train_run(tmp_path / "R", monkeypatch, capsys, "train.total_frames=2048", "eval.plots=true")
    first = json.loads((run / "metrics.json").read_text())
    code, lines, _ = run_cli(
        "train", [*RESUME, f"resume={run}", "train.total_frames=4096"], tmp_path, monkeypatch, capsys
    )
    assert code == 0, lines
    rows = list(csv.DictReader((run / "metrics.csv").open()))
    assert [int(r["iteration"]) for r in rows] == [1, 2, 3, 4]  # no iteration twice
    ckpt = load_checkpoint(run / "last.pt")
    assert [r["iteration"] for r in ckpt["history"]] == [1, 2, 3, 4]  # the learning curve's data
    metrics = json.loads((run / "metrics.json").read_text(), parse_constant=lambda c: pytest.fail(f"JSON has {c}"))
    assert metrics["train_wall_s"] > first["train_wall_s"]  # summed over both segments
    assert metrics["steps_per_s"] == pytest.approx(4096 / metrics["train_wall_s"])
    assert (run / "last.pt").stat().st_mode & 0o777 == 0o644 and (run / "metrics.json").stat().st_mode & 0o777 == 0o644


def test_07_metrics_json_has_no_nan(tmp_path):
    write_json(tmp_path / "m.json", {"a": float("nan"), "b": [1.0, float("inf")]})
    assert json.loads((tmp_path / "m.json").read_text(), parse_constant=pytest.fail) == {"a": None, "b": [1.0, None]}


# -- 8: one line where there was a traceback ----------------------------------------------------
@pytest.mark.parametrize(
    "args, message",
    [
        (["train.totl_steps=5"], "error: train.totl_steps: no such key"),
        (["seed=abc"], "error: seed: Value 'abc' of type 'str' could not be converted to Integer"),
        (["train.total_frames=abc"], "error: train.total_frames: Value 'abc' of type 'str' could not be converted"),
        (["hydra.run.dir=/proc/datt_run"], "error: hydra.run.dir: /proc/datt_run: cannot write in /proc"),
    ],
)
def test_08_train_input_errors(tmp_path, monkeypatch, capsys, args, message):
    one_line(run_cli("train", [*TINY, "train.total_frames=1024", *args], tmp_path, monkeypatch, capsys), message)


def test_08_output_dir_below_a_file(tmp_path, monkeypatch, capsys):
    (tmp_path / "afile").write_text("")
    result = run_cli("train", [*TINY, f"hydra.run.dir={tmp_path / 'afile' / 'run'}"], tmp_path, monkeypatch, capsys)
    one_line(
        result, f"error: hydra.run.dir: {tmp_path / 'afile' / 'run'}: {tmp_path / 'afile'} is a file, not a directory"
    )


def test_08_rma_adapter_given_as_policy_checkpoint(tmp_path, monkeypatch, capsys):
    args = ["checkpoint=checkpoints/datt_h10_rma.pt", "eval.timing.steps=0", "hydra.run.dir=e"]
    code, lines, _ = run_cli("eval", args, tmp_path, monkeypatch, capsys)
    one_line((code, lines), "error: checkpoint: ")
    assert "an RMA adapter, not a policy" in lines[0]


def test_08_wandb_online_without_a_login(tmp_path, monkeypatch, capsys):
    monkeypatch.delenv("WANDB_API_KEY", raising=False)
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.netrc
    monkeypatch.setenv("NETRC", str(tmp_path / "none"))
    args = [*[a for a in TINY if a != "logger=csv"], "logger.mode=online", "train.total_frames=1024", "hydra.run.dir=r"]
    one_line(run_cli("train", args, tmp_path, monkeypatch, capsys), "error: logger.mode: online needs a wandb login")


def test_08_divergence_at_iteration_0_names_no_missing_checkpoint(tmp_path, monkeypatch, capsys):
    args = [*TINY, "train.total_frames=1024", "algo.lr=10", "hydra.run.dir=r"]  # the largest lr the range allows
    result = run_cli("train", args, tmp_path, monkeypatch, capsys)
    one_line(result, "error: training diverged: non-finite ", 3)
    assert "at iteration 0 (frame 0); no checkpoint was written" in result[1][0]
    assert json.loads((tmp_path / "r" / "failed.json").read_text())["status"] == "diverged"


def test_08_ctrl_c_during_training_saves_a_checkpoint(tmp_path):
    cmd = [sys.executable, str(ROOT / "train.py"), *TINY, "train.total_frames=100000000", "hydra.run.dir=r"]
    proc = _popen(cmd, tmp_path)
    _read_until(proc, "run dir:", 120)
    time.sleep(3.0)
    proc.send_signal(signal.SIGINT)
    proc.wait(timeout=120)
    err = [ln for ln in proc.stderr.read().splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 130 and len(err) == 1, err
    assert err[0].startswith("error: interrupted by SIGINT: checkpoint at ") and "resume with resume=" in err[0]
    assert load_checkpoint(tmp_path / "r" / "last.pt")["frames"] > 0


@pytest.mark.parametrize("variant", ["bom", "semicolon"])
def test_08_csv_with_a_bom_or_semicolons(tmp_path, variant):
    plain = load_csv_reference(write_csv(tmp_path / "plain.csv", SMALL_CSV))
    path = write_csv(
        tmp_path / "v.csv", SMALL_CSV, delimiter=";" if variant == "semicolon" else ",", bom=variant == "bom"
    )
    t, pos = load_csv_reference(path)
    assert torch.equal(t, plain[0]) and torch.equal(pos, plain[1])


def test_08_busy_udp_port_and_a_second_simulated_server(tmp_path, monkeypatch, capsys):
    pytest.importorskip("cflib")
    from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams

    port = next(ports)
    first = SimCrazyflie(SimCrazyflieParams(host="127.0.0.1", port=port)).start()
    try:
        with pytest.raises(ConfigError, match=f"deploy.uri: udp://127.0.0.1:{port} cannot be bound"):
            SimCrazyflie(SimCrazyflieParams(host="127.0.0.1", port=port)).start()
        result = run_cli(
            "deploy", [f"deploy.uri=udp://127.0.0.1:{port}", "hydra.run.dir=f"], tmp_path, monkeypatch, capsys
        )
        one_line(result, f"error: deploy.uri: udp://127.0.0.1:{port} cannot be bound (Address already in use)")
    finally:
        first.stop()


def test_08_crazyflie_without_a_radio(tmp_path, monkeypatch, capsys):
    pytest.importorskip("cflib")
    from cflib.crtp.radiodriver import RadioManager  # noqa: F401  (the driver the real link uses)

    args = ["deploy=crazyflie", "deploy.connect_timeout_s=2", "hydra.run.dir=f"]
    code, lines, _ = run_cli("deploy", args, tmp_path, monkeypatch, capsys)
    if code == 0 or "Crazyradio" not in " ".join(lines):  # pragma: no cover - a radio is plugged in
        pytest.skip("a Crazyradio is present")
    one_line((code, lines), "error: connect: radio://")
    assert "plug in a Crazyradio" in lines[0] and "firmware" not in lines[0]


def test_08_killed_flight_exits_non_zero(tmp_path, monkeypatch, capsys):
    """A 2° tilt limit KILLs the flight as soon as it banks (on a loaded machine another KILL
    reason may come first: any KILL must exit 4 with one line)."""
    pytest.importorskip("cflib")
    args = [*FLIGHT, f"deploy.uri=udp://127.0.0.1:{next(ports)}", "deploy.safety.max_tilt_deg=2", "hydra.run.dir=f"]
    code, lines, _ = run_cli("deploy", args, tmp_path, monkeypatch, capsys)
    one_line((code, lines), "error: flight killed: ", 4)
    assert (tmp_path / "f" / "flight.csv").is_file()


def test_lock_is_released_when_its_holder_dies(tmp_path):
    code = f"from datt.runs import RunLock; RunLock({str(tmp_path)!r}).acquire(); import os; os._exit(0)"
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
    with RunLock(tmp_path):  # no stale lock left behind
        pass


def test_second_signal_during_a_stop_request_interrupts_at_once():
    from datt.runs import StopRequest

    with StopRequest() as stop:
        os.kill(os.getpid(), signal.SIGINT)
        assert stop.signal == "SIGINT"
        with pytest.raises(KeyboardInterrupt):
            os.kill(os.getpid(), signal.SIGINT)
            time.sleep(0.1)


def test_10_a_full_disk_while_checkpointing_is_one_line_and_keeps_the_log(tmp_path, monkeypatch, capsys):
    """The checkpoint is serialised in memory and then written: a full disk is an OSError naming
    the file (before, torch's zip writer raised ``RuntimeError: unexpected pos`` with a traceback).
    Checked by hand on a 2 MB tmpfs too (docs/faults.md #10)."""
    import contextlib
    import errno

    from datt import checkpoint

    real = checkpoint.atomic_write

    @contextlib.contextmanager
    def full_disk(path, mode="w", **kw):
        with real(path, mode, **kw) as f:
            yield f
            raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(checkpoint, "atomic_write", full_disk)
    args = [*TINY, "train.total_frames=1024", "hydra.run.dir=r"]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    one_line((code, lines), f"error: {tmp_path / 'r'}/")
    assert lines[0].split(": ", 2)[1].endswith(".pt") and "No space left on device; free some space" in lines[0]
    assert (tmp_path / "r" / "metrics.csv").is_file() and not list((tmp_path / "r").glob("*.pt"))
    assert not list((tmp_path / "r").glob(".*.tmp"))  # no half-written temp file left


def test_10_resuming_on_a_read_only_mount_is_one_line(tmp_path, monkeypatch, capsys):
    import errno

    run = tmp_path / "r"
    code, _, _ = run_cli(
        "train", [*TINY, "train.total_frames=1024", f"hydra.run.dir={run}"], tmp_path, monkeypatch, capsys
    )
    assert code == 0
    before = snapshot(run)

    def read_only(self):
        raise OSError(errno.EROFS, "Read-only file system", str(self.run_dir / ".lock"))

    monkeypatch.setattr(RunLock, "acquire", read_only)
    code, lines, _ = run_cli(
        "train", [*RESUME, f"resume={run}", "train.total_frames=2048"], tmp_path, monkeypatch, capsys
    )
    one_line((code, lines), f"error: {run / '.lock'}: Read-only file system; copy the run to a writable place")
    assert snapshot(run) == before


def test_10_corrupt_job_files_are_listed_and_the_table_goes_on(tmp_path, monkeypatch, capsys):
    sweep = tmp_path / "sweep"
    code, _, _ = run_cli(
        "train",
        [*TINY, "train.total_frames=1024", "seed=0,1,2", f"hydra.sweep.dir={sweep}", "-m"],
        tmp_path,
        monkeypatch,
        capsys,
    )
    assert code == 0
    text = (sweep / "1" / "metrics.json").read_text()
    (sweep / "1" / "metrics.json").write_text(text[: len(text) // 2])  # truncated
    (sweep / "2" / ".hydra" / "overrides.yaml").write_bytes(b"\x00\x01 not yaml")
    (sweep / "0" / "metrics.csv").write_text("frames,tracking_error_m\n12,")  # a torn last row
    md = ablation_table(sweep, tmp_path, monkeypatch, capsys)
    assert f"- errored: `{sweep / '1'}` metrics.json: unreadable (" in md
    assert f"- errored: `{sweep / '2'}` .hydra/overrides.yaml: unreadable (" in md
    code, lines, _ = run_cli(
        "tables", ["ablation", f"runs={sweep}", f"out_dir={tmp_path / 'p'}"], tmp_path, monkeypatch, capsys
    )
    assert code == 0 and (tmp_path / "p" / "ablation_curves.png").is_file()  # plots skip what they cannot read


@pytest.mark.slow  # a real process tree and its signals: ~30-60 s
def test_10_tables_run_stops_its_sweep_on_sigterm_and_keeps_what_finished(tmp_path):
    """``tables.py ... run=true`` runs the sweep as a child in its own process group; SIGTERM is
    passed to the whole group (no orphan keeps training), and the command exits 130 naming the
    sweep dir. Before, the child sweep kept running after tables.py died."""
    overrides = [o for o in TINY if not o.startswith("hydra")] + ["train.total_frames=100000000", "seed=0,1"]
    quoted = ",".join(f"'{o}'" for o in overrides)
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "tables.py"), "ablation", "run=true", f"sweep_overrides=[{quoted}]"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.time() + 240
    while time.time() < deadline and not list(tmp_path.glob("outputs/sweeps/ablation/*/0/metrics.csv")):
        time.sleep(0.5)
    assert list(tmp_path.glob("outputs/sweeps/ablation/*/0/metrics.csv")), "the sweep did not start training"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=240)
    lines = [ln for ln in err.splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 130, err[-2000:]
    assert lines[-1].startswith("error: interrupted by SIGTERM: the ablation sweep was stopped"), lines
    (sweep,) = tmp_path.glob("outputs/sweeps/ablation/*")
    assert (sweep / "0" / "last.pt").is_file()  # the running job saved its checkpoint
    time.sleep(1.0)
    ps = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True).stdout
    assert str(sweep) not in ps  # no process of the sweep outlived the command


@pytest.mark.slow  # a real process tree and its signals: ~30-60 s
def test_10_sigterm_ends_an_evaluation_in_one_line(tmp_path):
    """A command without its own stop point (eval) ends on SIGTERM as on Ctrl-C: one line, 130
    (it used to die by the signal with no message)."""
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "eval.py"), "controller=mppi", f"hydra.run.dir={tmp_path / 'e'}"],
        cwd=tmp_path,
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
        text=True,
    )
    deadline = time.time() + 120
    while time.time() < deadline and not (tmp_path / "e").is_dir():
        time.sleep(0.2)
    time.sleep(2.0)  # inside the task
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 130 and len(lines) == 1, err[-2000:]
    assert lines[0].startswith("error: interrupted by SIGTERM: ") and lines[0].endswith("(complete: false)"), lines


def _group_members(pgid: int) -> list[str]:
    """The processes of process group ``pgid`` still running (zombies reaped by nobody excluded)."""
    out = subprocess.run(["ps", "-eo", "pgid=,stat=,args="], capture_output=True, text=True).stdout
    return [line for line in out.splitlines() if line.split()[0] == str(pgid) and not line.split()[1].startswith("Z")]


# each launcher's way to start two training jobs side by side
LAUNCHERS = {
    "joblib": ["seed=0,1,2,3", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2"],
    "submitit_local": ["seed=0,1", "hydra/launcher=submitit_local"],
}


@pytest.mark.slow  # two or four training processes and their signals: ~1-2 min each
@pytest.mark.parametrize("launcher", sorted(LAUNCHERS))
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_10_a_signal_stops_every_worker_of_a_parallel_multirun(tmp_path, sig, launcher):
    """SIGTERM / SIGINT to ``train.py -m`` under a parallel launcher (joblib, submitit's local
    executor): one line naming the sweep and what finished, exit 130, and no process of the
    command's group left (before: joblib exited 143 with no line while its loky workers trained on
    to the end; submitit's job controllers, started to outlive the command, trained on too)."""
    sweep = tmp_path / "sweep"
    args = [*TINY, "train.total_frames=100000000", *LAUNCHERS[launcher]]
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "train.py"), "-m", *args, f"hydra.sweep.dir={sweep}"],
        cwd=tmp_path,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group: the count below is the command's alone
    )
    deadline = time.time() + 300
    while time.time() < deadline and len(list(sweep.glob("*/metrics.csv"))) < 2:
        time.sleep(0.5)
    assert len(list(sweep.glob("*/metrics.csv"))) == 2, "the two workers did not start training"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 130, err[-2000:]
    assert lines[-1].startswith(f"error: interrupted by {sig.name}: sweep {sweep}: "), lines
    deadline = time.time() + 60  # the workers' own shutdown is asynchronous: wait for it, bounded
    while time.time() < deadline and _group_members(proc.pid):
        time.sleep(0.5)
    assert _group_members(proc.pid) == []
