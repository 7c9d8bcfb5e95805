"""Entry points: ``train.py`` / ``eval.py`` / ``tables.py`` / ``deploy.py`` (root shims), the
``datt`` console script and ``python -m datt``.

Only entry points and error reporting live here: every user error ends in one line on stderr
(``error: <key>: <what>``) and exit code 2; a diverged training run exits with 3; a multirun exits
with the number of its jobs that did not finish.
"""

from __future__ import annotations

import contextlib
import errno
import re
import shutil
import signal
import sys
import tempfile
import traceback
from collections.abc import Callable
from pathlib import Path

from omegaconf import DictConfig

from datt.configuration import (
    CONF_PACKAGE,
    available_options,
    conf_dir,
    config_groups,
    refuse_retired_keys,
    root_from_uri,
)
from datt.errors import ConfigError, FlightAborted, FlightStopped, TrainingDiverged, TrainingInterrupted, one_line
from datt.runs import (
    OWN_RUN,
    ignore_stop_signals,
    read_failure,
    record_failure,
    requeue_with_scheduler,
    retire_failure,
    stop_children,
    stop_signals,
)


def _split_argv(argv: list[str]) -> tuple[list[str], list[str], bool]:
    """A Hydra command line as (``--config-dir``/``-cd`` values, overrides, whether it uses any
    other flag such as ``--cfg`` or ``--info``); ``-m``/``--multirun`` is dropped."""
    dirs, overrides, other, skip = [], [], False, False
    for i, arg in enumerate(argv):
        if skip:
            skip = False
        elif arg in ("--config-dir", "-cd"):
            dirs += argv[i + 1 : i + 2]
            skip = True
        elif arg.startswith("--config-dir="):
            dirs.append(arg.split("=", 1)[1])
        elif arg in ("-m", "--multirun"):
            continue
        elif arg.startswith("-"):
            other = True
        else:
            overrides.append(arg)
    return dirs, overrides, other


def _argv_search_roots(argv: list[str]) -> list[Path]:
    """The config search path the command line asks for: ``--config-dir``/``-cd`` and
    ``hydra.searchpath=[...]`` before the package's own tree (as Hydra orders them)."""
    dirs, overrides, _ = _split_argv(argv)
    roots = [Path(d).expanduser().resolve() for d in dirs if d]
    for arg in overrides:
        key = arg.lstrip("+")
        if key.startswith("hydra.searchpath="):
            for item in key.split("=", 1)[1].strip("[]").split(","):
                root = root_from_uri(item.strip().strip("'\""))
                if root is not None:
                    roots.append(root)
    return [*roots, conf_dir()]


def check_config_dirs(argv: list[str]) -> None:
    """Each ``--config-dir`` is a directory whose YAML files parse: one line naming the dir or the
    file (and the YAML's own line) instead of Hydra's traceback."""
    import yaml

    for text in _split_argv(argv)[0]:
        path = Path(text).expanduser()
        if not path.exists():
            raise ConfigError(f"--config-dir: {path} does not exist; give the directory that holds your config tree")
        if not path.is_dir():
            raise ConfigError(f"--config-dir: {path} is a file; give the directory that holds your config tree")
        for file in sorted(path.rglob("*.yaml")):
            try:
                yaml.safe_load(file.read_text())
            except yaml.YAMLError as exc:
                mark = getattr(exc, "problem_mark", None)
                where = f" (line {mark.line + 1}: {getattr(exc, 'problem', None) or 'invalid'})" if mark else ""
                raise ConfigError(f"--config-dir: {file} is not valid YAML{where}") from None
            except (OSError, UnicodeDecodeError) as exc:
                raise ConfigError(f"--config-dir: {file} cannot be read ({one_line(exc)})") from None


def hydra_group_options(group: str, roots: list[Path]) -> list[str]:
    """The options of Hydra's own config group ``group`` (``hydra/launcher``: Hydra's and its
    plugins', the package's, a ``--config-dir`` tree's)."""
    from hydra import initialize_config_module
    from hydra.core.global_hydra import GlobalHydra

    options = set()
    with initialize_config_module(config_module=CONF_PACKAGE, version_base="1.3"):
        options.update(GlobalHydra.instance().config_loader().get_group_options(group))
    for root in roots:
        options.update(p.stem for p in (root / group).glob("*.yaml"))
    return sorted(options)


