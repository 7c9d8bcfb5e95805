"""Run directories that never lose work: an exclusive lock while a process writes a run, failure
records a sweep can read, and JSON/permissions every tool can read.

A run dir is locked with ``flock`` on ``<run>/.lock`` (released by the kernel when the holder
exits, so a killed run never leaves a stale lock); the file names the holder.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import signal
import socket
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any

from datt.errors import ConfigError

try:  # POSIX; elsewhere runs are not locked
    import fcntl
except ImportError:  # pragma: no cover - Windows
    fcntl = None  # type: ignore[assignment]

LOCK_NAME = ".lock"
FAILED_NAME = "failed.json"

# ``resume=own``: a job resumes the run its own dir holds, if any (what ``train.py resume=<sweep dir>``
# gives every job of the sweep it carries on: datt.cli.sweep_resume_argv)
OWN_RUN = "own"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def public_mode(path: str | Path) -> None:
    """Give a file written through ``mkstemp`` (0600) the mode a plain ``open`` would have."""
    os.chmod(path, 0o666 & ~_umask())


def finite_json(value: Any) -> Any:
    """``value`` with every NaN/inf float replaced by ``None`` (JSON has no NaN)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: finite_json(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_json(v) for v in value]
    return value


@contextlib.contextmanager
def atomic_write(path: str | Path, mode: str = "w", **open_kwargs: Any) -> Iterator[IO]:
    """Write ``path`` through a temp file in its directory, then ``os.replace``: a reader sees the
    old file or the whole new one, and a crash mid-write leaves the old one. The new file gets the
    mode a plain ``open`` would give it."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, mode, **open_kwargs) as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        public_mode(tmp)
        os.replace(tmp, path)
    except BaseException as exc:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError) and exc.filename is None:
            exc.filename = str(path)  # a write to the temp file's descriptor names no file
        raise


def write_json(path: str | Path, value: Any, default: Any = None) -> Path:
    """Strict JSON (NaN/inf -> null), written atomically; ``default`` as :func:`json.dumps`'s (the
    text of a value JSON has no type for)."""
    text = json.dumps(finite_json(value), indent=2, allow_nan=False, default=default) + "\n"
    with atomic_write(path) as f:
        f.write(text)
    return Path(path)


def record_failure(run_dir: str | Path, status: str, message: str, **extra: Any) -> Path:
    """``failed.json``: why a run stopped. ``status``: ``diverged`` (non-finite training; the paper's
    *failed*) or ``errored`` (a bad value or a crash); ``tables.py`` lists both."""
    if status not in ("diverged", "errored"):
        raise ValueError(f"status must be diverged or errored, got {status!r}")
    return write_json(Path(run_dir) / FAILED_NAME, {"status": status, "message": message, **extra})


def retire_failure(run_dir: str | Path) -> Path | None:
    """A new attempt at a run: its ``failed.json`` (why an earlier attempt stopped) becomes
    ``failed.previous.json``, kept, so that the run's records say what its latest attempt did (a
    table reads ``failed.json`` before ``metrics.json``). Returns the kept record's path, or None."""
    path = Path(run_dir) / FAILED_NAME
    if not path.is_file():
        return None
    kept = path.with_name("failed.previous.json")
    os.replace(path, kept)
    return kept


def read_failure(run_dir: str | Path) -> dict | None:
    """The ``failed.json`` of a run (older ones without ``status`` were divergences), or None."""
    path = Path(run_dir) / FAILED_NAME
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return {"status": "errored", "message": f"unreadable {FAILED_NAME}"}
    data.setdefault("status", "diverged")
    return data


class RunLock:
    """Exclusive hold on a run dir while this process trains or resumes it.

    ``with RunLock(run_dir): ...``; a second process gets a :class:`ConfigError` naming the holder.
    """

    def __init__(self, run_dir: str | Path) -> None:
        self.run_dir = Path(run_dir)
        self._file = None

    def acquire(self) -> RunLock:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        path = self.run_dir / LOCK_NAME
        f = open(path, "a+")
        if fcntl is not None:
            try:
                fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                f.seek(0)
                holder = f.read().strip() or "another process"
                f.close()
                raise ConfigError(
                    f"run dir {str(self.run_dir)!r} is in use by {holder}; wait for it to finish or use another run"
                ) from None
        f.seek(0)
        f.truncate()
        f.write(f"pid {os.getpid()} on {socket.gethostname()} since {time.strftime('%Y-%m-%d %H:%M:%S')}\n")
        f.flush()
        self._file = f
        return self

    def release(self) -> None:
        if self._file is not None:
            self._file.close()  # closing drops the flock
            self._file = None

    def __enter__(self) -> RunLock:
        return self.acquire()

    def __exit__(self, *exc: object) -> None:
        self.release()


