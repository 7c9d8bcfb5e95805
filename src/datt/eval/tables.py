"""Paper tables from finished runs: ``python tables.py <table>`` (``conf/tables.yaml``).

A table collects every job directory of its sweep (``outputs/sweeps/<table>/<time>/<job>/``, or
the directories given as ``runs=``), reads each job's ``metrics.json`` and Hydra overrides, groups
jobs by their swept keys (all overrides except ``seed``) and reports mean ± std over seeds, with the
95 % t-interval of the mean in brackets, next to
the paper's numbers, as Markdown, CSV and LaTeX (plus PNG plots for training sweeps). A job that
diverged (``failed.json`` with status ``diverged``) or whose drones all crashed counts as *failed*,
as in the paper. Every job of a sweep is listed, never silently dropped: *errored* jobs (a bad
value or a crash, with the reason from ``failed.json``), *incomplete* ones (with how far they got)
and *missing* ones (jobs the sweep's ``multirun.yaml`` defines that never started).

Kinds of table (``datt/eval/paper_tables/<name>.yaml``, loaded into ``TABLES``):

* ``train`` (ablation, horizon): one number per run, the end-of-training error on the zigzag bank
  without disturbance; rows = swept keys.
* ``rma``: the four Brownian rows each ``fit_rma.py`` run evaluates (d̂ = 0, L1, RMA, privileged).
* ``eval`` (main, wind): per controller (and disturbance), per-episode errors pooled over the
  eval seeds; inference time from ``inference_ms``.
"""

from __future__ import annotations

import csv
import json
import math
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from datt.errors import ConfigError, one_line
from datt.eval.metrics import run_failed
from datt.eval.protocol import get_protocol
from datt.runs import read_failure


@dataclass
class Cell:
    """Values of one table cell: per-run (or per-episode) errors, failures and total runs."""

    values: list[float] = field(default_factory=list)
    failed: int = 0
    total: int = 0

    def add(self, value: float | None) -> None:
        self.total += 1
        if value is None or not math.isfinite(value):
            self.failed += 1
        else:
            self.values.append(float(value))

    def interval95(self) -> tuple[float, float] | None:
        """The 95 % confidence interval of the mean of the values (Student's t with n − 1
        degrees of freedom over the sample std); None with fewer than two values."""
        n = len(self.values)
        if n < 2:
            return None
        from scipy.stats import t

        mean = float(np.mean(self.values))
        half = float(t.ppf(0.975, n - 1)) * float(np.std(self.values, ddof=1)) / math.sqrt(n)
        return mean - half, mean + half

    def text(self, digits: int = 3) -> str:
        """``mean ± std [95 % interval of the mean]`` (population std, as the paper's ±), with
        the failed share; "failed" when every run failed, "—" without runs."""
        if self.total == 0:
            return "—"
        if not self.values:
            return "failed"
        mean = float(np.mean(self.values))
        out = f"{mean:.{digits}f}"
        interval = self.interval95()
        if interval is not None:
            out += f" ± {float(np.std(self.values)):.{digits}f} [{interval[0]:.{digits}f}, {interval[1]:.{digits}f}]"
        if self.failed:
            out += f" ({self.failed}/{self.total} failed)"
        return out


@dataclass
class Job:
    path: Path
    overrides: dict[str, str]
    metrics: dict | None
    status: str  # finished | diverged | errored | incomplete | missing
    note: str = ""


@dataclass
class TableSpec:
    """A paper table, declared as data in ``datt/eval/paper_tables/<name>.yaml``: ``kind`` (train | rma |
    eval), ``entry`` (the script that runs its sweep, ``conf/sweep/<name>.yaml``), ``columns``,
    and per row key (``ablation=h5``, a controller name, ...) in print order its label and the
    paper's figures per column."""

    name: str
    kind: str
    title: str
    entry: str
    columns: list[str]
    row_order: list[str]
    row_labels: dict[str, str]
    paper: dict[str, list[str]]
    paper_note: str


