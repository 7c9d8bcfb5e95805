"""What every task shares: its run directory, torch threads and what it says."""

from __future__ import annotations

import io
import logging
import math
import os
from collections.abc import Mapping
from fnmatch import fnmatchcase
from pathlib import Path

from rich.console import Console

log = logging.getLogger("datt")

TEXT_WIDTH = 200  # columns of a rendered table: a log line is never wrapped at a terminal's 80


def as_text(renderable) -> str:
    """A rich renderable (a :class:`rich.table.Table`) as plain text, no colour, ``TEXT_WIDTH``
    columns at most."""
    out = io.StringIO()
    Console(file=out, width=TEXT_WIDTH, color_system=None, force_terminal=False, soft_wrap=True).print(renderable)
    return out.getvalue().rstrip("\n")


class RunOutput:
    """What a run says, through Python's ``logging`` (logger ``datt``): Hydra's job logging
    (``conf/hydra/default.yaml``) writes each line to the console, unwrapped, and to
    ``<run dir>/<entry point>.log``. ``print`` takes a line or a rich table, so the tasks and a
    flight's event log (:class:`datt.deploy.flight_log.FlightLog`) share one interface."""

    def print(self, message) -> None:
        log.info(message if isinstance(message, str) else as_text(message))


console = RunOutput()


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


def headline(result: object, path: str | None) -> float | None:
    """The figure a Hydra sweeper optimises (``optimized_metric``): the value at the dotted
    ``path`` of the task's result (its ``metrics.json``; ``*`` in a part matches any key there,
    ``fnmatch`` style, and several matches are averaged, e.g. over an evaluation's seeds). A
    matched value that is not a finite number (null: every episode of a group crashed) makes the
    figure ``inf``, the worst for the minimising default. None without a path, or when the result
    has nothing there (``train.eval_at_end=false``; one line says so)."""
    if not path or not isinstance(result, Mapping):
        return None
    values = _select(result, str(path).split("."))
    if not values:
        log.warning("optimized_metric: %r is not in this run's results; the job returns no figure", path)
        return None
    numbers = [v for v in values if isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)]
    if len(numbers) < len(values):
        return math.inf
    return float(sum(numbers) / len(numbers))


def _select(node: object, parts: list[str]) -> list:
    if not parts:
        return [node]
    if not isinstance(node, Mapping):
        return []
    return [v for key in node if fnmatchcase(str(key), parts[0]) for v in _select(node[key], parts[1:])]
