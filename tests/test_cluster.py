"""Cluster runs: the Slurm preset's sbatch, the job's threads from its CPUs, and a training job
that a scheduler stops (time limit or preemption) saving, being requeued and resuming in its own
run dir through submitit's real local executor."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from omegaconf import OmegaConf

from datt.runs import StopRequest, requeue_with_scheduler, scheduler_signal
from datt.tasks.common import launcher_threads

from .train.test_training import TINY

REPO = Path(__file__).resolve().parents[1]
SLURM = "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"


def _hydra_cfg(*overrides: str, cwd: Path):
    out = subprocess.run(
        [sys.executable, str(REPO / "train.py"), *overrides, "--cfg", "hydra", "--resolve"],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr[-2000:]
    return OmegaConf.create(out.stdout)["hydra"]


def test_slurm_preset_renders_an_sbatch_with_its_resources_and_requeue(tmp_path, monkeypatch):
    """The sbatch text submitit writes for a 3-job sweep with ``hydra/launcher=slurm``, built by the
    plugin's own launch() (only the submission is stopped; ``srun`` need only exist on PATH)."""
    import submitit
    from hydra.utils import instantiate

    hydra_cfg = _hydra_cfg(
        "hydra/launcher=slurm",
        "hydra.launcher.partition=gpu",
        "hydra.launcher.gpus_per_node=1",
        f"hydra.sweep.dir={tmp_path / 'sweep'}",
        cwd=tmp_path,
    )
    fake_bin = tmp_path / "bin"
    fake_bin.mkdir()
    (fake_bin / "srun").write_text("#!/bin/sh\nexit 1\n")
    (fake_bin / "srun").chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake_bin}{os.pathsep}{os.environ['PATH']}")
    executors = []
    monkeypatch.setattr(submitit.AutoExecutor, "map_array", lambda self, fn, *args: executors.append(self) or [])

    launcher = instantiate(hydra_cfg.launcher)
    assert type(launcher).__name__ == "SlurmLauncher"
    launcher.config = OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path / "sweep")}}})
    assert launcher.launch([["seed=0"], ["seed=1"], ["seed=2"]], initial_job_idx=0) == []
    (auto,) = executors
    slurm = auto._executor
    assert slurm.max_num_timeout == 20  # requeues on time limit / preemption
    slurm.parameters["map_count"] = 100  # what submitit sets when it submits an array of 100 jobs
    sbatch = slurm._make_submission_file_text("python -u -m submitit.core._submit x", "uid").splitlines()
    for line in [
        "#SBATCH --array=0-99%64",  # 64 at once
        "#SBATCH --cpus-per-task=4",
        "#SBATCH --gpus-per-node=1",
        "#SBATCH --mem=8GB",
        "#SBATCH --partition=gpu",
        "#SBATCH --requeue",
        "#SBATCH --signal=USR2@120",
        "#SBATCH --time=240",
    ]:
        assert line in sbatch, (line, sbatch)
    assert f"#SBATCH --output={tmp_path / 'sweep'}/.submitit/%A_%a/%A_%a_0_log.out" in sbatch


def test_a_job_without_threads_gets_the_cpus_it_asked_the_scheduler_for(monkeypatch):
    from hydra.core.hydra_config import HydraConfig

    instance = HydraConfig.instance()
    monkeypatch.setattr(instance, "cfg", OmegaConf.create({"hydra": {"launcher": {"_target_": SLURM}}}))
    assert launcher_threads() is None  # cpus_per_task unset: torch's default
    instance.cfg.hydra.launcher.cpus_per_task = 6
    assert launcher_threads() == 6
    instance.cfg.hydra.launcher = {"_target_": "hydra_plugins.hydra_joblib_launcher.JoblibLauncher", "n_jobs": 1}
    assert launcher_threads() == (os.cpu_count() or 1)