def _package(*parts: str):
    from importlib import resources

    return resources.files("datt").joinpath(*parts)


def load_spec(name: str) -> TableSpec:
    """``paper_tables/<name>.yaml`` as a :class:`TableSpec`. A label may name ``{span_s}``: the
    time the row's feedforward window spans (its ``horizon`` × ``env.ref_spacing_s``)."""
    data = yaml.safe_load(_package("eval", "paper_tables", f"{name}.yaml").read_text())
    spacing_s = float(yaml.safe_load(_package("conf", "env", "default.yaml").read_text())["ref_spacing_s"])
    rows = data["rows"]
    labels = {}
    for key, row in rows.items():
        horizon = key.partition("=")[2] if key.startswith("horizon=") else "0"
        labels[key] = str(row["label"]).format(span_s=int(horizon) * spacing_s)
    return TableSpec(
        name=name,
        kind=data["kind"],
        title=data["title"],
        entry=data["entry"],
        columns=list(data["columns"]),
        row_order=list(rows),
        row_labels=labels,
        paper={key: [str(v) for v in row["paper"]] for key, row in rows.items() if "paper" in row},
        paper_note=data["paper_note"],
    )


# every table of the package, by name (paper_tables/*.yaml)
TABLES: dict[str, TableSpec] = {
    path.name.removesuffix(".yaml"): load_spec(path.name.removesuffix(".yaml"))
    for path in sorted(_package("eval", "paper_tables").iterdir(), key=lambda p: p.name)
    if path.name.endswith(".yaml")
}


# -- collecting runs -----------------------------------------------------------------------
def job_entry(path: Path) -> str | None:
    """The entry point (``train.py``, ``eval.py`` ...) that ran the job dir ``path``, from its
    ``.hydra/hydra.yaml`` (``hydra.job.config_name``); None where that file does not say."""
    try:
        data = yaml.safe_load((path / ".hydra" / "hydra.yaml").read_text()) or {}
        name = data["hydra"]["job"]["config_name"]
    except (OSError, ValueError, KeyError, TypeError, yaml.YAMLError):
        return None
    return f"{name}.py" if isinstance(name, str) else None


def check_jobs_are_the_tables(spec: TableSpec, jobs: list[Job]) -> None:
    """Every job was run by the table's own entry point: a sweep of another script (a training
    sweep given to an evaluation table) is refused in one line, not turned into ``?`` rows."""
    for job in jobs:
        entry = job_entry(job.path) if job.path.is_dir() else None
        if entry is not None and entry != spec.entry:
            raise ConfigError(
                f"runs: {job.path} is a {entry} job; table {spec.name} is made from {spec.entry} jobs "
                f"(python {spec.entry} +sweep={spec.name}, or tables.py {spec.name} run=true)"
            )


def find_jobs(roots: list[Path]) -> list[Job]:
    """Every Hydra job dir (one with ``.hydra/``) under ``roots``, plus the jobs a sweep dir's
    ``multirun.yaml`` defines that have no directory under any of the roots (missing: a job
    run again in another sweep of the same table counts as found)."""
    jobs, sweep_dirs = [], []
    for root in roots:
        if not root.exists():
            continue
        dirs = (
            [root]
            if (root / ".hydra").is_dir()
            else sorted({p.parent.parent for p in root.glob("**/.hydra/config.yaml")})
        )
        jobs.extend(read_job(d) for d in dirs)
        sweep_dirs += [root, *sorted(p.parent for p in root.glob("**/multirun.yaml") if p.parent != root)]
    anywhere = [j.overrides for j in jobs]
    for sweep_dir in sweep_dirs:
        own = [j.overrides for j in jobs if j.path.parent == sweep_dir]
        for num, overrides in enumerate(sweep_jobs(sweep_dir)):
            expected = _override_dict(overrides)
            if expected in own:
                own.remove(expected)
            elif expected not in anywhere:  # matched by overrides: job dirs are named by number or controller
                jobs.append(Job(sweep_dir / str(num), expected, None, "missing", f"job {num} never started"))
    return jobs


