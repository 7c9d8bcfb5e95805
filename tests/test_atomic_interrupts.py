"""An atomic write stopped part way, by each way a run stops: an error, Ctrl-C (KeyboardInterrupt),
SIGINT and SIGTERM delivered to a process in the middle of writing (with SIGTERM handled as the
entry points handle it: ``datt.cli.sigterm_as_interrupt``). Whatever stops it, the previous file is
intact and no temporary file is left beside it; for every writer the runs use (text through
``write_json``, bytes through ``save_checkpoint``)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from datt.runs import atomic_write, write_json

WRITERS = ("text", "bytes")

# A child process: writes the old file, then starts the new one and blocks half way through it
# (printing "writing" once the temporary file holds part of the new text) until a signal ends it.
CHILD = textwrap.dedent(
    """
    import signal, sys, threading
    from pathlib import Path
    from datt.cli import sigterm_as_interrupt
    from datt.runs import atomic_write, write_json
    from datt.checkpoint import save_checkpoint

    path, writer = Path(sys.argv[1]), sys.argv[2]
    # a process started by a pytest-xdist worker inherits SIGINT ignored; a user's command has Ctrl-C
    signal.signal(signal.SIGINT, signal.default_int_handler)
    if writer == "text":
        write_json(path, {"old": True})
    else:
        save_checkpoint(path, {"old": True})
    with sigterm_as_interrupt():
        try:
            with atomic_write(path, "w" if writer == "text" else "wb") as f:
                f.write("{\\"new\\": " if writer == "text" else b"PK-partial")
                f.flush()
                print("writing", flush=True)
                threading.Event().wait()  # until a signal interrupts the write
        except KeyboardInterrupt:
            sys.exit(130)
    """
)


def _old_is_intact(path: Path, writer: str) -> None:
    if writer == "text":
        assert json.loads(path.read_text()) == {"old": True}
    else:
        from datt.checkpoint import load_checkpoint

        assert load_checkpoint(path)["old"] is True


def _no_temporary_files(directory: Path, path: Path) -> None:
    assert sorted(p.name for p in directory.iterdir()) == [path.name]


@pytest.mark.parametrize("writer", WRITERS)
@pytest.mark.parametrize("stop", [RuntimeError, KeyboardInterrupt], ids=["error", "KeyboardInterrupt"])
def test_a_write_stopped_in_process_keeps_the_old_file_and_leaves_nothing_else(tmp_path, writer, stop):
    from datt.checkpoint import save_checkpoint

    path = tmp_path / ("metrics.json" if writer == "text" else "last.pt")
    if writer == "text":
        write_json(path, {"old": True})
    else:
        save_checkpoint(path, {"old": True})
    with pytest.raises(stop):
        with atomic_write(path, "w" if writer == "text" else "wb") as f:
            f.write('{"new": ' if writer == "text" else b"PK-partial")
            raise stop("stopped half way")
    _old_is_intact(path, writer)
    _no_temporary_files(tmp_path, path)


@pytest.mark.parametrize("writer", WRITERS)
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_write_stopped_by_a_signal_keeps_the_old_file_and_leaves_nothing_else(tmp_path, writer, sig):
    path = tmp_path / "out" / ("metrics.json" if writer == "text" else "last.pt")
    path.parent.mkdir()
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"), *sys.path]))
    command = [sys.executable, "-c", CHILD, str(path), writer]
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "writing", proc.stderr.read()
        temporaries = [p for p in path.parent.iterdir() if p.name != path.name]
        assert len(temporaries) == 1  # the case interrupts a write in progress
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)  # a hang guard, not a timing
    finally:
        proc.kill()
    assert proc.returncode == 130, err
    _old_is_intact(path, writer)
    _no_temporary_files(path.parent, path)