def check_hydra_options(argv: list[str], roots: list[Path]) -> None:
    """Hydra's own groups (``hydra/launcher=...``, options over the search path ``roots``) and the
    launcher's job count, in one line."""
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+~")
        if key.startswith("hydra/") and "," not in value:
            allowed = hydra_group_options(key, roots)
            if value not in allowed:
                raise ConfigError(f"{key}: unknown option {value!r}; allowed: {', '.join(allowed)}")
        if key == "hydra.launcher.n_jobs":
            try:
                jobs = int(value)
            except ValueError:
                jobs = 0
            if jobs == 0 or str(jobs) != value.strip():
                raise ConfigError(
                    f"hydra.launcher.n_jobs: must be an integer >= 1 (or -1: one job per core), got {value!r}"
                )


def preflight(argv: list[str]) -> None:
    """Reject unknown config-group options (over the whole search path) in one line, before
    Hydra prints a multi-line error."""
    refuse_retired_keys([arg for arg in argv if "=" in arg and not arg.startswith("-")])
    check_config_dirs(argv)
    roots = _argv_search_roots(argv)
    check_hydra_options(argv, roots)
    groups = config_groups(roots)
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        group = key.lstrip("+~").split("@")[0]
        if group in groups and "," not in value and "(" not in value and value != "null":
            allowed = available_options(group, roots)
            if value not in allowed:
                raise ConfigError(f"{group}: unknown option {value!r}; allowed: {', '.join(allowed)}")


def _overrides_of(argv: list[str]) -> list[str] | None:
    """The Hydra overrides of a command line, with its whole search path (``--config-dir`` and
    ``hydra.searchpath``) as one search-path override; None when the line uses other Hydra flags
    (``--cfg``, ``--info`` ...: nothing to check)."""
    dirs, overrides, other = _split_argv(argv)
    if other:
        return None
    if dirs:
        paths = ",".join(f"file://{root}" for root in _argv_search_roots(argv)[:-1])
        overrides = [o for o in overrides if not o.lstrip("+").startswith("hydra.searchpath=")]
        overrides.append(f"hydra.searchpath=[{paths}]")
    return overrides