def is_locked(run_dir: str | Path) -> bool:
    """Whether another process holds ``run_dir``'s lock right now."""
    path = Path(run_dir) / LOCK_NAME
    if fcntl is None or not path.is_file():
        return False
    with open(path) as f:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            return True
        fcntl.flock(f.fileno(), fcntl.LOCK_UN)
    return False


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


@contextlib.contextmanager
def stop_signals(handler, signals: tuple[signal.Signals, ...] = STOP_SIGNALS) -> Iterator[None]:
    """``signals`` (SIGINT and SIGTERM) go to ``handler`` (a function or ``signal.SIG_IGN``)
    inside the block; the previous handlers come back after it. Signals can only be set from the
    main thread: elsewhere this does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = {sig: signal.signal(sig, handler) for sig in signals}
    try:
        yield
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def ignore_stop_signals() -> None:
    """SIGINT and SIGTERM are ignored from now until the process exits (for a command on its way
    out after a stop: a late second Ctrl-C must not turn its exit status into a traceback).
    Outside the main thread it does nothing."""
    if threading.current_thread() is threading.main_thread():
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_IGN)


# After a stop, the processes a command started (a launcher's workers: submitit's local job
# controllers, joblib's loky workers) first get CHILD_GRACE_S to end by themselves (a terminal's
# Ctrl-C reaches its whole process group, and a second signal would cut a job's save short), then
# SIGTERM and CHILD_STOP_S to save and exit, then SIGKILL: the command never outlives them, and
# never waits for ever.
CHILD_GRACE_S = 5.0
CHILD_STOP_S = 120.0
KILLED_GONE_S = 5.0  # a SIGKILLed process is gone within this (bounded: the command exits anyway)
# Children left to their owners' own shutdown, which ends them when the command exits: wandb's
# service (it finishes the run's offline record), torch's compile workers, and the resource
# trackers of joblib (loky) and multiprocessing. Matched in the child's command line.
SERVICE_MARKERS = ("wandb", "compile_worker", "resource_tracker")


def _process_table() -> list[tuple[int, int, str]]:
    """(pid, parent pid, command line) of every live process (zombies left out), from ``ps``."""
    import subprocess

    try:
        ps = subprocess.Popen(["ps", "-A", "-ww", "-o", "pid=,ppid=,stat=,args="], stdout=subprocess.PIPE, text=True)
        out, _ = ps.communicate(timeout=10)
    except (OSError, subprocess.SubprocessError):  # no ps: nothing can be listed (and so nothing waited for)
        return []
    rows = []
    for line in out.splitlines():
        parts = line.split(None, 3)
        if len(parts) >= 3 and parts[0].isdigit() and parts[1].isdigit() and not parts[2].startswith("Z"):
            if int(parts[0]) != ps.pid:  # the listing's own process
                rows.append((int(parts[0]), int(parts[1]), parts[3] if len(parts) == 4 else ""))
    return rows


def _reap_children() -> None:
    """Collect this process's children that have exited, so they stop counting as alive."""
    with contextlib.suppress(ChildProcessError):
        while os.waitpid(-1, os.WNOHANG)[0] > 0:
            pass


def live_children(descendants: bool = False) -> list[int]:
    """The live processes this one started, but for the services of :data:`SERVICE_MARKERS`;
    with ``descendants`` their own children too, recursively."""
    table = _process_table()
    parents, found = {os.getpid()}, []
    while True:
        level = [
            p for p, ppid, args in table
            if ppid in parents and p not in found and not any(m in args for m in SERVICE_MARKERS)
        ]  # fmt: skip
        found += level
        if not descendants or not level:
            return found
        parents = set(level)


