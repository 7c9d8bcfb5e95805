"""Progress of a long loop as plain log lines, the same on a terminal, under nohup and in a
Slurm ``.out`` file.

Every entry point says what it does through Python's ``logging`` (logger ``datt.*``); Hydra's
job logging (``conf/hydra/default.yaml``) sends each record to the console, unwrapped, and to
``<run dir>/<entry point>.log``. A loop that runs for minutes (training, an evaluation over seeds
and conditions, the RMA fit, ``tables.py run=true``) reports through :class:`ProgressReport`:
one line at its first step, then at most one per ``every_s`` seconds, and its last step, e.g.::

    train: 2,654,208 / 10,000,000 frames (26.5 %), 21,139 frames/s, ETA 5 min 48 s, err 0.086 m

The clock is a parameter, so a test decides when a line is due without waiting.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

log = logging.getLogger("datt.progress")


def duration(seconds: float) -> str:
    """``seconds`` as ``1 h 02 min``, ``5 min 48 s`` or ``12 s``."""
    s = max(0, round(seconds))
    if s >= 3600:
        return f"{s // 3600} h {s % 3600 // 60:02d} min"
    if s >= 60:
        return f"{s // 60} min {s % 60:02d} s"
    return f"{s} s"


class ProgressReport:
    """Lines of ``what``'s progress towards ``total`` ``unit``.

    :meth:`update` is called at every step with the amount done so far (counted from zero for the
    whole job, so a resumed run reports its true position) and optional named fields already
    formatted (``err="0.086 m"``). A line is written at the first call, whenever ``every_s``
    seconds of ``clock`` (default :func:`time.monotonic`) have passed since the last line, and
    when ``done`` reaches ``total``.
    The rate and ETA count only what this process did (a resume's earlier frames are not its
    speed). ``enabled=False`` writes nothing."""

    def __init__(
        self,
        what: str,
        total: float,
        unit: str,
        every_s: float = 30.0,
        clock: Callable[[], float] | None = None,
        enabled: bool = True,
        logger: logging.Logger = log,
    ) -> None:
        self.what, self.total, self.unit, self.every_s = what, total, unit, every_s
        self.clock = clock or time.monotonic
        self.enabled, self.logger = enabled, logger
        self._start_s = self.clock()
        self._done_at_start: float | None = None
        self._last_line_s: float | None = None
        self.lines = 0

    def update(self, done: float, **fields: str) -> None:
        now = self.clock()
        if self._done_at_start is None:
            self._done_at_start, self._start_s = done, now
            return self._write(done, now, fields)  # the first step: the run is alive
        due = self._last_line_s is None or now - self._last_line_s >= self.every_s
        if due or done >= self.total:
            self._write(done, now, fields)

    def line(self, done: float, now: float, fields: dict[str, str]) -> str:
        """The report at ``done`` and clock time ``now``."""
        parts = [f"{self.what}: {done:,.0f} / {self.total:,.0f} {self.unit}"]
        if self.total > 0:
            parts[0] += f" ({100.0 * done / self.total:.1f} %)"
        elapsed = now - self._start_s
        made = done - (self._done_at_start or 0.0)
        if elapsed > 0 and made > 0:
            rate = made / elapsed
            parts.append(f"{rate:,.0f} {self.unit}/s" if rate >= 10 else f"{rate:.2f} {self.unit}/s")
            if done < self.total:
                parts.append(f"ETA {duration((self.total - done) / rate)}")
        parts.extend(f"{name} {value}" for name, value in fields.items())
        return ", ".join(parts)

    def _write(self, done: float, now: float, fields: dict[str, str]) -> None:
        self._last_line_s = now
        if self.enabled:
            self.logger.info(self.line(done, now, fields))
            self.lines += 1