def check_composition(config_name: str, argv: list[str]) -> None:
    """Compose the config the command line asks for (each value of a sweep list in turn) and
    check it against the schemas (:mod:`datt.tasks.validation`), so an unknown key or option and
    a value out of its range are one line before any job starts, not Hydra's multi-line report."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import HydraException

    from datt.configuration import compose

    overrides = _overrides_of(argv)
    if overrides is None:
        return
    kept = [o for o in overrides if not o.lstrip("+~").startswith("hydra") or o.startswith("hydra.searchpath=")]
    try:
        parsed = OverridesParser.create().parse_overrides(kept)
    except HydraException as exc:
        hint = ""
        if any(re.match(r"[\w.]+=\[[^'\"\]]*=", o) for o in kept):  # key=[a=b]: an unquoted override in a list
            hint = "; quote each item of a list that holds overrides: \"sweep_overrides=['budget=0.2']\""
        raise ConfigError(f"overrides: {one_line(exc)}{hint}") from None
    firsts, variants = [], []
    for text, ov in zip(kept, parsed):
        if ov.is_sweep_override():
            try:
                values = list(ov.sweep_string_iterator())
            except HydraException:  # range()/interval(): the sweeper expands it, nothing to check here
                continue
            key = ov.get_key_element()
            firsts.append(f"{key}={values[0]}")
            variants += [(len(firsts) - 1, f"{key}={v}") for v in values[1:]]
        else:
            firsts.append(text)
    from datt.configuration import preflight_command
    from datt.tasks.validation import validate_composed

    for chosen in [firsts, *([*firsts[:i], text, *firsts[i + 1 :]] for i, text in variants)]:
        with preflight_command(_argv_search_roots(argv), chosen):
            validate_composed(config_name, compose(config_name, chosen))


def _output_dir_arg(argv: list[str]) -> tuple[str, str | None]:
    """The key the command's output dir is set by (``hydra.sweep.dir`` for a multirun, a
    ``sweep=`` or a ``search=``, else ``hydra.run.dir``) and the value the command line gives it
    (the last; None: unset)."""
    multirun = any(a in ("-m", "--multirun") for a in argv) or any(
        a.lstrip("+").startswith(("sweep=", "search=")) for a in argv
    )
    key = "hydra.sweep.dir" if multirun else "hydra.run.dir"
    given = [a.split("=", 1)[1] for a in argv if a.startswith(key + "=")]
    return key, (given[-1] if given else None)


# Room a run needs on its disk before it starts: its config, log and first records (a training's
# checkpoints are ~1 MB each; a flight asks for more before arming, deploy.flight_log)
RUN_MIN_FREE_BYTES = 10_000_000


def check_output_dir(argv: list[str]) -> None:
    """The directory runs will be written under must be creatable: one line before Hydra tries
    (and prints a traceback). Interpolated parts (``${now:...}``) are cut off."""
    key, given = _output_dir_arg(argv)
    default = "outputs/multirun" if key == "hydra.sweep.dir" else "outputs"
    target = default if given is None else (given.split("${")[0] or ".")
    path = Path(target).expanduser().absolute()
    base = path
    while not base.exists():
        base = base.parent
    problem, advice = None, f"run from a writable directory or set {key}=<writable dir>"
    if not base.is_dir():
        problem = f"{base} is a file, not a directory"
    else:
        try:
            tempfile.TemporaryDirectory(dir=base).cleanup()
        except OSError as exc:
            problem = f"cannot write in {base} ({exc.strerror})"
    if problem is None:
        # Hydra writes .hydra/ before any task runs, and reports a failed write as a traceback of
        # its own (it never reaches this entry's handler): a disk without room refuses here
        free = shutil.disk_usage(base).free
        if free < RUN_MIN_FREE_BYTES:
            need_mb = RUN_MIN_FREE_BYTES / 1e6
            problem = f"{free / 1e6:.2f} MB free on its disk, under the {need_mb:.0f} MB a run's records need"
            advice = f"free some space or set {key}=<another disk>"
    if problem:
        raise ConfigError(f"{key}: {path}: {problem}; {advice}")


# What a run of any entry point leaves in its dir: a dir holding one of these holds a run, and no
# command writes into it (Hydra would replace its .hydra/ before the task starts, a training its
# checkpoints, an evaluation its metrics.json).
RUN_RECORDS = (
    ".hydra",
    "last.pt",
    "best.pt",
    "metrics.json",
    "metrics.csv",
    "flight.csv",
    "events.json",
    "failed.json",
)


def run_records(path: Path) -> list[str]:
    """The names of :data:`RUN_RECORDS` that ``path`` holds."""
    return [name for name in RUN_RECORDS if (path / name).exists()]


def check_run_dir(argv: list[str]) -> None:
    """The run-dir contract of every entry point: an explicit ``hydra.run.dir`` (or, for a
    multirun, ``hydra.sweep.dir``) is new, empty or holds no run's records; one that holds a run
    is refused in one line naming ``resume=`` and how to start a fresh one, and an empty value is
    refused. The default dirs are new by construction (a timestamp and 4 random hex digits)."""
    key, given = _output_dir_arg(argv)
    if given is None or f"resume={OWN_RUN}" in argv:  # a carried-on sweep writes into its own job dirs
        return
    text = given.strip().strip("'\"")
    if not text:
        raise ConfigError(f"{key}: empty; give a directory, or leave {key} unset for a new one under outputs/")
    if "${" in text:  # interpolated (a timestamp, a job's override): a new dir per command
        return
    path = Path(text).expanduser().absolute()
    if not path.is_dir():
        return
    held = run_records(path)
    if key == "hydra.sweep.dir":
        held += [f"{job.name}/{name}" for job in sorted(path.iterdir()) if job.is_dir() for name in run_records(job)]
    if held:
        raise ConfigError(
            f"{key}: {path} already holds a run ({', '.join(held[:3])}{' ...' if len(held) > 3 else ''}); "
            f"nothing is written over it: carry a training on with resume={path} (without {key}), "
            f"or leave {key} unset for a new dir under outputs/, or give one that holds no run"
        )


# what may change when a sweep is carried on: where and how its jobs run, not what they train
SWEEP_RESUME_CHANGEABLE = ("hydra/launcher=", "hydra.launcher.", "threads=", "logger.mode=")


def sweep_resume_argv(config_name: str, argv: list[str]) -> list[str] | None:
    """``train.py resume=<sweep dir>``: the command line that carries a whole multirun on, or None
    when ``resume=`` names no sweep dir. It is the sweep's own command line (its overrides from
    ``<sweep dir>/multirun.yaml``) in that sweep dir, each job with ``resume=own``: a job whose dir
    holds a finished run reports it and trains nothing, one that stopped resumes from its
    ``last.pt``, one that never started trains. The same job numbers map to the same overrides
    (Hydra enumerates a sweep in a fixed order). Only the launcher and its options may change."""
    given = [a.split("=", 1)[1] for a in argv if a.startswith("resume=")]
    if config_name != "train" or not given:
        return None
    sweep = Path(given[-1]).expanduser().absolute()
    record = sweep / "multirun.yaml"
    if not record.is_file():
        return None
    others = [a for a in argv if not a.startswith(("resume=", "-m", "--multirun"))]
    fixed = [a for a in others if not a.lstrip("+~").startswith(SWEEP_RESUME_CHANGEABLE)]
    if fixed:
        raise ConfigError(
            f"resume: {sweep} is a sweep: it carries on as it was launched; drop {fixed[0]!r} "
            f"(only {', '.join(k.rstrip('=.') for k in SWEEP_RESUME_CHANGEABLE)} may change)"
        )
    from omegaconf import OmegaConf

    try:
        saved = OmegaConf.load(record).hydra
        task, hydra = [str(o) for o in saved.overrides.task], [str(o) for o in saved.overrides.hydra]
        sweeper = str(OmegaConf.select(saved, "sweeper._target_", default="") or "")
    except Exception as exc:  # a damaged or foreign file: one line, nothing launched
        raise ConfigError(f"resume: {record} is not a Hydra sweep record ({one_line(exc)})") from None
    if sweeper and not sweeper.endswith("BasicSweeper"):  # a search: its next trials depend on its study
        raise ConfigError(
            f"resume: {sweep} is a search ({sweeper.rsplit('.', 1)[-1]}), not a grid: its study is not kept, "
            "so it cannot be carried on; run the search again"
        )
    task = [o for o in task if not o.lstrip("+~").startswith("resume=")]
    hydra = [o for o in hydra if not o.startswith(("hydra.mode=", "hydra.sweep.dir=", "hydra.run.dir="))]
    jobs = [p for p in sweep.iterdir() if p.is_dir() and p.name.isdigit()]
    log_line = f"resume: carrying on sweep {sweep} ({len(jobs)} job dirs): finished jobs are kept, stopped ones resume"
    print(log_line)
    return ["-m", *task, f"resume={OWN_RUN}", *hydra, *others, f"hydra.sweep.dir={sweep}"]


# what the machine, not the code, refuses: a full disk, a read-only mount, no permission
FILE_FAULTS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO})


def file_fault_line(exc: OSError) -> str:
    """One line for a file the command could not write or read (what was already written is
    kept: checkpoints and records are written atomically)."""
    where = f"{exc.filename}: " if exc.filename else ""
    hint = {
        errno.ENOSPC: "free some space (or set hydra.run.dir=<another disk>)",
        errno.EDQUOT: "free some space (or set hydra.run.dir=<another disk>)",
        errno.EROFS: "copy the run to a writable place and run it there (or set hydra.run.dir=<writable dir>)",
    }.get(exc.errno or 0, "check the path's permissions (or set hydra.run.dir=<writable dir>)")
    return f"{where}{exc.strerror or one_line(exc)}; {hint}; files written before are kept"


def _fail(message: str, code: int) -> None:
    """The command's one error line on stderr, also into the run's log file (when Hydra's job
    logging has opened one), and exit ``code``."""
    print(f"error: {message}", file=sys.stderr)
    import logging

    record = logging.LogRecord("datt", logging.ERROR, __file__, 0, f"error: {message}", None, None)
    for handler in logging.getLogger().handlers:
        if isinstance(handler, logging.FileHandler):
            handler.handle(record)
    sys.exit(code)


def run_tool(main) -> None:
    """Run a ``tools/`` script's ``main()`` with the entry points' error contract: a user error
    (:class:`ConfigError`) is one line on stderr and exit 2."""
    try:
        main()
    except ConfigError as exc:
        _fail(str(exc), 2)


# Failed jobs of the multirun that ran in this process (set by SweepReport, read by the entry).
_failed_jobs = 0


def _in_multirun() -> bool:
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        return HydraConfig.get().mode == RunMode.MULTIRUN
    except (ImportError, ValueError):
        return False


def _job_failed(status: str, message: str, trace: str | None = None) -> None:
    """A failing multirun job: record why in its ``failed.json`` and let the sweep go on."""
    from hydra.core.hydra_config import HydraConfig

    hc = HydraConfig.get()
    job_dir = Path(hc.runtime.output_dir)
    if read_failure(job_dir) is None:  # the task may have written a fuller record (frames)
        record_failure(job_dir, status, message)
    if trace:
        (job_dir / "traceback.txt").write_text(trace)
    overrides = " ".join(o for o in hc.overrides.task if not o.startswith("hydra"))
    print(f"error: job {hc.job.num} ({overrides}): {message}", file=sys.stderr)


def sweep_summary(sweep_dir: Path) -> dict[str, int]:
    """Jobs of a sweep dir by state, as ``tables.py`` reads them: done, diverged, errored,
    incomplete."""
    from datt.eval.tables import read_job

    counts = {"done": 0, "diverged": 0, "errored": 0, "incomplete": 0}
    for job in sorted(p.parent for p in sweep_dir.glob("*/.hydra")):
        status = read_job(job).status
        counts["done" if status == "finished" else status] += 1
    return counts


try:
    from hydra.experimental.callback import Callback as _HydraCallback
except ImportError:  # pragma: no cover - hydra-core is a dependency
    _HydraCallback = object  # type: ignore[assignment,misc]


# The sweep dir of the multirun this process launches (set when it starts, for the line a signal prints).
_sweep_dir: Path | None = None


class SweepReport(_HydraCallback):
    """Hydra callback (``conf/hydra/default.yaml``): after a multirun, one line per state and the
    number of failed jobs for the exit status."""

    def on_multirun_start(self, config: DictConfig, **kwargs: object) -> None:
        global _sweep_dir
        _sweep_dir = Path(str(config.hydra.sweep.dir))

    def on_multirun_end(self, config: DictConfig, **kwargs: object) -> None:
        global _failed_jobs
        sweep_dir = Path(str(config.hydra.sweep.dir))
        counts = sweep_summary(sweep_dir)
        _failed_jobs = counts["diverged"] + counts["errored"] + counts["incomplete"]
        print(sweep_line(sweep_dir, counts, "none"), file=sys.stderr)


def sweep_line(sweep_dir: Path, counts: dict[str, int], empty: str) -> str:
    """``sweep <dir>: <n> jobs: <k> done, ...`` (``empty`` when no job has a dir)."""
    states = ", ".join(f"{n} {state}" for state, n in counts.items() if n)
    return f"sweep {sweep_dir}: {sum(counts.values())} jobs: {states or empty}"


def _sweep_state() -> str:
    """``: sweep <dir>: ...`` (:func:`sweep_line`) for a multirun this process launched, else ''."""
    if _sweep_dir is None or not _sweep_dir.is_dir():
        return ""
    return ": " + sweep_line(_sweep_dir, sweep_summary(_sweep_dir), "none started")


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def sigterm_as_interrupt() -> contextlib.AbstractContextManager:
    """SIGTERM ends a command like Ctrl-C (one line, exit 130; what was written stays), where the
    task installs no handler of its own (training and flights stop at a safe point themselves).
    A SIGTERM handler set before (an embedding program's) is left alone."""
    if signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, None):
        return contextlib.nullcontext()
    return stop_signals(_interrupt, (signal.SIGTERM,))