def sweep_jobs(sweep_dir: Path) -> list[list[str]]:
    """The override list of each job a multirun defines (``multirun.yaml``: the command's
    overrides and the sweeper's params, expanded as Hydra's basic sweeper does), in job order."""
    path = sweep_dir / "multirun.yaml"
    if not path.is_file():
        return []
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from omegaconf import OmegaConf

    try:
        cfg = OmegaConf.load(path)
        hydra_cfg = cfg.hydra
        args = [f"{k}={v}" for k, v in (hydra_cfg.sweeper.get("params") or {}).items()]
        args += list(hydra_cfg.overrides.task)
        batches = BasicSweeper.split_arguments(OverridesParser.create().parse_overrides(args), None)
    except Exception:  # another sweeper (optuna ...) or a hand-edited file: list only what exists
        return []
    return [job for batch in batches for job in batch]


# overrides that change how a run is carried out, not what it trains or measures: never a row
BOOKKEEPING_KEYS = (
    "sweep",
    "budget",
    "threads",
    "train.progress",
    "train.progress_every_s",
    "train.threads",
    "train.checkpoint_every",
)


def _override_dict(items) -> dict[str, str]:
    overrides = {}
    for item in items:
        key, _, value = str(item).partition("=")
        key = key.lstrip("+~")
        if key not in BOOKKEEPING_KEYS and not key.startswith(("hydra", "logger")):
            overrides[key] = value
    return overrides


def read_job(path: Path) -> Job:
    """A job dir as the table reads it. A file that cannot be read (truncated, not text, no
    permission) makes the job ``errored`` with the file named: the table lists it and goes on."""
    ov_file = path / ".hydra" / "overrides.yaml"
    try:
        overrides = _override_dict(yaml.safe_load(ov_file.read_text()) or []) if ov_file.is_file() else {}
    except (OSError, ValueError, yaml.YAMLError) as exc:
        return Job(path, {}, None, "errored", _unreadable(ov_file, exc))
    failure = read_failure(path)
    if failure is not None:
        status = "diverged" if failure["status"] == "diverged" else "errored"
        return Job(path, overrides, None, status, str(failure.get("message", "")))
    metrics_file = path / "metrics.json"
    if metrics_file.is_file():
        try:
            metrics = json.loads(metrics_file.read_text())
        except (OSError, ValueError) as exc:
            return Job(path, overrides, None, "errored", _unreadable(metrics_file, exc))
        if not isinstance(metrics, dict):
            return Job(path, overrides, None, "errored", f"{metrics_file.name}: not a metrics record")
        if metrics.get("complete") is False:  # an evaluation stopped part-way: its finished seeds only
            return Job(path, overrides, None, "incomplete", f"stopped after seeds {metrics.get('seeds_done')}")
        return Job(path, overrides, metrics, "finished")
    return Job(path, overrides, None, "incomplete", _progress(path))


def _unreadable(path: Path, exc: BaseException) -> str:
    """``<file relative to its job dir>: unreadable (<reason>)``."""
    name = f".hydra/{path.name}" if path.parent.name == ".hydra" else path.name
    return f"{name}: unreadable ({one_line(exc)})"


def _progress(path: Path) -> str:
    rows = path / "metrics.csv"
    if not rows.is_file():
        return "no progress logged"
    try:
        lines = rows.read_text().strip().splitlines()
        if len(lines) < 2:
            return "no progress logged"
        last = dict(zip(lines[0].split(","), lines[-1].split(",")))
        return f"stopped at {int(float(last.get('frames', 0))):,} frames"
    except (OSError, ValueError) as exc:
        return _unreadable(rows, exc)


AUTHORS_SUFFIX = "@authors"  # row key suffix of a job measured under eval.protocol=authors