def stop_children(grace_s: float = CHILD_GRACE_S, stop_s: float = CHILD_STOP_S) -> list[int]:
    """After this command was stopped: wait up to ``grace_s`` for the processes it started to
    end, send SIGTERM to those still running (they save and exit: submitit's controller passes it
    to its job), wait up to ``stop_s``, then SIGKILL whatever is left with its descendants.
    Returns the pids that needed the SIGTERM."""

    def wait(seconds: float) -> list[int]:
        end = time.monotonic() + seconds
        while True:
            _reap_children()
            alive = live_children()
            if not alive or time.monotonic() >= end:
                return alive
            time.sleep(0.2)

    termed = wait(grace_s)
    for pid in termed:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGTERM)
    if termed and wait(stop_s):
        for pid in live_children(descendants=True):
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        wait(KILLED_GONE_S)
    return termed


def scheduler_signal() -> signal.Signals | None:
    """The signal a job scheduler sends this process before a time limit or a preemption, when the
    scheduler's own handler for it is installed: submitit (``hydra/launcher=submitit_*``, ``slurm``)
    installs one for ``SIGUSR2`` (or ``$SUBMITIT_PREEMPT_SIGNAL``) that checkpoints the job's
    callable and requeues it. None outside such a job."""
    name = "SIG" + os.environ.get("SUBMITIT_PREEMPT_SIGNAL", "USR2")
    sig = getattr(signal, name, None)
    if not isinstance(sig, signal.Signals) or threading.current_thread() is not threading.main_thread():
        return None
    owner = getattr(signal.getsignal(sig), "__self__", None)
    return sig if owner is not None and type(owner).__module__.startswith("submitit.") else None


def requeue_with_scheduler(signal_name: str | None, message: str = "") -> None:
    """After a loop stopped on the scheduler's signal (:func:`scheduler_signal`) and saved, print
    ``message`` and hand the signal to the scheduler's handler: it requeues the job (which resumes
    from the saved state) and exits the process. Returns (does nothing) for any other signal or
    outside a scheduler job."""
    sig = scheduler_signal()
    if sig is not None and signal_name == sig.name:
        if message:
            print(message, file=sys.stderr)
        signal.getsignal(sig)(sig, None)  # submitit: requeue, then SystemExit


class StopRequest:
    """While active (``with StopRequest() as stop``), SIGINT and SIGTERM (and, in a scheduler's job,
    its preemption signal: :func:`scheduler_signal`) only set ``stop.signal`` (``"SIGINT"``,
    ``"SIGTERM"``, ``"SIGUSR2"``), so a loop can finish its step and save before it stops; a second
    signal raises ``KeyboardInterrupt`` at once. Outside the main thread it does nothing."""

    def __init__(self) -> None:
        self.signal: str | None = None
        self._handlers = contextlib.ExitStack()

    def _handle(self, signum: int, frame: object) -> None:
        if self.signal is not None:
            raise KeyboardInterrupt
        self.signal = signal.Signals(signum).name

    def __enter__(self) -> StopRequest:
        preempt = scheduler_signal()
        self._handlers.enter_context(stop_signals(self._handle, STOP_SIGNALS + ((preempt,) if preempt else ())))
        return self

    def __exit__(self, *exc: object) -> None:
        self._handlers.close()


def run_stoppable(cmd: list[str], cwd: str | Path | None = None) -> tuple[int, str | None]:
    """Run ``cmd`` as a child in its own process group and wait for it; a SIGINT/SIGTERM to this
    process is passed on to the whole group (the child's own workers too), and the child is
    waited for, so it can save what it has and no process outlives the command. Returns the
    child's exit code and the name of the signal that stopped it (None: it ran to its end)."""
    import subprocess

    proc = subprocess.Popen(cmd, cwd=cwd, start_new_session=True)
    sent: set[str] = set()
    with StopRequest() as stop:
        while True:
            try:
                code = proc.wait(timeout=0.2)
                break
            except subprocess.TimeoutExpired:
                pass
            except KeyboardInterrupt:  # a second signal: stop the group at once
                stop.signal = stop.signal or "SIGINT"
                sent.add("SIGKILL")
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
            if stop.signal and stop.signal not in sent:
                sent.add(stop.signal)
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, getattr(signal, stop.signal))
    return code, stop.signal