def _job_lock(lock: bool) -> contextlib.AbstractContextManager:
    """The job's run dir held for the task (``lock``), so that a second command on the same dir is
    refused in one line naming the holder instead of mixing its records in; training takes the
    lock itself (on the dir it trains in, which a resume changes)."""
    if not lock:
        return contextlib.nullcontext()
    from hydra.core.hydra_config import HydraConfig

    from datt.runs import RunLock

    return RunLock(HydraConfig.get().runtime.output_dir)


def _run_job(task: Callable[[DictConfig], object], cfg: DictConfig, lock: bool = True) -> float | None:
    """Run ``task`` as one Hydra job, mapping each error to its exit line and status (see
    :func:`hydra_main`); a job of a multirun records ``failed.json`` instead of exiting. Returns
    the job's headline figure (``optimized_metric`` of its result, for a sweeper such as
    Optuna's), None for a job that failed or has none."""
    from datt.tasks.common import headline

    multirun = _in_multirun()
    try:
        with sigterm_as_interrupt(), _job_lock(lock):
            if multirun:  # a job carried on by resume=<sweep dir>: its records are of this attempt
                from hydra.core.hydra_config import HydraConfig

                retire_failure(HydraConfig.get().runtime.output_dir)
            return headline(task(cfg), cfg.get("optimized_metric"))
    except ConfigError as exc:
        if not multirun:
            _fail(str(exc), 2)
        _job_failed("errored", str(exc))
    except FlightAborted as exc:
        if not multirun:
            ignore_stop_signals()  # the flight is over and logged; only the exit is left
            _fail(f"flight {exc}", 4)
        _job_failed("errored", f"flight {exc}")
    except TrainingInterrupted as exc:
        # a scheduler's preemption signal: requeued, and the next attempt resumes in its own run dir
        requeue_with_scheduler(exc.signal, f"preempted ({exc}); the scheduler requeues this job")
        ignore_stop_signals()
        _fail(f"interrupted by {exc}", 130)  # the user stops the whole sweep too
    except FlightStopped as exc:
        ignore_stop_signals()
        _fail(f"flight {exc}", 130)
    except KeyboardInterrupt as exc:
        ignore_stop_signals()
        _fail(f"interrupted by {exc.args[0] if exc.args else 'SIGINT'}", 130)
    except TrainingDiverged as exc:
        if not multirun:
            _fail(f"training diverged: {exc}", 3)
        _job_failed("diverged", f"training diverged: {exc}")
    except OSError as exc:
        if exc.errno not in FILE_FAULTS:
            if not multirun:
                raise
            _job_failed("errored", f"{type(exc).__name__}: {one_line(exc)}", traceback.format_exc())
            return None
        if not multirun:
            _fail(file_fault_line(exc), 2)
        _job_failed("errored", file_fault_line(exc))
    except Exception as exc:  # a crash in one job must not take the sweep's other jobs with it
        if not multirun:
            raise
        _job_failed("errored", f"{type(exc).__name__}: {one_line(exc)}", traceback.format_exc())
    return None  # a failed job of a multirun has no figure


