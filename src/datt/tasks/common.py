"""What every task shares: its run directory, torch threads and the console."""

from __future__ import annotations

import os
from pathlib import Path

from rich.console import Console

console = Console()


def hydra_run_dir() -> Path:
    """The output directory of the running Hydra job."""
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def launcher_threads() -> int | None:
    """The torch threads a job of a parallel launcher gets when ``threads`` is null:
    ``hydra/launcher=joblib``: the cores divided by the parallel jobs (2 jobs on 2 cores use 1
    thread each instead of oversubscribing); ``submitit_*``/``slurm``: the CPUs the job asked the
    scheduler for (``hydra.launcher.cpus_per_task``). Otherwise (or unset) None."""
    try:
        from hydra.core.hydra_config import HydraConfig

        launcher = HydraConfig.get().launcher
    except (ImportError, ValueError):
        return None
    target = str(launcher.get("_target_", ""))
    if "submitit" in target:
        cpus = launcher.get("cpus_per_task")
        return int(cpus) if cpus else None
    if "joblib" not in target:
        return None
    cores = os.cpu_count() or 1
    n_jobs = int(launcher.get("n_jobs") or -1)
    n_jobs = cores + 1 + n_jobs if n_jobs < 0 else n_jobs  # joblib: -1 = all cores, -2 = all but one
    return max(1, cores // max(1, min(n_jobs, cores)))


def set_threads(n: int | None) -> None:
    """``n`` torch threads; ``None`` = automatic (see :func:`launcher_threads`, else torch's default)."""
    n = n or launcher_threads()
    if n:
        import torch

        torch.set_num_threads(int(n))


def wandb_run_id(run_dir: Path) -> str:
    """The wandb run id of a training run dir (``<parent dir>-<run dir>``): a resume or a requeued
    attempt continues that run, and ``eval.py`` names it as the training run it evaluates."""
    return f"{run_dir.parent.name}-{run_dir.name}"


def sweep_group(job_dir: Path) -> str | None:
    """The wandb group of a multirun job dir (``<sweep dir>/<job number>``), as its training run
    named it: ``<sweep_name or multirun>/<sweep dir name>``; None for a single run."""
    if not (job_dir.name.isdigit() and (job_dir.parent / "multirun.yaml").is_file()):
        return None
    from omegaconf import OmegaConf

    config = job_dir / ".hydra" / "config.yaml"
    sweep_name = OmegaConf.load(config).get("sweep_name") if config.is_file() else None
    return f"{sweep_name or 'multirun'}/{job_dir.parent.name}"
