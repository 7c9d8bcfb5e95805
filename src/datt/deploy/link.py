"""The radio link to a Crazyflie through cflib (the only module that imports cflib).

``CrazyflieLink(uri)``: connect (with a timeout), put the firmware in rate mode
(``flightmode.stabModeRoll/Pitch = 0``), log the onboard estimate (position, velocity,
quaternion, battery) in two blocks within the firmware's 26-byte block limit at ``log_period_ms``
(10 ms = 100 Hz by default), and send external positions, rate setpoints, arm/disarm and the
emergency stop. The latest state is kept with its arrival time so the safety layer can tell a
stale estimate; ``link_lost`` is set by cflib's connection-lost callback.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass


class LinkError(RuntimeError):
    pass


def _cflib():
    try:
        import cflib.crtp
        from cflib.crazyflie import Crazyflie
        from cflib.crazyflie.log import LogConfig
    except ImportError:
        raise LinkError('cflib is not installed: pip install -e ".[deploy]"') from None
    return cflib.crtp, Crazyflie, LogConfig


@dataclass
class StateSample:
    """Onboard estimate (world frame, SI): pos_m, vel_mps (3), quat (w, x, y, z), battery."""

    t_s: float
    pos_m: tuple
    vel_mps: tuple
    quat: tuple
    vbat_v: float


BLOCK_A = ["stateEstimate.x", "stateEstimate.y", "stateEstimate.z", "stateEstimate.vx", "stateEstimate.vy", "stateEstimate.vz"]
BLOCK_B = ["stateEstimate.qx", "stateEstimate.qy", "stateEstimate.qz", "stateEstimate.qw", "pm.vbat"]


class CrazyflieLink:
    def __init__(self, uri: str, log_period_ms: int = 10, connect_timeout_s: float = 10.0) -> None:
        self.uri = uri
        self.log_period_ms = int(log_period_ms)
        self.connect_timeout_s = float(connect_timeout_s)
        self.link_lost = threading.Event()
        self.lost_reason = ""
        self._a: dict | None = None
        self._b: dict | None = None
        self._t_a = self._t_b = -math.inf
        self._lock = threading.Lock()
        self.cf = None

    # -- connection ------------------------------------------------------------------------
    def connect(self) -> "CrazyflieLink":
        crtp, Crazyflie, LogConfig = _cflib()
        import logging

        logging.getLogger("cflib").setLevel(logging.WARNING)  # its INFO chatter drowns the flight log
        crtp.init_drivers()
        self.cf = Crazyflie(rw_cache=None)
        done, error = threading.Event(), []
        self.cf.connected.add_callback(lambda uri: done.set())
        self.cf.connection_failed.add_callback(lambda uri, msg: (error.append(msg), done.set()))
        self.cf.connection_lost.add_callback(self._on_lost)
        self.cf.open_link(self.uri)
        if not done.wait(self.connect_timeout_s) or error:
            self.close()
            lines = [ln.strip() for ln in str(error[0]).splitlines() if ln.strip()][:2] if error else []
            why = "; ".join(lines) if lines else f"no answer within {self.connect_timeout_s:.0f} s"
            raise LinkError(f"connect: {self.uri}: {why}")
        self.cf.param.set_value("flightmode.stabModeRoll", 0)
        self.cf.param.set_value("flightmode.stabModePitch", 0)
        for name, variables, store in (("state_a", BLOCK_A, "_a"), ("state_b", BLOCK_B, "_b")):
            lc = LogConfig(name=name, period_in_ms=self.log_period_ms)
            for v in variables:
                lc.add_variable(v, "float")
            self.cf.log.add_config(lc)
            lc.data_received_cb.add_callback(self._make_cb(store))
            lc.start()
        return self

    def _make_cb(self, store: str):
        def cb(timestamp, data, logconf):
            with self._lock:
                setattr(self, store, data)
                setattr(self, "_t" + store, time.monotonic())

        return cb

    def _on_lost(self, uri, msg) -> None:
        self.lost_reason = str(msg)
        self.link_lost.set()

    def close(self) -> None:
        if self.cf is not None:
            try:
                self.cf.close_link()
            except Exception:  # closing a dead link must not mask the flight's outcome
                pass

    # -- state -----------------------------------------------------------------------------
    def state(self) -> StateSample | None:
        """Latest estimate (None before both log blocks arrived); ``t_s`` = older block's arrival."""
        with self._lock:
            a, b = self._a, self._b
            t = min(self._t_a, self._t_b)
        if a is None or b is None:
            return None
        return StateSample(
            t_s=t,
            pos_m=(a["stateEstimate.x"], a["stateEstimate.y"], a["stateEstimate.z"]),
            vel_mps=(a["stateEstimate.vx"], a["stateEstimate.vy"], a["stateEstimate.vz"]),
            quat=(b["stateEstimate.qw"], b["stateEstimate.qx"], b["stateEstimate.qy"], b["stateEstimate.qz"]),
            vbat_v=b["pm.vbat"],
        )

    # -- commands --------------------------------------------------------------------------
    def send_rates(self, roll_degps: float, pitch_degps: float, yaw_arg_degps: float, thrust_cmd: int) -> None:
        self.cf.commander.send_setpoint(roll_degps, pitch_degps, yaw_arg_degps, int(thrust_cmd))

    def send_extpos(self, pos_m) -> None:
        self.cf.extpos.send_extpos(float(pos_m[0]), float(pos_m[1]), float(pos_m[2]))

    def arm(self, on: bool = True) -> None:
        self.cf.supervisor.send_arming_request(bool(on))

    def emergency_stop(self) -> None:
        self.cf.supervisor.send_emergency_stop()