def hydra_main(config_name: str, task: Callable[[DictConfig], object], lock: bool = True) -> Callable[[], None]:
    """``task`` wrapped in ``@hydra.main`` (config tree from the package) with one-line errors.

    A single run exits 2 on a user error, 3 on a divergence, 4 on a flight that did not land,
    130 when interrupted (after saving). A job of a multirun never exits:
    it records ``failed.json`` and the sweep goes on; the multirun exits with the number of jobs
    that did not finish (0 = all done)."""
    import hydra

    @hydra.main(config_path=f"pkg://{CONF_PACKAGE}", config_name=config_name, version_base="1.3")
    def _main(cfg: DictConfig) -> float | None:
        return _run_job(task, cfg, lock)  # what a sweeper reads

    def entry() -> None:
        global _failed_jobs, _sweep_dir
        _failed_jobs, _sweep_dir = 0, None
        if any(arg in ("-h", "--help") for arg in sys.argv[1:]):  # ours; Hydra's page is --hydra-help
            from datt.usage import help_text

            print(help_text(config_name, Path(sys.argv[0]).name if sys.argv[0].endswith(".py") else sys.argv[0]))
            sys.exit(0)
        try:
            carried_on = sweep_resume_argv(config_name, sys.argv[1:])
            if carried_on is not None:
                sys.argv[1:] = carried_on
            preflight(sys.argv[1:])
            check_composition(config_name, sys.argv[1:])
            check_output_dir(sys.argv[1:])
            check_run_dir(sys.argv[1:])
        except ConfigError as exc:
            _fail(str(exc), 2)
        try:
            # the launching process too: SIGTERM becomes the KeyboardInterrupt on which joblib's
            # launcher stops its worker processes (by default the signal ended this process alone
            # and the workers trained on); a job of the basic launcher ends itself (_run_job)
            with sigterm_as_interrupt():
                _main()
        except KeyboardInterrupt as exc:
            ignore_stop_signals()
            stop_children()  # a launcher's job processes end before the command does (and its line counts them)
            _fail(f"interrupted by {exc.args[0] if exc.args else 'SIGINT'}{_sweep_state()}", 130)
        except OSError as exc:  # Hydra's own writes (.hydra/, the job log) on a full or read-only disk
            if exc.errno not in FILE_FAULTS:
                raise
            _fail(file_fault_line(exc), 2)
        if _failed_jobs:
            sys.exit(min(_failed_jobs, 100))

    return entry


