"""Position sources for the external-position (mocap) stream sent to the vehicle.

``read() -> (pos_m (x, y, z), quat (w, x, y, z) | None, t_s) | None`` with ``t_s`` on
``time.monotonic()`` (the arrival of the frame; a new frame has a new ``t_s``):

* ``none``: no external position; the onboard estimate is used as is.
* ``motioncapture``: the ``motioncapture`` library (Vicon, OptiTrack, Qualisys, ...; optional,
  ``pip install motioncapture``), rigid body ``body`` from ``system``/``host``.
* ``simulated``: the simulated Crazyflie's true position with a latency, Gaussian noise
  (``noise_std_m``) and random dropouts
  (``dropout_after_s`` cuts the stream for good: fault injection).
"""

from __future__ import annotations

import collections
import random
import threading
import time


class MocapSource:
    """``subscribe(callback)``: ``callback(sample)`` is called with every new frame as it arrives
    (on the source's thread), so a frame can be forwarded at once instead of at the next tick."""

    name = "none"

    def __init__(self) -> None:
        self._subscribers: list = []

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
        self._running = threading.Event()

    def start(self) -> None:
        self._t0 = time.monotonic()
        self._running.set()
        threading.Thread(target=self._loop, daemon=True).start()

    def _loop(self) -> None:
        while self._running.is_set():
            now = time.monotonic()
            cut = self.dropout_after_s is not None and now - self._t0 > self.dropout_after_s
            if not cut and self.rng.random() >= self.dropout_prob:
                true = self.server.true_state()
                pos = tuple(p + self.rng.gauss(0.0, self.noise_std_m) if self.noise_std_m else p for p in true["pos_m"])
                self._buffer.append((pos, tuple(true["quat"]), now))
            while self._buffer and now - self._buffer[0][-1] >= self.latency_s:
                self._publish(self._buffer.popleft())
            time.sleep(self.period_s)

    def read(self):
        return self._latest

    def stop(self) -> None:
        self._running.clear()


class MotionCaptureMocap(MocapSource):
    name = "motioncapture"

    def __init__(self, system: str, host: str, body: str, options: dict[str, str] | None = None) -> None:
        """``system`` and ``host`` (and ``options``: the library's other settings, e.g. a Qualisys
        ``port``, all strings) go to ``motioncapture.connect``; ``body`` is the rigid body flown."""
        try:
            import motioncapture
        except ImportError:
            from datt.errors import ConfigError

            raise ConfigError("deploy.mocap: the motioncapture source needs `pip install motioncapture`") from None
        super().__init__()
        self.mc = motioncapture.connect(system, {"hostname": host, **{k: str(v) for k, v in (options or {}).items()}})
        self.body = body
        self._latest = None
        self._running = threading.Event()

    def start(self) -> None:
        self._running.set()
        threading.Thread(target=self._loop, daemon=True).start()

    def _loop(self) -> None:
        while self._running.is_set():
            self.mc.waitForNextFrame()
            for name, obj in self.mc.rigidBodies.items():
                if name == self.body:
                    p, q = obj.position, getattr(obj, "rotation", None)
                    quat = None if q is None else (float(q.w), float(q.x), float(q.y), float(q.z))
                    self._publish(((float(p[0]), float(p[1]), float(p[2])), quat, time.monotonic()))

    def read(self):
        return self._latest

    def stop(self) -> None:
        self._running.clear()