def test_only_a_scheduler_s_own_handler_makes_its_signal_a_stop_request(monkeypatch):
    """Outside a scheduler's job SIGUSR2 is not training's business; with submitit's handler
    installed (its real SignalHandler) it stops training at a safe point like SIGTERM, and the
    scheduler's handler is back in place afterwards for the requeue."""
    from submitit.core.job_environment import SignalHandler

    monkeypatch.delenv("SUBMITIT_PREEMPT_SIGNAL", raising=False)
    previous = signal.getsignal(signal.SIGUSR2)
    try:
        signal.signal(signal.SIGUSR2, signal.SIG_DFL)
        assert scheduler_signal() is None
        requeue_with_scheduler("SIGUSR2")  # nothing to hand over to: returns
        submitit_handler = SignalHandler(None, None, None).checkpoint_and_try_requeue
        signal.signal(signal.SIGUSR2, submitit_handler)
        assert scheduler_signal() == signal.SIGUSR2
        monkeypatch.setenv("SUBMITIT_PREEMPT_SIGNAL", "USR1")  # submitit's setting for another signal
        assert scheduler_signal() is None
        monkeypatch.delenv("SUBMITIT_PREEMPT_SIGNAL")
        with StopRequest() as stop:
            os.kill(os.getpid(), signal.SIGUSR2)
            time.sleep(0.05)
            assert stop.signal == "SIGUSR2"
        assert signal.getsignal(signal.SIGUSR2) == submitit_handler
        requeue_with_scheduler("SIGTERM")  # a user's stop is not handed to the scheduler: returns
    finally:
        signal.signal(signal.SIGUSR2, previous)


TINY_JOB = [
    *TINY,
    "curriculum.fixed_ref_frames=0",
    "eval.plots=false",
    "eval.bank={zigzag:[{traj:zigzag,seed:1000,count:2}]}",
    "eval.conditions.brownian=null",
    "train.total_frames=102400",
    "train.checkpoint_every=1000",  # only the stop signal's save: a resume from it loses nothing
    "threads=1",
]


def _frames(run_dir: Path) -> list[int]:
    with open(run_dir / "metrics.csv") as f:
        return [int(row["frames"]) for row in csv.DictReader(f)]


def _task_pids(sweep: Path) -> list[int]:
    """The submitit task processes (``python -m submitit.core._submit <sweep>/.submitit/<id>``)."""
    pids = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit():
            try:
                cmd = (proc / "cmdline").read_bytes().decode(errors="replace")
            except OSError:
                continue
            if "submitit.core._submit" in cmd and str(sweep) in cmd:
                pids.append(int(proc.name))
    return pids


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc").is_dir(), reason="finds the job's task process through /proc")
def test_a_preempted_training_job_saves_is_requeued_and_resumes_in_its_own_run_dir(tmp_path):
    """One tiny training job through ``hydra/launcher=submitit_local``; once it has logged 20
    iterations its task process gets the scheduler's signal (SIGUSR2, what submitit's controller
    sends before a time limit and Slurm at preemption). The job saves, submitit requeues it, the
    new attempt resumes from last.pt in the same run dir: every iteration logged exactly once, and
    the run's record has what an uninterrupted run's has."""
    sweep = tmp_path / "sweep"
    cmd = [
        sys.executable,
        str(REPO / "train.py"),
        "-m",
        "hydra/launcher=submitit_local",
        "hydra.launcher.timeout_min=30",
        f"hydra.sweep.dir={sweep}",
        *TINY_JOB,
    ]
    proc = subprocess.Popen(cmd, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    run_dir = sweep / "0"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and proc.poll() is None:
        if (run_dir / "metrics.csv").is_file() and len(_frames(run_dir)) >= 20:
            break
        time.sleep(0.2)
    pids = _task_pids(sweep)
    assert len(pids) == 1, pids
    os.kill(pids[0], signal.SIGUSR2)
    out, _ = proc.communicate(timeout=600)
    assert proc.returncode == 0, out[-3000:]
    assert "1 jobs: 1 done" in out
    logs = "".join(p.read_text() for p in (sweep / ".submitit").glob("*/*_log.*"))
    assert "preempted (SIGUSR2: checkpoint at" in logs and "requeued job: resuming its own run" in logs, logs[-3000:]

    frames = _frames(run_dir)
    per_iteration = 64 * 16
    assert frames == [per_iteration * (i + 1) for i in range(102400 // per_iteration)]  # each once, in order
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["frames"] == 102400

    whole = tmp_path / "whole"  # the same job, never interrupted
    subprocess.run(
        [sys.executable, str(REPO / "train.py"), *TINY_JOB, f"hydra.run.dir={whole}"],
        cwd=tmp_path,
        check=True,
        capture_output=True,
        timeout=600,
    )
    uninterrupted = json.loads((whole / "metrics.json").read_text())
    assert set(metrics) == set(uninterrupted)
    assert set(metrics["conditions"]) == set(uninterrupted["conditions"])
    assert _frames(whole) == frames