def _row_key(job: Job, spec: TableSpec, varying: set[str] | None = None) -> str:
    """Row of a job: its eval controller, or ``key=value`` of its swept overrides (the table's own
    keys such as ``ablation``/``horizon`` plus any key that differs between jobs; not ``seed``),
    plus :data:`AUTHORS_SUFFIX` when it was measured under the authors' protocol (so a table of
    two sweeps shows both protocols' rows side by side)."""
    suffix = _protocol_suffix(job)
    if spec.kind == "eval":
        return (job.metrics or {}).get("controller", job.overrides.get("controller", "?")) + suffix
    own = {"ablation", "horizon"}
    skip = {"seed", "eval.protocol"}
    keys = sorted(k for k in job.overrides if k not in skip and (k in own or varying is None or k in varying))
    return (",".join(f"{k}={job.overrides[k]}" for k in keys) or "base") + suffix


def varying_keys(jobs: list[Job]) -> set[str]:
    values: dict[str, set[str]] = {}
    for job in jobs:
        for k, v in job.overrides.items():
            values.setdefault(k, set()).add(v)
    return {k for k, v in values.items() if len(v) > 1 or any(k not in j.overrides for j in jobs)}


def _group_error(metrics: dict, condition: str | None, group: str) -> float | None:
    conds = metrics.get("conditions", {})
    cond = conds.get(condition) if condition else next(iter(conds.values()), None)
    if cond is None or group not in cond["groups"]:
        return None
    row = cond["groups"][group]
    if run_failed(row):  # the paper's "failed": most episodes diverged, all crashed among them
        return None
    mean = row["mean_m"]  # over the episodes its protocol counts (datt.eval.protocol)
    return mean if mean is not None and math.isfinite(mean) else None


def _episodes(metrics: dict, group: str) -> tuple[list[float], int]:
    """Per-episode errors of ``group`` pooled over every condition (seed) of an eval run, and
    the number of crashed/failed episodes (excluded from the values)."""
    values, failed = [], 0
    for cond in metrics.get("conditions", {}).values():
        row = cond["groups"].get(group)
        if row is None:
            continue
        crashed = row.get("per_episode_crashed", [False] * len(row["per_episode_m"]))
        if _counts_every_episode(row):  # a non-finite episode (null in strict JSON) fails
            crashed = [e is None or not math.isfinite(e) for e in row["per_episode_m"]]
        values += [e for e, c in zip(row["per_episode_m"], crashed) if not c]
        failed += sum(crashed)
    return values, failed


def collect(spec: TableSpec, jobs: list[Job]) -> tuple[dict[str, list[Cell]], dict]:
    """Cells per row key, and per-row extras (inference ms)."""
    rows: dict[str, list[Cell]] = {}
    extras: dict[str, dict] = {}
    varying = varying_keys(jobs)

    def cells(key: str) -> list[Cell]:
        return rows.setdefault(key, [Cell() for _ in spec.columns])

    for job in jobs:
        if job.status not in ("finished", "diverged"):  # errored/incomplete/missing: listed in the notes
            continue
        m = job.metrics or {}
        if spec.kind == "train":
            cells(_row_key(job, spec, varying))[0].add(
                _group_error(m, "clean", "zigzag") if job.status == "finished" else None
            )
        elif spec.kind == "rma":
            suffix = _protocol_suffix(job)
            for cond in spec.row_order:
                cells(cond + suffix)[0].add(_group_error(m, cond, "zigzag") if job.status == "finished" else None)
        elif spec.name == "main":
            key = _row_key(job, spec)
            row = cells(key)
            for col, group in ((0, "smooth"), (1, "zigzag")):
                values, failed = _episodes(m, group)
                row[col].values += values
                row[col].failed += failed
                row[col].total += len(values) + failed
            if "inference_ms" in m:
                extras.setdefault(key, {}).setdefault("inference_ms", []).append(m["inference_ms"]["median_ms"])
        else:  # wind: columns by (group, disturbance)
            key = _row_key(job, spec)
            dist = m.get("disturbance", job.overrides.get("disturbance"))
            col_of = {
                ("smooth", "plate"): 0,
                ("smooth", "wind_plate"): 1,
                ("zigzag", "plate"): 2,
                ("zigzag", "wind_plate"): 3,
            }
            for group in ("smooth", "zigzag"):
                col = col_of.get((group, dist))
                if col is None:
                    continue
                values, failed = _episodes(m, group)
                cell = cells(key)[col]
                cell.values += values
                cell.failed += failed
                cell.total += len(values) + failed
    for key, extra in extras.items():
        if spec.name == "main":
            ms = extra["inference_ms"]
            rows[key][2] = Cell(values=[float(np.median(ms))], total=1)
    return rows, extras


