"""Position sources for the external-position (mocap) stream sent to the vehicle.

``read() -> (pos_m (x, y, z), quat (w, x, y, z) | None, t_s) | None`` with ``t_s`` on the
source's ``clock`` (the arrival of the frame; a new frame has a new ``t_s``):

* ``none``: no external position; the onboard estimate is used as is.
* ``motioncapture``: the ``motioncapture`` library (Vicon, OptiTrack, Qualisys, ...; optional,
  ``pip install motioncapture``), rigid body ``body`` from ``system``/``host``.
* ``simulated``: the simulated Crazyflie's true position with a latency, Gaussian noise
  (``noise_std_m``) and random dropouts
  (``dropout_after_s`` cuts the stream for good: fault injection).
"""

from __future__ import annotations

import collections
import json
import random
import subprocess
import sys
import threading
import weakref

from datt.deploy.clock import WALL


class MocapSource:
    """``subscribe(callback)``: ``callback(sample)`` is called with every new frame as it arrives
    (on the source's thread), so a frame can be forwarded at once instead of at the next tick."""

    name = "none"
    # deploy.mocap.lead_s and lead_window_s, set by with_lead (the deploy task always does); a source
    # built without them is not led
    lead_s: float | None = 0.0
    lead_window_s: float | None = None
    clock = WALL  # the clock its frames are stamped on (datt.deploy.clock); the simulated one's is the vehicle's

    def __init__(self) -> None:
        self._subscribers: list = []

    def with_lead(self, lead_s: float | None, window_s: float) -> MocapSource:
        """The lead (:class:`FrameLead`) the flight applies to the positions it forwards."""
        self.lead_s, self.lead_window_s = lead_s, float(window_s)
        return self

    def subscribe(self, callback) -> None:
        self._subscribers.append(callback)

    def _publish(self, sample) -> None:
        self._latest = sample
        for callback in list(self._subscribers):
            callback(sample)

    def start(self) -> None:
        pass

    def read(self):
        return None

    def stop(self) -> None:
        pass


class NoMocap(MocapSource):
    pass


class FrameLead:
    """Mocap positions moved ``lead_s`` ahead along the velocity of the frames of the last
    ``window_s`` (world frame, m): the vehicle's Kalman filter takes each external position as a
    measurement of *now*, while it describes the vehicle one mocap latency plus one radio leg ago.
    The velocity's baseline (``window_s``) keeps the position noise it amplifies small: with 1 mm
    of noise a 40 ms baseline adds ~1 mm of noise per 30 ms of lead. ``lead_s`` 0 returns each
    position as it is."""

    def __init__(self, lead_s: float, window_s: float) -> None:
        self.lead_s, self.window_s = float(lead_s), float(window_s)
        self._frames: collections.deque = collections.deque()

    def __call__(self, pos, t_s: float) -> tuple:
        """``pos`` (x, y, z) of a frame that arrived at ``t_s``, led; frames arrive in time order."""
        frames = self._frames
        frames.append((t_s, pos))
        while len(frames) > 2 and t_s - frames[1][0] >= self.window_s:
            frames.popleft()
        t0, p0 = frames[0]
        if self.lead_s == 0.0 or t_s <= t0:
            return tuple(pos)
        scale = self.lead_s / (t_s - t0)
        return tuple(p + (p - q) * scale for p, q in zip(pos, p0))


class SimulatedMocap(MocapSource):
    name = "simulated"

    def __init__(
        self,
        server,
        latency_s: float = 0.0,
        dropout_prob: float = 0.0,
        dropout_after_s: float | None = None,
        rate_hz: float = 100.0,
        seed: int = 0,
        noise_std_m: float = 0.0,
    ) -> None:
        super().__init__()
        self.server, self.latency_s, self.dropout_prob = server, float(latency_s), float(dropout_prob)
        self.dropout_after_s = dropout_after_s
        self.period_s = 1.0 / float(rate_hz)
        self.rng = random.Random(seed)
        self.noise_std_m = float(noise_std_m)
        self._buffer: collections.deque = collections.deque()
        self._latest = None
        self.clock = getattr(server, "clock", WALL)
        self._running = threading.Event()
        self._stopping = self.clock.event()

    def start(self) -> None:
        self._t0 = self.clock.monotonic()
        self._running.set()
        self.clock.start_thread(self._loop, "sim-mocap")

    def _loop(self) -> None:
        while self._running.is_set():
            now = self.clock.monotonic()
            cut = self.dropout_after_s is not None and now - self._t0 > self.dropout_after_s
            if not cut and self.rng.random() >= self.dropout_prob:
                true = self.server.true_state()
                pos = tuple(p + self.rng.gauss(0.0, self.noise_std_m) if self.noise_std_m else p for p in true["pos_m"])
                self._buffer.append((pos, tuple(true["quat"]), now))
            while self._buffer and now - self._buffer[0][-1] >= self.latency_s:
                self._publish(self._buffer.popleft())
            self.clock.wait(self._stopping, self.period_s)

    def read(self):
        return self._latest

    def stop(self) -> None:
        self._running.clear()
        self._stopping.set()


