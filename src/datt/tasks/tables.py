"""``tables.py <table>``: (optionally run the table's sweep, then) collect its jobs into the
paper's table as Markdown, CSV and LaTeX, with plots."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import MISSING, DictConfig, ListConfig
from rich.table import Table

from datt.configuration import Range, ranged, structured
from datt.errors import ConfigError, TrainingInterrupted
from datt.eval import tables
from datt.paths import original_cwd, resolve_path
from datt.runs import run_stoppable
from datt.tasks.common import console, sweep_group
from datt.train.loggers import LoggerParams, log_results_run


@dataclass
class SideBySide:
    group: str = MISSING
    index: int = ranged(MISSING, Range(0, 100_000, integer=True))

    def validate(self) -> None:
        pass  # every rule is a field's own range


@dataclass
class TablesParams:
    """``conf/tables.yaml``."""

    table: str = MISSING
    runs: Any = MISSING  # sweep dir(s) or job dirs; null = the newest outputs/sweeps/<table>/<time>
    out_dir: str | None = MISSING
    run: bool = MISSING  # run the table's sweep first
    sweep_overrides: list[str] = MISSING
    plots: bool = MISSING
    side_by_side: SideBySide = field(default_factory=SideBySide)
    logger: LoggerParams = field(default_factory=LoggerParams)  # logger=wandb: the table to its sweep's group

    def validate(self) -> None:
        self.side_by_side.validate()
        self.logger.validate()


def run_roots(runs: Any) -> list[Path]:
    """``runs``: a sweep or job dir, or a list of them; each must exist."""
    items = list(runs) if isinstance(runs, (list, tuple, ListConfig)) else [runs]
    roots = []
    for item in items:
        if not isinstance(item, str) or not item:
            raise ConfigError(f"runs: must be a sweep or job dir (or a list of them), got {runs!r}")
        roots.append(resolve_path(item))
        if not roots[-1].exists():
            raise ConfigError(f"runs: {str(roots[-1])!r} does not exist")
    return roots


def run_tables(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """Build one table; returns the files written, its rows and the number of jobs read."""
    params = structured(TablesParams, cfg, "")
    spec = tables.get_spec(params.table)
    outputs = original_cwd() / "outputs"
    if params.run:
        sweep_dir = outputs / "sweeps" / spec.name / time.strftime("%Y-%m-%d_%H-%M-%S")
        command = spec.entry.removesuffix(".py")
        overrides = [*params.sweep_overrides, f"hydra.sweep.dir={sweep_dir}"]
        cmd = [sys.executable, "-m", "datt", command, f"+sweep={spec.name}", *overrides]
        console.print("running: " + " ".join(cmd[1:]))
        code, stopped_by = run_stoppable(cmd, cwd=original_cwd())
        if stopped_by:
            raise TrainingInterrupted(
                f"{stopped_by}: the {spec.name} sweep was stopped; its finished jobs are kept in {sweep_dir} "
                f"(the table of what finished: python tables.py {spec.name} runs={sweep_dir})"
            )
        if code != 0 and not (sweep_dir / "multirun.yaml").is_file():  # refused before any job started
            raise ConfigError(f"run: the {spec.name} sweep did not start (see its output above)")
        if code != 0:
            console.print(f"{code} job(s) of the sweep did not finish; the table lists each one's state")
        roots = [sweep_dir]
    elif params.runs:
        roots = run_roots(params.runs)
    else:
        roots = tables.default_roots(spec, outputs)
    jobs = tables.find_jobs(roots)
    if not jobs:
        raise ConfigError(f"runs: no Hydra job dirs under {', '.join(map(str, roots))}")
    tables.check_jobs_are_the_tables(spec, jobs)
    rows, _ = tables.collect(spec, jobs)
    rendered = tables.render(spec, rows, jobs)
    out_dir = resolve_path(params.out_dir) if params.out_dir else roots[0]
    files = tables.write(spec, rendered, out_dir)
    if params.plots and spec.kind == "train":
        files += tables.plot_train_sweep(spec, rows, jobs, out_dir)
    if params.plots and spec.kind == "eval":
        sbs = params.side_by_side
        path = tables.plot_side_by_side_from_jobs(jobs, sbs.group, sbs.index, out_dir / f"{spec.name}_side_by_side.png")
        files += [path] if path else []
    table = Table(title=spec.title)
    for h in rendered["header"]:
        table.add_column(h)
    for r in rendered["rows"]:
        table.add_row(*r)
    console.print(table)
    for note in tables.job_notes(jobs):
        console.print(note)
    console.print("wrote " + ", ".join(str(f) for f in files))
    _log_table(cfg, spec, rendered, jobs, roots, out_dir, files)
    return {"files": [str(f) for f in files], "rows": rendered["rows"], "jobs": len(jobs)}


def _cell_summary(numeric: list[list]) -> dict:
    """``table/<row>/<column>`` -> the cell's mean (rows of :data:`datt.eval.tables.NUMERIC_COLUMNS`)."""
    return {f"table/{row}/{column}": mean for row, column, mean, *_ in numeric}


def _log_table(cfg: DictConfig, spec, rendered: dict, jobs: list, roots: list[Path], out_dir: Path, files) -> None:
    """``logger=wandb``: the table as a run in its sweep's group: a numeric wandb Table (one row
    per cell: mean, std, runs, the paper's figure; :data:`datt.eval.tables.NUMERIC_COLUMNS`), its
    plots, and each cell's mean as a summary key ``table/<row>/<column>``."""
    groups = {sweep_group(job.path) for job in jobs if job.path.is_dir()} - {None}
    log_results_run(
        cfg.logger,
        out_dir,
        {"table": spec.name, "runs": [str(r) for r in roots], "jobs": len(jobs)},
        name=f"table-{spec.name}",
        group=groups.pop() if len(groups) == 1 else None,  # jobs of several sweeps: no one group
        job_type="table",
        summary={"jobs": len(jobs), **_cell_summary(rendered["numeric"][1])},
        images={Path(f).stem: f for f in files if str(f).endswith(".png")},
        tables={f"table/{spec.name}": rendered["numeric"]},
    )