# -- rendering -----------------------------------------------------------------------------
def render(spec: TableSpec, rows: dict[str, list[Cell]], jobs: list[Job]) -> dict[str, str]:
    known = [k + suffix for k in spec.row_order for suffix in ("", AUTHORS_SUFFIX)]
    order = [k for k in known if k in rows] + sorted(k for k in rows if k not in known)
    header = ["method" if spec.kind != "train" else "ablation"] + spec.columns + [f"paper: {c}" for c in spec.columns]
    body = []
    for key in order:
        base = key.removesuffix(AUTHORS_SUFFIX)
        label = spec.row_labels.get(base, base) + (" (authors' protocol)" if key != base else "")
        ours = [c.text(digits=2 if "ms" in col else 3) for c, col in zip(rows[key], spec.columns)]
        seeds = max(c.total for c in rows[key]) if spec.kind in ("train", "rma") else None
        if seeds:
            label += f" [{seeds} run{'s' if seeds > 1 else ''}]"
        paper = spec.paper.get(base, ["—"] * len(spec.columns))
        body.append([label, *ours, *paper])
    protocols = ", ".join(sorted(evaluation_protocols(jobs))) or "project"
    md = [
        f"**{spec.title}** (ours: simulation, evaluation protocol {protocols} (datt.eval.protocol), "
        "mean ± std [95 % t-interval of the mean]; "
        f"paper: {spec.paper_note})",
        "",
        "| " + " | ".join(header) + " |",
    ]
    md.append("|" + "---|" * len(header))
    md += ["| " + " | ".join(r) + " |" for r in body]
    notes = job_notes(jobs)
    if notes:
        md += ["", *notes]
    tex = [
        "\\begin{tabular}{l" + "c" * (len(header) - 1) + "}",
        "\\toprule",
        " & ".join(_tex(h) for h in header) + " \\\\",
        "\\midrule",
    ]
    tex += [" & ".join(_tex(c) for c in r) + " \\\\" for r in body]
    tex += ["\\bottomrule", "\\end{tabular}"]
    numeric = numeric_rows(spec, rows, order)
    return {
        "md": "\n".join(md) + "\n",
        "tex": "\n".join(tex) + "\n",
        "rows": body,
        "header": header,
        "numeric": (NUMERIC_COLUMNS, numeric),
    }


# the table as numbers (wandb's Table: sortable, plottable): one row per (table row, column)
NUMERIC_COLUMNS = ["row", "column", "mean", "std", "ci95_low", "ci95_high", "values", "failed", "total", "paper"]


def paper_number(text: str) -> float | None:
    """The paper's figure in a cell (``"0.055 ± 0.007"`` -> 0.055); None for "failed", "—"."""
    match = re.match(r"\s*([-+]?\d+(?:\.\d*)?(?:[eE][-+]?\d+)?)", str(text))
    return float(match.group(1)) if match else None


def numeric_rows(spec: TableSpec, rows: dict[str, list[Cell]], order: list[str]) -> list[list]:
    """The cells of ``rows`` in ``order`` as :data:`NUMERIC_COLUMNS`: the row's label, the
    column, the mean and population std of its values (None without values), the 95 % interval of
    the mean (None under two values), how many values,
    failed and total, and the paper's figure for that cell (None where the paper has none)."""
    out = []
    for key in order:
        base = key.removesuffix(AUTHORS_SUFFIX)
        label = spec.row_labels.get(base, base) + (" (authors' protocol)" if key != base else "")
        paper = spec.paper.get(base, [None] * len(spec.columns))
        for cell, column, cited in zip(rows[key], spec.columns, paper):
            values = cell.values
            mean = float(np.mean(values)) if values else None
            std = float(np.std(values)) if values else None
            low, high = cell.interval95() or (None, None)
            out.append([label, column, mean, std, low, high, len(values), cell.failed, cell.total, paper_number(cited)])
    return out