class MotionCaptureMocap(MocapSource):
    """Frames of rigid body ``body`` from the ``motioncapture`` library, read from a client process
    of its own (:mod:`datt.deploy.mocap_stream`: a vendor SDK that blocks cannot hold the flying
    process). The constructor waits at most ``connect_timeout_s`` for the first frame that holds
    ``body``; without one the client is killed and the flight refused in one line."""

    name = "motioncapture"

    def __init__(
        self,
        system: str,
        host: str,
        body: str,
        options: dict[str, str] | None = None,
        connect_timeout_s: float = 5.0,
    ) -> None:
        """``system`` and ``host`` (and ``options``: the library's other settings, e.g. a Qualisys
        ``port``, all strings) go to ``motioncapture.connect``; ``body`` is the rigid body flown."""
        from datt.errors import ConfigError

        try:
            import motioncapture  # noqa: F401  (checked here: the client process imports it again)
        except ImportError:
            raise ConfigError("deploy.mocap: the motioncapture source needs `pip install motioncapture`") from None
        super().__init__()
        self.body = body
        self._latest = None
        self._running = threading.Event()
        self._bodies_seen: list[str] | None = None
        self._error: str | None = None
        self._first = threading.Event()
        settings = json.dumps({"hostname": host, **{k: str(v) for k, v in (options or {}).items()}})
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "datt.deploy.mocap_stream", system, settings, body],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            stdin=subprocess.DEVNULL,
            text=True,
            preexec_fn=_die_with_parent if sys.platform.startswith("linux") else None,
        )
        weakref.finalize(self, _kill, self._proc)
        threading.Thread(target=self._read, daemon=True).start()
        try:
            arrived = self._first.wait(connect_timeout_s)  # interruptible: a signal ends the wait
        except BaseException:
            _kill(self._proc)
            raise
        if not arrived:
            _kill(self._proc)
            seen = self._bodies_seen
            if self._error is not None:
                why = f"the motioncapture library refused: {self._error}"
            elif seen is None:
                limit = f"deploy.mocap.connect_timeout_s ({connect_timeout_s:g} s)"
                why = f"no frame from {system} at {host} within {limit}"
            else:
                why = (
                    f"frames from {system} at {host} hold no rigid body {body!r} (bodies seen: "
                    f"{', '.join(seen) or 'none'}) within deploy.mocap.connect_timeout_s ({connect_timeout_s:g} s)"
                )
            raise ConfigError(f"deploy.mocap: {why}; check the host, that the system streams, and deploy.mocap.body")

    def _read(self) -> None:
        """The client's lines: frames are published once ``start`` ran (the first one always
        marks the source alive)."""
        for line in self._proc.stdout:
            try:
                item = json.loads(line)
            except ValueError:
                continue
            if "error" in item:
                self._error = str(item["error"])
            elif "bodies" in item:
                self._bodies_seen = [str(b) for b in item["bodies"]]
            else:
                p, q = item["p"], item.get("q")
                pos = (float(p[0]), float(p[1]), float(p[2]))
                sample = (pos, None if q is None else tuple(q), self.clock.monotonic())
                self._first.set()
                if self._running.is_set():
                    self._publish(sample)

    def start(self) -> None:
        self._running.set()

    def read(self):
        return self._latest

    def stop(self) -> None:
        self._running.clear()
        _kill(self._proc)


def _die_with_parent() -> None:
    """In the client process (Linux): the kernel kills it when the flying process dies, however."""
    import ctypes
    import signal

    PR_SET_PDEATHSIG = 1
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)


def _kill(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.kill()
        proc.wait()
