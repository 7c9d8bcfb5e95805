"""The time a flight runs on: the wall clock, or one lockstep clock shared by the host and the
simulated Crazyflie.

Every wait of a flight goes through a clock: ``monotonic()`` (s), ``sleep(s)``, ``wait(event,
timeout_s)`` and ``event()``; the threads that take part in a flight start through
``start_thread``, and whatever one side hands the other across a thread (a datagram, a queued
send) is bracketed by ``begin()`` when it leaves and ``end()`` when it has been taken up.

* :data:`WALL` (:class:`WallClock`): real time. A real Crazyflie flies on it, and so does the
  simulated one by default (``deploy.server.clock=real_time``): the host's compute time and the
  machine's stalls then land in the flight as they would in a real one.
* :class:`LockstepClock` (``deploy.server.clock=lockstep``): virtual time that moves only when every
  thread taking part waits on the clock and nothing handed between threads is still on its way;
  it then jumps to the earliest deadline. The simulated vehicle's physics, radio and the host's
  control loop meet at the same virtual instants however busy the machine is, so a flight's
  outcome does not depend on the machine's load (the tests fly on it). What it leaves out is
  what real time adds: the host's compute takes no virtual time, and no tick is late.

A lockstep clock never waits forever: when a thread keeps running (computing, or blocked outside
the clock) and time has not moved by itself for ``stall_s`` of real time, virtual time goes on at
real pace until it can move by itself again, so a wedged send still meets its timeout.
"""

from __future__ import annotations

import math
import threading
import time

# how often a waiting thread looks again at threads that ended or a stall (real seconds)
_POLL_S = 0.05


class WallClock:
    """Real time (``time.monotonic`` and ``time.sleep``)."""

    lockstep = False

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))

    def event(self) -> threading.Event:
        return threading.Event()

    def wait(self, event: threading.Event, timeout_s: float | None) -> bool:
        return event.wait(timeout_s)

    def start_thread(self, target, name: str) -> threading.Thread:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        return thread

    def take_part(self) -> None:
        """The calling thread takes part in the flight from now (real time needs no account of it)."""

    def leave(self) -> None:
        """The calling thread no longer takes part."""

    def begin(self) -> None:
        """Something left for another thread (real time needs no account of it)."""

    def end(self) -> None:
        """Something handed between threads was taken up."""


WALL = WallClock()


class _ClockEvent(threading.Event):
    """An event whose ``set`` tells the lockstep clock at once (a waiter on it runs again)."""

    def __init__(self, clock: LockstepClock) -> None:
        super().__init__()
        self._clock = clock

    def set(self) -> None:
        super().set()
        self._clock._changed()


class LockstepClock:
    """Virtual time (s, from ``start_s``) shared by the threads of one flight; see the module."""

    lockstep = True

    def __init__(self, start_s: float = 1000.0, stall_s: float = 5.0) -> None:
        self._cond = threading.Condition()
        self._now_s = float(start_s)
        self.stall_s = float(stall_s)
        # each taking part: None while it runs, (deadline_s, event or None) while it waits
        self._waits: dict[threading.Thread, tuple[float, threading.Event | None] | None] = {}
        self._in_flight = 0  # handed between threads and not yet taken up
        self._moved_real_s = time.monotonic()  # when time last moved by itself (the stall guard's)
        self._stall_real_s = -math.inf  # when the stall guard last moved time on
        self.stalls = 0  # how often it did

    def monotonic(self) -> float:
        return self._now_s

    def sleep(self, seconds: float) -> None:
        self._wait(None, self._now_s + max(0.0, seconds))

    def event(self) -> threading.Event:
        return _ClockEvent(self)

    def wait(self, event: threading.Event, timeout_s: float | None) -> bool:
        deadline = math.inf if timeout_s is None else self._now_s + max(0.0, timeout_s)
        return self._wait(event, deadline)

    def start_thread(self, target, name: str) -> threading.Thread:
        """A daemon thread that takes part from its start (time waits for its first wait)."""

        def run() -> None:
            try:
                target()
            finally:
                self.leave()

        thread = threading.Thread(target=run, name=name, daemon=True)
        with self._cond:  # registered before it can wait: started, so is_alive() holds
            thread.start()
            self._waits[thread] = None
        return thread

    def take_part(self) -> None:
        """The calling thread takes part from now: time waits while it runs (the thread that
        starts the vehicle and then flies it: the vehicle does not run ahead while it prepares)."""
        with self._cond:
            self._waits.setdefault(threading.current_thread(), None)

    def leave(self) -> None:
        """The calling thread no longer takes part (time no longer waits for it)."""
        with self._cond:
            self._waits.pop(threading.current_thread(), None)
            self._cond.notify_all()

    def begin(self) -> None:
        with self._cond:
            self._in_flight += 1

    def end(self) -> None:
        with self._cond:
            self._in_flight -= 1
            self._cond.notify_all()

    # -- the scheduler ---------------------------------------------------------------------
    def _changed(self) -> None:
        """Something happened: wake the waiters to look again."""
        with self._cond:
            self._cond.notify_all()

    def _wait(self, event: threading.Event | None, deadline_s: float) -> bool:
        me = threading.current_thread()
        with self._cond:
            self._waits[me] = (deadline_s, event)
            try:
                while not (event is not None and event.is_set()) and self._now_s < deadline_s:
                    if not self._advance():
                        self._cond.wait(_POLL_S)
            finally:
                self._waits[me] = None
        return True if event is None else event.is_set()

    def _advance(self) -> bool:
        """Move time to the earliest deadline when nothing else can happen first (held lock);
        True when it moved."""
        busy = self._in_flight > 0
        deadlines = []
        for thread, waiting in list(self._waits.items()):
            if not thread.is_alive():
                del self._waits[thread]
            elif waiting is None:
                busy = True  # running
            elif (waiting[1] is not None and waiting[1].is_set()) or waiting[0] <= self._now_s:
                busy = True  # woken, not yet running
            else:
                deadlines.append(waiting[0])
        target = min(deadlines, default=math.inf)
        if not math.isfinite(target):
            return False
        real_s = time.monotonic()
        if busy:  # the stall guard: time stuck that long in real time goes on at real pace
            if real_s - self._moved_real_s < self.stall_s or real_s - self._stall_real_s < _POLL_S:
                return False
            self._stall_real_s = real_s
            self.stalls += 1
            self._now_s = max(self._now_s, min(target, self._now_s + _POLL_S))
            self._cond.notify_all()
            return False  # the waiter sleeps a poll: real pace
        self._moved_real_s = real_s
        self._now_s = max(self._now_s, target)
        self._cond.notify_all()
        return True