def job_protocols(job: Job) -> set[str]:
    """The evaluation protocols a job's metrics were measured under (``project`` for records
    written before the protocol was recorded)."""
    found = set()
    for cond in (job.metrics or {}).get("conditions", {}).values():
        for row in cond.get("groups", {}).values():
            found.add(row.get("protocol", "project"))
    return found


def _protocol_suffix(job: Job) -> str:
    return AUTHORS_SUFFIX if "authors" in job_protocols(job) else ""


def _counts_every_episode(row: dict) -> bool:
    """Whether a summary row's mean runs over every episode (its protocol's accounting)."""
    return get_protocol(row.get("protocol", "project")).count_every_step


def evaluation_protocols(jobs: list[Job]) -> set[str]:
    return set().union(*(job_protocols(job) for job in jobs)) if jobs else set()


def _tex(text: str) -> str:
    text = text.replace("±", "$\\pm$").replace("d̂", "$\\hat d$").replace("_", "\\_").replace("%", "\\%")
    return "\\textit{failed}" if text == "failed" else text


def job_notes(jobs: list[Job]) -> list[str]:
    notes = []
    for job in jobs:
        if job.status == "incomplete":
            notes.append(f"- incomplete: `{job.path}` ({job.note})")
        elif job.status == "diverged":
            notes.append(f"- failed (diverged): `{job.path}` {job.note}".rstrip())
        elif job.status == "errored":
            notes.append(f"- errored: `{job.path}` {job.note}".rstrip())
        elif job.status == "missing":
            notes.append(f"- missing: {job.note} ({_format_overrides(job.overrides)})")
    return notes


def _format_overrides(overrides: dict[str, str]) -> str:
    return " ".join(f"{k}={v}" for k, v in overrides.items()) or "no overrides"