def _task(module: str, name: str) -> Callable[[DictConfig], object]:
    """Import the task on first use: ``datt --help``-like paths stay free of torch/TorchRL imports."""

    def run(cfg: DictConfig) -> object:
        import importlib

        return getattr(importlib.import_module(module), name)(cfg)

    return run


def _tables_entry(inner: Callable[[], None]) -> Callable[[], None]:
    """``tables.py ablation`` = ``tables.py table=ablation`` (a positional table name)."""

    def entry() -> None:
        if len(sys.argv) > 1 and "=" not in sys.argv[1] and not sys.argv[1].startswith("-"):
            sys.argv[1] = f"table={sys.argv[1]}"
        inner()

    return entry


train_main = hydra_main("train", _task("datt.tasks.train", "run_train"), lock=False)  # locks its own dir
eval_main = hydra_main("eval", _task("datt.tasks.eval", "run_eval"))
tables_main = _tables_entry(hydra_main("tables", _task("datt.tasks.tables", "run_tables")))
deploy_main = hydra_main("deploy", _task("datt.tasks.deploy", "run_deploy_command"))
export_main = hydra_main("export", _task("datt.tasks.export", "run_export"))
fit_rma_main = hydra_main("fit_rma", _task("datt.tasks.rma", "run_fit_rma"))
COMMANDS = {
    "train": train_main,
    "fit_rma": fit_rma_main,
    "eval": eval_main,
    "tables": tables_main,
    "deploy": deploy_main,
    "export": export_main,
}


