"""Run loggers. One interface (``log(metrics, step)``, ``close()``); CSV always, wandb optional
(offline by default: no login or network needed; ``wandb sync <run>/wandb/offline-run-*`` later).
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import MISSING

from datt.configuration import Range, ranged, structured
from datt.errors import ConfigError, one_line
from datt.runs import atomic_write

WANDB_MODES = ("offline", "online", "disabled")
# the columns of an evaluation's wandb Table (one row per condition and reference group)
RESULT_COLUMNS = ["condition", "group", "mean_m", "std_m", "crashes", "episodes"]

# wandb's sections (panels) for the training metrics, as the TorchRL and CleanRL scripts group
# theirs; metrics.csv keeps the flat names. A metric not listed is a training metric.
METRIC_SECTIONS = {
    "loss_objective": "losses",
    "loss_critic": "losses",
    "grad_norm": "losses",
    "kl_approx": "losses",
    "steps_per_s": "time",
    "frames": "time",
    "train_wall_s": "time",
}
# the summary wandb keeps of a training metric (wandb.define_metric); the rest keep their last value
METRIC_SUMMARIES = {
    "train/tracking_error_m": "min",  # the best batch error, not the last
    "train/episode_return_est": "max",
    "train/crash_rate": "min",
    "time/steps_per_s": "mean",
    "train/lr": "last",
}
# what each plot shows, by its file's stem (its prefix for per-condition plots)
PLOT_CAPTIONS = {
    "learning_curve": "training: the batch's mean tracking error (m) and return over frames",
    "tracks_": "tracks in the x-y plane against the references, condition {}",
    "axes_": "position per axis against the reference over time, condition {}",
}


def wandb_key(name: str) -> str:
    """The wandb key of a training metric: ``<section>/<name>`` (:data:`METRIC_SECTIONS`; a name
    that already has a section is kept)."""
    return name if "/" in name else f"{METRIC_SECTIONS.get(name, 'train')}/{name}"


def caption(stem: str) -> str:
    """The caption of the plot whose file stem is ``stem`` (its name as a wandb image)."""
    for prefix, text in PLOT_CAPTIONS.items():
        if stem == prefix or (prefix.endswith("_") and stem.startswith(prefix)):
            return text.format(stem.removeprefix(prefix))
    return stem.replace("_", " ")


def condition_key(disturbance: str, adaptation: str, seed: int, seeds) -> str:
    """An evaluated condition's wandb name, the same in ``train.py``'s end-of-run evaluation and
    in ``eval.py``: ``<disturbance>-<adaptation>``, with ``-seed<k>`` when the job evaluated
    several seeds (as :func:`datt.eval.schema.per_seed_name` names them in metrics.json)."""
    key = f"{disturbance}-{adaptation}"
    return key if len(list(seeds)) == 1 else f"{key}-seed{seed}"


@dataclass
class LoggerParams:
    """``logger`` (``conf/logger/csv.yaml``: CSV only; ``wandb.yaml``: CSV + wandb). The wandb
    keys are unused (and may be left out) when ``wandb`` is false."""

    wandb: bool = MISSING
    mode: str | None = ranged(None, Range(choices=WANDB_MODES, optional=True))
    project: str | None = None
    group: str | None = None
    tags: list[str] = field(default_factory=list)

    def validate(self) -> None:
        if self.wandb and self.mode is None:
            raise ConfigError(f"logger.mode: must be one of {', '.join(WANDB_MODES)} with logger.wandb=true")
        if self.wandb and not self.project:
            raise ConfigError("logger.project: must name the wandb project with logger.wandb=true")


def eval_summary(
    conditions: Mapping[str, Any], names: Mapping[str, str] | None = None, prefix: str = "eval"
) -> dict[str, float]:
    """An evaluation's conditions (``metrics.json``'s ``conditions``) as flat summary keys:
    ``eval/<condition>/<group>/{mean_m, std_m, crashes, episodes}``, ``<condition>`` renamed by
    ``names`` (metrics.json's name -> :func:`condition_key`) where given."""
    out: dict[str, float] = {}
    for name, result in conditions.items():
        cond = (names or {}).get(name, name)
        for group, stats in (result.get("groups") or {}).items():
            for key in ("mean_m", "std_m", "crashes", "episodes"):
                if key in stats:
                    value = _plain(stats[key])
                    # a group where every episode crashed has no mean: null, as in metrics.json
                    out[f"{prefix}/{cond}/{group}/{key}"] = None if isinstance(value, str) else value
    return out


def result_rows(conditions: Mapping[str, Any], names: Mapping[str, str] | None = None) -> list[list[Any]]:
    """An evaluation's conditions as the rows of a table with :data:`RESULT_COLUMNS` (conditions
    renamed by ``names`` as in :func:`eval_summary`)."""
    return [
        [(names or {}).get(cond, cond), group, *(stats.get(k) for k in RESULT_COLUMNS[2:])]
        for cond, result in conditions.items()
        for group, stats in (result.get("groups") or {}).items()
    ]


class Logger:
    def checkpoints(self, name: str, files: list[Path], metadata: Mapping[str, Any]) -> None:
        """Record a training run's checkpoints (only wandb keeps them as an artifact)."""

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        raise NotImplementedError

    def results(
        self,
        summary: Mapping[str, Any],
        images: Mapping[str, Path] | None = None,
        tables: Mapping[str, tuple[list[str], list[list[Any]]]] | None = None,
    ) -> None:
        """A run's results, once: ``summary`` keys (the numbers a table sorts by), plots and
        tables (name -> (columns, rows)). CSV keeps them in metrics.json; wandb in the run."""

    def close(self) -> None:
        pass


class CsvLogger(Logger):
    """Appends rows to ``<run_dir>/metrics.csv`` (columns grow as new metrics appear; resume appends)."""

    def __init__(self, run_dir: str | Path, filename: str = "metrics.csv") -> None:
        self.path = Path(run_dir) / filename
        self.rows: list[dict[str, Any]] = []
        if self.path.exists():
            with self.path.open(newline="") as f:
                self.rows = list(csv.DictReader(f))
            for n, row in enumerate(self.rows, start=2):  # line 1 is the header
                self._check_row(row, n)

    def _check_row(self, row: dict, line: int) -> None:
        """A row read back (a resume appends to the file): as many cells as the header, a numeric
        step; else one line naming the file and line (a hand edit), nothing rewritten."""
        from datt.errors import ConfigError

        problem = None
        if None in row or any(v is None for v in row.values()):
            problem = "has not as many cells as the header"
        else:
            try:
                float(row.get("step") or 0)
            except ValueError:
                problem = f"has step {row.get('step')!r}, not a number"
        if problem:
            raise ConfigError(
                f"{self.path}: line {line} {problem}; a resume keeps the rows up to its checkpoint and "
                "appends: restore the file as the run wrote it, or move it away (the resume starts a new one)"
            )

    def keep_until(self, step: int) -> None:
        """Drop the rows logged after ``step`` (a resume trains them again from its checkpoint)."""
        kept = [row for row in self.rows if float(row.get("step") or 0) <= step]
        if len(kept) != len(self.rows):
            self.rows = kept
            self._write()

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        self.rows.append({"step": step, **{k: _plain(v) for k, v in metrics.items()}})
        self._write()

    def _write(self) -> None:
        fields: list[str] = []
        for row in self.rows:
            fields += [k for k in row if k not in fields]
        with atomic_write(self.path, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=fields)
            writer.writeheader()
            writer.writerows(self.rows)


class WandbLogger(Logger):
    """wandb run in ``<run_dir>/wandb`` (``mode`` offline by default)."""

    def __init__(
        self,
        run_dir: str | Path,
        config: Mapping[str, Any],
        project: str = "datt",
        group: str | None = None,
        tags: list[str] | None = None,
        mode: str = "offline",
        name: str | None = None,
        run_id: str | None = None,
        job_type: str = "train",
    ) -> None:
        import wandb

        os.environ.setdefault("WANDB_SILENT", "true")
        self._wandb = wandb
        if mode == "online" and not (os.environ.get("WANDB_API_KEY") or _wandb_logged_in()):
            raise ConfigError(
                "logger.mode: online needs a wandb login (`wandb login` or WANDB_API_KEY); "
                "or use logger.mode=offline and `wandb sync` later"
            )
        try:
            self.run = wandb.init(
                project=project,
                group=group,
                tags=list(tags or []),
                mode=mode,
                dir=str(run_dir),
                config=dict(config),
                name=name,
                id=run_id,
                resume="allow" if run_id else None,
                job_type=job_type,
                settings=wandb.Settings(console="off", x_disable_stats=True),
            )
        except (wandb.errors.UsageError, wandb.errors.CommError) as exc:
            raise ConfigError(f"logger: wandb could not start the run (logger.mode={mode}: {one_line(exc)})") from None
        if job_type == "train":
            for key, kept in METRIC_SUMMARIES.items():
                self.run.define_metric(key, summary=kept)

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        """One row of training metrics at ``step`` (frames), each under its section (:func:`wandb_key`)."""
        self.run.log({wandb_key(k): _plain(v) for k, v in metrics.items()}, step=step)

    def results(self, summary, images=None, tables=None) -> None:
        self.run.summary.update({k: _plain(v) for k, v in summary.items()})
        media: dict[str, Any] = {}
        for name, path in (images or {}).items():
            if Path(path).is_file():
                media[name] = self._wandb.Image(str(path), caption=caption(name))
        for name, (columns, rows) in (tables or {}).items():
            media[name] = self._wandb.Table(columns=list(columns), data=[list(r) for r in rows])
        if media:
            self.run.log(media, commit=True)

    def checkpoints(self, name: str, files: list[Path], metadata: Mapping[str, Any]) -> None:
        """``files`` (checkpoints, their config and evaluation) as a versioned wandb artifact of
        type ``model`` named ``name``, aliased ``latest``; ``metadata`` (frames, eval summary)
        makes versions comparable in wandb's artifact view."""
        artifact = self._wandb.Artifact(name, type="model", metadata={k: _plain(v) for k, v in metadata.items()})
        for path in files:
            if Path(path).is_file():
                artifact.add_file(str(path))
        self.run.log_artifact(artifact, aliases=["latest"])

    def close(self) -> None:
        """Finish the run and stop wandb's service: ``finish`` returns before the service has
        written the run's ``.wandb`` file (offline, it holds only its header until the stream
        closes), so without the teardown a job could report done with its record still unwritten
        (``wandb sync`` or a table generator reading it would see an empty run)."""
        self.run.finish()
        self._wandb.teardown()


def log_results_run(
    logger_cfg: Mapping[str, Any],
    run_dir: str | Path,
    config: Mapping[str, Any],
    *,
    name: str,
    group: str | None,
    job_type: str,
    summary: Mapping[str, Any],
    images: Mapping[str, str | Path] | None = None,
    tables: Mapping[str, tuple[list[str], list[list[Any]]]] | None = None,
) -> None:
    """One wandb run that holds only results (``eval.py``, ``tables.py``), when ``logger.wandb``:
    ``summary`` keys, ``images`` and ``tables`` (name -> (columns, rows)), in ``group`` beside
    the training runs it reports on. Nothing without ``logger.wandb``."""
    params = structured(LoggerParams, logger_cfg, "logger")
    if not params.wandb:
        return
    run = WandbLogger(
        run_dir,
        config,
        project=params.project,
        group=group or params.group,
        tags=params.tags,
        mode=params.mode,
        name=name,
        job_type=job_type,
    )
    try:
        run.results(summary, images, tables)
    finally:
        run.close()


class MultiLogger(Logger):
    def __init__(self, loggers: list[Logger]) -> None:
        self.loggers = loggers

    def log(self, metrics: Mapping[str, float], step: int) -> None:
        for logger in self.loggers:
            logger.log(metrics, step)

    def results(self, summary, images=None, tables=None) -> None:
        for logger in self.loggers:
            logger.results(summary, images, tables)

    def checkpoints(self, name: str, files: list[Path], metadata: Mapping[str, Any]) -> None:
        for logger in self.loggers:
            logger.checkpoints(name, files, metadata)

    def close(self) -> None:
        for logger in self.loggers:
            logger.close()


def _wandb_logged_in() -> bool:
    """Whether ~/.netrc (where `wandb login` writes) holds a key for the wandb API host."""
    import netrc

    host = os.environ.get("WANDB_BASE_URL", "https://api.wandb.ai").split("://")[-1].rstrip("/")
    try:
        return netrc.netrc().authenticators(host) is not None
    except (FileNotFoundError, netrc.NetrcParseError, OSError):
        return False


def _plain(v: Any) -> Any:
    if hasattr(v, "item"):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)
    return v