def write(spec: TableSpec, rendered: dict, out_dir: Path) -> list[Path]:
    out_dir.mkdir(parents=True, exist_ok=True)
    md, tex, csv_path = out_dir / f"{spec.name}.md", out_dir / f"{spec.name}.tex", out_dir / f"{spec.name}.csv"
    md.write_text(rendered["md"])
    tex.write_text(rendered["tex"])
    with open(csv_path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(rendered["header"])
        w.writerows(rendered["rows"])
    return [md, csv_path, tex]


def default_roots(spec: TableSpec, outputs: Path) -> list[Path]:
    """The newest sweep dir of this table under ``outputs/sweeps/<table>/``."""
    base = outputs / "sweeps" / spec.name
    dirs = sorted(p for p in base.glob("*") if p.is_dir()) if base.is_dir() else []
    if not dirs:
        raise ConfigError(
            f"runs: no sweep under {base}; run `python {spec.entry} +sweep={spec.name}` or pass runs=<sweep dir>"
        )
    return [dirs[-1]]


def get_spec(name: str) -> TableSpec:
    if name not in TABLES:
        raise ConfigError(f"table: unknown table {name!r}; allowed: {', '.join(TABLES)}")
    return TABLES[name]


# -- plots ---------------------------------------------------------------------------------
def _horizon_of(key: str) -> int | None:
    for part in key.removesuffix(AUTHORS_SUFFIX).split(","):
        k, _, v = part.partition("=")
        if k == "horizon" and v.isdigit():
            return int(v)
        if k == "ablation" and v in ("none", "h1", "h5", "h15", "h20"):
            return 10 if v == "none" else int(v[1:])
    return None


def plot_train_sweep(spec: TableSpec, rows: dict[str, list[Cell]], jobs: list[Job], out_dir: Path) -> list[Path]:
    """Horizon vs zigzag error (mean ± std over seeds) and learning curves (mean per row)."""
    import matplotlib

    matplotlib.use("Agg")
    paths = []
    points = sorted((h, c) for k, cs in rows.items() if (h := _horizon_of(k)) is not None for c in cs[:1])
    if points:
        paths.append(_plot_horizon(points, out_dir / f"{spec.name}_horizon.png"))
    curves = _learning_curves(spec, jobs)
    if curves:
        paths.append(_plot_curves(spec, curves, out_dir / f"{spec.name}_curves.png"))
    return paths


def _plot_horizon(points: list[tuple[int, Cell]], path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.6))
    ok = [(h, c) for h, c in points if c.values]
    if ok:
        ax.errorbar(
            [h for h, _ in ok],
            [np.mean(c.values) for _, c in ok],
            yerr=[np.std(c.values) for _, c in ok],
            marker="o",
            capsize=3,
            label="ours (sim)",
        )
        ax.legend()
    for h, c in points:
        if not c.values:
            ax.annotate("failed", (h, 0), textcoords="offset points", xytext=(0, 8), ha="center", color="C3")
    ax.set_xlabel("feedforward points H")
    ax.set_ylabel("zigzag tracking error (m)")
    ax.set_xticks([h for h, _ in points])
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def _learning_curves(spec: TableSpec, jobs: list[Job]) -> dict[str, list[tuple[np.ndarray, np.ndarray]]]:
    """Per row, each job's (frames, training tracking error) from its ``metrics.csv``."""
    curves: dict[str, list[tuple[np.ndarray, np.ndarray]]] = {}
    varying = varying_keys(jobs)
    for job in jobs:
        f = job.path / "metrics.csv"
        if not f.is_file():
            continue
        try:
            with open(f) as fh:
                data = list(csv.DictReader(fh))
            if data and "tracking_error_m" in data[0]:
                x = np.array([float(r["frames"]) for r in data])
                y = np.array([float(r["tracking_error_m"]) for r in data])
                curves.setdefault(_row_key(job, spec, varying), []).append((x, y))
        except (OSError, ValueError, TypeError, KeyError):  # a truncated or hand-edited log: no curve
            continue
    return curves


def _plot_curves(spec: TableSpec, curves: dict[str, list[tuple[np.ndarray, np.ndarray]]], path: Path) -> Path:
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4))
    for key in [k for k in spec.row_order if k in curves] + sorted(k for k in curves if k not in spec.row_order):
        n = min(len(x) for x, _ in curves[key])
        x = curves[key][0][0][:n]
        y = np.mean([c[1][:n] for c in curves[key]], axis=0)
        ax.plot(x, y, label=f"{spec.row_labels.get(key, key)} ({len(curves[key])})", lw=1.2)
    ax.set_yscale("log")
    ax.set_xlabel("env steps")
    ax.set_ylabel("training tracking error (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_side_by_side_from_jobs(jobs: list[Job], group: str, index: int, path: Path) -> Path | None:
    """Every eval job's saved trace (``trace_seed<k>.pt``, first seed) on one reference: the
    ``index``-th of ``group``. None when no job saved a trace."""
    from types import SimpleNamespace

    import torch

    from datt.eval.plots import plot_side_by_side

    traces, dt_s = {}, 0.02
    for job in jobs:
        files = sorted(job.path.glob("trace_seed*.pt"))
        if job.metrics is None or not files:
            continue
        try:
            data = torch.load(files[0], weights_only=True)
        except Exception:  # a truncated or foreign file: this controller has no trace to show
            continue
        if not isinstance(data, dict) or group not in data.get("names", ()):
            continue
        start = sum(data["counts"][: data["names"].index(group)])
        traces[job.metrics.get("controller", job.path.name)] = (SimpleNamespace(**data), start + index)
    if not traces:
        return None
    ordered = {name: tr for name, (tr, _) in traces.items()}
    idx = next(iter(traces.values()))[1]
    return plot_side_by_side(ordered, idx, dt_s, path, title=f"{group} #{index}: controllers side by side")