# what each subcommand does, for ``datt --help``
SUBCOMMANDS = {
    "train": "train a policy with PPO (python train.py)",
    "fit_rma": "fit an RMA adapter to a trained policy",
    "eval": "evaluate a controller over the seeded reference bank",
    "tables": "build a paper table from its sweep (tables.py <table> [run=true])",
    "deploy": "fly a policy on a Crazyflie or the simulated one",
    "export": "export a policy to C, the Crazyflie app, TorchScript or ONNX",
}


def main() -> None:
    """``datt <command> [hydra overrides]``; ``datt --help`` lists the commands."""
    usage = f"usage: datt {{{','.join(COMMANDS)}}} [overrides...]"
    if len(sys.argv) >= 2 and sys.argv[1] in ("-h", "--help", "help"):
        lines = [usage, "", "commands:", *(f"  {name:8} {text}" for name, text in SUBCOMMANDS.items())]
        print("\n".join([*lines, "", "datt <command> --help: the command's options, examples and config groups"]))
        sys.exit(0)
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS:
        print(usage, file=sys.stderr)
        sys.exit(2)
    command = sys.argv.pop(1)
    sys.argv[0] = f"datt {command}"
    COMMANDS[command]()


__all__ = ["main", "train_main", "fit_rma_main", "eval_main", "tables_main", "deploy_main", "export_main", "preflight"]
