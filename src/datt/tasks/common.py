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


def joblib_threads() -> int | None:
    """Under ``hydra/launcher=joblib``: the cores divided by the parallel jobs (2 jobs on 2 cores
    use 1 thread each instead of oversubscribing); otherwise None."""
    try:
        from hydra.core.hydra_config import HydraConfig

        launcher = HydraConfig.get().launcher
    except (ImportError, ValueError):
        return None
    if "joblib" not in str(launcher.get("_target_", "")):
        return None
    cores = os.cpu_count() or 1
    n_jobs = int(launcher.get("n_jobs") or -1)
    n_jobs = cores + 1 + n_jobs if n_jobs < 0 else n_jobs  # joblib: -1 = all cores, -2 = all but one
    return max(1, cores // max(1, min(n_jobs, cores)))


def set_threads(n: int | None) -> None:
    """``n`` torch threads; ``None`` = automatic (see :func:`joblib_threads`, else torch's default)."""
    n = n or joblib_threads()
    if n:
        import torch

        torch.set_num_threads(int(n))
