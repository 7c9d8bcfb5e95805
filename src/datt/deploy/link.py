"""The radio link to a Crazyflie through cflib (the only module that imports cflib).

``CrazyflieLink(uri)``: connect (with a timeout), put the firmware in rate mode
(``flightmode.stabModeRoll/Pitch = 0``) and select the Kalman estimator (``stabilizer.estimator =
2``: the default complementary estimator drops external positions, so x and y would stay 0), each
read back from the vehicle; without an external position stream (``external_position=False``) a
positioning deck must be present. Then log the onboard estimate (position, velocity,
quaternion, battery) in two blocks within the firmware's 26-byte block limit at ``log_period_ms``
(10 ms = 100 Hz by default), and send external positions, rate setpoints, arm/disarm and the
emergency stop. The latest state is kept with its arrival time so the safety layer can tell a
stale estimate; ``link_lost`` is set by cflib's connection-lost callback.

Every call that sends through cflib (setpoints, external position, arming, emergency stop,
closing) runs on one daemon thread and is waited for at most ``io_timeout_s``. cflib can wedge
when the link dies mid-send: its receive thread sets ``Crazyflie.link = None`` between
``send_packet``'s check and its use, the send raises with ``_send_lock`` held, and every later
send (including the emergency stop) blocks forever. A call that does not return in time, or
raises, marks the link lost (the safety layer then KILLs) and later calls return at once; the
vehicle's own setpoint watchdog stops the motors when setpoints stop arriving.

Every wait goes through the flight's clock (:mod:`datt.deploy.clock`). On the simulated
Crazyflie's lockstep clock the link opens through :func:`_lockstep_udp_driver`, cflib's UDP driver
accounting each datagram to the clock, and reads and writes parameters with packets of its own
(cflib's parameter thread sends from a queue the clock cannot see).
"""

from __future__ import annotations

import collections
import math
import queue
import struct
import threading
from dataclasses import dataclass

from datt.deploy import firmware
from datt.deploy.clock import WALL
from datt.deploy.firmware import fact
from datt.errors import LinkError

PARAM_READ_CHANNEL = 1  # param port: read replies are <id:2><status:1><value>; write echoes come on channel 2
PARAM_WRITE_CHANNEL = 2  # param port: a write is <id:2><value>
# Off-board flight settings, in the order they are set (and restored in reverse at close): only the
# PID and INDI controllers fly roll/pitch-rate setpoints; the position/altitude holds of the
# legacy commander turn thrust and attitude setpoints into velocity commands; rate mode makes
# roll/pitch rates; the Kalman filter is the estimator that takes external positions.
OFFBOARD_SETTINGS = (
    (str(fact("param_controller")), firmware.CONTROLLER_PID),
    (str(fact("param_althold")), 0),
    (str(fact("param_poshold")), 0),
    (str(fact("param_posset")), 0),
    (str(fact("param_stab_mode_roll")), 0),
    (str(fact("param_stab_mode_pitch")), 0),
    (str(fact("param_estimator")), firmware.ESTIMATOR_KALMAN),
)
# a write takes effect in the firmware's stabilizer loop (controller and estimator switch there): read
# back only after this long (at least one cycle of the simulated vehicle's 50 Hz loop, 500 of a real one)
PARAM_SETTLE_S = 0.05


# how many times the supervisor's state is asked for (io_timeout_s apart) before the vehicle is
# taken not to answer it
SUPERVISOR_REQUESTS = 4

# Decks that give the Kalman filter a position (or flow + height) of its own (firmware deck drivers'
# requiredEstimator = kalman); without one and without mocap, x and y are unobserved.
POSITIONING_DECKS = ("deck.bcLighthouse4", "deck.bcDWM1000", "deck.bcLoco", "deck.bcFlow", "deck.bcFlow2")


def _cflib():
    try:
        import cflib.crtp
        from cflib.crazyflie import Crazyflie
        from cflib.crazyflie.log import LogConfig
    except ImportError:
        raise LinkError('cflib is not installed: pip install -e ".[deploy]"') from None
    return cflib.crtp, Crazyflie, LogConfig


def _lockstep_udp_driver(clock, uri: str):
    """cflib's UDP driver for ``uri`` only, accounting each datagram to the lockstep ``clock``: one
    sent is on its way (``begin``) until the simulated vehicle takes it up; one received is until
    cflib's packet thread comes back for the next (it has then handed this one to every callback)."""
    from cflib.crtp.exceptions import WrongUriType
    from cflib.crtp.udpdriver import UdpDriver

    class LockstepUdpDriver(UdpDriver):
        def connect(self, link_uri, *callbacks):
            if link_uri != uri:
                raise WrongUriType(f"{link_uri}: not the lockstep vehicle's")
            self._handed = False
            super().connect(link_uri, *callbacks)

        def send_packet(self, pk):
            if self.socket is None:
                return
            clock.begin()
            super().send_packet(pk)

        def receive_packet(self, wait=0):
            if self._handed:
                self._handed = False
                clock.end()
            pk = super().receive_packet(wait)
            self._handed = pk is not None
            return pk

    return LockstepUdpDriver


def _packed_value(element, value: float) -> bytes:
    """``value`` as the vehicle stores the parameter ``element`` (its TOC type), as written."""
    number = float(value) if element.pytype in ("<f", "<d", "<e") else int(value)
    return struct.pack(element.pytype, number)


def _connect_failure(message: str | None, timeout_s: float) -> str:
    """cflib's connect failure (message + traceback) as one line with what to do."""
    if message is None:
        return f"no answer within {timeout_s:.0f} s (vehicle off, out of range, or another channel/address?)"
    text = str(message).split("Traceback")[0]
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    why = "; ".join(lines[:2]) or "connection failed"
    if "Crazyradio" in why:
        return f"{why}: plug in a Crazyradio and check its USB permissions (docs/deploy.md)"
    return why


@dataclass
class StateSample:
    """Onboard estimate (world frame, SI): pos_m, vel_mps (3), quat (w, x, y, z), battery."""

    t_s: float
    pos_m: tuple
    vel_mps: tuple
    quat: tuple
    vbat_v: float
    vehicle_s: float | None = None  # the vehicle's clock when it logged the position block (s)


BLOCK_A = [
    "stateEstimate.x",
    "stateEstimate.y",
    "stateEstimate.z",
    "stateEstimate.vx",
    "stateEstimate.vy",
    "stateEstimate.vz",
]
BLOCK_B = ["stateEstimate.qx", "stateEstimate.qy", "stateEstimate.qz", "stateEstimate.qw", "pm.vbat"]
BLOCK_KALMAN = ["kalman.varPX", "kalman.varPY", "kalman.varPZ"]  # position variances (m²), every 50 ms


class _BoundedCaller:
    """Runs calls on one daemon thread; ``call`` waits at most ``timeout_s`` for each."""

    def __init__(self, timeout_s: float, clock=WALL) -> None:
        self.timeout_s = float(timeout_s)
        self.clock = clock
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._queued = clock.event()
        clock.start_thread(self._run, "cflib-io")

    def _run(self) -> None:
        while True:
            self._queued.clear()
            while True:
                try:
                    fn, args, done, out = self._jobs.get_nowait()
                except queue.Empty:
                    break
                self.clock.end()  # taken up: this thread runs it
                try:
                    fn(*args)
                except Exception as exc:  # handed to the caller
                    out.append(exc)
                done.set()
            self.clock.wait(self._queued, None)

    def call(self, fn, *args, timeout_s: float | None = None) -> Exception | None:
        """None on success; the exception raised, or TimeoutError when the call is still running."""
        wait_s = self.timeout_s if timeout_s is None else timeout_s
        done, out = self.clock.event(), []
        self.clock.begin()
        self._jobs.put((fn, args, done, out))
        self._queued.set()
        if not self.clock.wait(done, wait_s):
            return TimeoutError(f"did not return within {wait_s:g} s")
        return out[0] if out else None


class CrazyflieLink:
    def __init__(
        self,
        uri: str,
        log_period_ms: int = 10,
        connect_timeout_s: float = 10.0,
        io_timeout_s: float = 0.5,
        clock=WALL,
    ) -> None:
        if not io_timeout_s > 0:
            raise LinkError(f"deploy.io_timeout_s: must be > 0, got {io_timeout_s}")
        self.uri = uri
        self.log_period_ms = int(log_period_ms)
        self.connect_timeout_s = float(connect_timeout_s)
        self.clock = clock  # the flight's (datt.deploy.clock): every wait goes through it
        self._io = _BoundedCaller(io_timeout_s, clock)
        self.link_lost = clock.event()
        self.lost_reason = ""
        self._a: dict | None = None
        self._b: dict | None = None
        self._t_a = self._t_b = -math.inf
        self._stamp_a = self._stamp_b = None  # the vehicle's timestamp (ms) of each block's latest sample
        self.variances: collections.deque = collections.deque(maxlen=50)  # (varPX, varPY, varPZ) samples
        self._lock = threading.Lock()
        self._fresh = clock.event()  # set with every log block
        self.round_trip_s = math.inf  # the shortest param read round trip seen (request -> answer)
        self.cf = None
        self.restore: dict[str, float] = {}  # parameters set at connect -> the value they held before

    # -- connection ------------------------------------------------------------------------
    def connect(self, external_position: bool = True) -> CrazyflieLink:
        """Open the link, set and read back rate mode and the Kalman estimator, start the logs.
        ``external_position``: mocap positions will be streamed; if not, a positioning deck is
        required (:data:`POSITIONING_DECKS`)."""
        crtp, Crazyflie, LogConfig = _cflib()
        import logging

        cflib_log = logging.getLogger("cflib")
        # cflib logs a connect failure with its traceback; we report it in one line below
        cflib_log.setLevel(logging.CRITICAL)
        try:
            crtp.init_drivers()
            self.cf = Crazyflie(rw_cache=None)
            done, error = self.clock.event(), []
            self.cf.connected.add_callback(lambda uri: done.set())
            self.cf.connection_failed.add_callback(lambda uri, msg: (error.append(msg), done.set()))
            self.cf.connection_lost.add_callback(self._on_lost)
            if self.clock.lockstep:
                crtp.CLASSES.insert(0, _lockstep_udp_driver(self.clock, self.uri))
                try:
                    self.cf.open_link(self.uri)
                finally:
                    del crtp.CLASSES[0]
            else:
                self.cf.open_link(self.uri)
            ok = self.clock.wait(done, self.connect_timeout_s) and not error
        finally:
            cflib_log.setLevel(logging.WARNING)  # its INFO chatter would drown the flight log
        if not ok:
            self.close()
            raise LinkError(
                f"connect: {self.uri}: {_connect_failure(error[0] if error else None, self.connect_timeout_s)}"
            )
        try:
            self._configure(external_position)
        except LinkError:
            self.close()
            raise
        for name, variables, store in (("state_a", BLOCK_A, "_a"), ("state_b", BLOCK_B, "_b")):
            lc = LogConfig(name=name, period_in_ms=self.log_period_ms)
            for v in variables:
                lc.add_variable(v, "float")
            self.cf.log.add_config(lc)
            lc.data_received_cb.add_callback(self._make_cb(store))
            lc.start()
        lc = LogConfig(name="kalman", period_in_ms=50)
        for v in BLOCK_KALMAN:
            lc.add_variable(v, "float")
        self.cf.log.add_config(lc)
        lc.data_received_cb.add_callback(self._on_variance)
        lc.start()
        return self

    def _on_variance(self, timestamp, data, logconf) -> None:
        with self._lock:
            self.variances.append(tuple(float(data[v]) for v in BLOCK_KALMAN))

    def reset_kalman(self) -> None:
        """Restart the Kalman filter (``kalman.resetEstimation``) and forget the variances seen."""
        with self._lock:
            self.variances.clear()
        self._send("kalman reset", self._set_value, "kalman.resetEstimation", 1)

    def kalman_settled(self, samples: int = 10, spread_m2: float = 1e-3) -> bool:
        """The last ``samples`` position variances each vary by less than ``spread_m2`` (cflib's
        ``wait_for_position_estimator`` rule)."""
        with self._lock:
            recent = list(self.variances)[-samples:]
        if len(recent) < samples:
            return False
        return all(max(axis) - min(axis) < spread_m2 for axis in zip(*recent))

    def _configure(self, external_position: bool) -> None:
        if not external_position:
            decks = [d for d in POSITIONING_DECKS if self._in_toc(d) and self.read_param(d) == 1]
            if not decks:
                raise LinkError(
                    "deploy.mocap.source: none, and the vehicle has no positioning deck (Lighthouse, Loco, Flow): "
                    "its estimator would not know x and y; set deploy.mocap.source=motioncapture"
                )
        self.set_params_checked(dict(OFFBOARD_SETTINGS))

    def _in_toc(self, name: str) -> bool:
        group, short = name.split(".")
        return short in self.cf.param.toc.toc.get(group, {})

    def read_param(self, name: str) -> float:
        """The value the vehicle holds now: a read request answered on the read channel. Write
        echoes are ignored (the firmware answers a write with the request itself, and cflib hands
        both to its update callbacks), and so is cflib's cache."""
        from cflib.crtp.crtpstack import CRTPPort

        element = self.cf.param.toc.get_element_by_complete_name(name)
        if element is None:
            raise LinkError(f"connect: the vehicle has no parameter {name} (firmware too old?)")
        ident = struct.pack("<H", element.ident)
        got, seen = self.clock.event(), []

        def cb(pk):
            data = bytes(pk.data)
            if pk.channel == PARAM_READ_CHANNEL and data[:2] == ident and len(data) >= 3:
                seen.append(struct.unpack(element.pytype, data[3:])[0])
                got.set()

        self.cf.add_port_callback(CRTPPort.PARAM, cb)
        try:
            asked = self.clock.monotonic()
            if self.clock.lockstep:
                self._param_packet(PARAM_READ_CHANNEL, ident)
            else:
                self.cf.param.request_param_update(name)
            if not self.clock.wait(got, self._io.timeout_s * 4):
                raise LinkError(f"connect: no answer reading {name} from the vehicle")
            self.round_trip_s = min(self.round_trip_s, self.clock.monotonic() - asked)
        finally:
            self.cf.remove_port_callback(CRTPPort.PARAM, cb)
        return float(seen[-1])

    def set_param_checked(self, name: str, value: float) -> None:
        """:meth:`set_params_checked` of one parameter."""
        self.set_params_checked({name: value})

    def set_params_checked(self, values: dict[str, float]) -> None:
        """Set each parameter, wait for the firmware's loop to act on them, then read each back
        fresh; a vehicle that holds another value (a read-only parameter, an id its firmware
        does not know) is refused. The value each held first is remembered and restored at
        :meth:`close`."""
        expected = {}
        for name, value in values.items():
            element = self.cf.param.toc.get_element_by_complete_name(name) if self._in_toc(name) else None
            if element is None:
                raise LinkError(f"connect: the vehicle has no parameter {name} (firmware too old?)")
            expected[name] = float(struct.unpack(element.pytype, _packed_value(element, value))[0])
            if name not in self.restore:
                self.restore[name] = self.read_param(name)
        for name, value in values.items():
            self._set_value(name, value)
        self.clock.sleep(PARAM_SETTLE_S)
        for name, value in values.items():
            got = self.read_param(name)
            if got != expected[name]:
                raise LinkError(f"connect: {name} reads back {got:g} after setting {value}")

    def wait_armed(self, timeout_s: float) -> bool:
        """True once the supervisor reports the vehicle armed (``supervisor.info`` bit), False
        if it has not within ``timeout_s`` (the supervisor updates at 25 Hz)."""
        deadline = self.clock.monotonic() + timeout_s
        while True:
            if self.supervisor_bits() & firmware.SUPERVISOR_BIT_ARMED:
                return True
            if self.clock.monotonic() >= deadline or self.link_lost.is_set():
                return False
            self.clock.sleep(firmware.SUPERVISOR_PERIOD_S / 2)

    def _make_cb(self, store: str):
        def cb(timestamp, data, logconf):
            with self._lock:
                setattr(self, store, data)
                setattr(self, "_t" + store, self.clock.monotonic())
                setattr(self, "_stamp" + store, timestamp)
            self._fresh.set()

        return cb

    def _on_lost(self, uri, msg) -> None:
        if not self.link_lost.is_set():
            self.lost_reason = str(msg)
        self.link_lost.set()

    def _send(self, what: str, fn, *args) -> None:
        """``fn(*args)`` within ``io_timeout_s``; a failure marks the link lost (never raises)."""
        if self.link_lost.is_set():
            return  # a dead or wedged link: do not queue behind a call that never returns
        error = self._io.call(fn, *args)
        if error is not None:
            self._on_lost(self.uri, f"{what}: {type(error).__name__}: {error}")

    def supervisor_bits(self) -> int:
        """The supervisor's state bitfield, asked for over the link (``supervisor.info``; the bits
        in :mod:`datt.deploy.firmware`)."""
        from cflib.crtp.crtpstack import CRTPPacket, CRTPPort

        got, seen = self.clock.event(), []

        def cb(pk):
            reply = firmware.SUPERVISOR_CMD_RESPONSE | firmware.SUPERVISOR_CMD_GET_STATE_BITFIELD
            if pk.channel == fact("supervisor_info_channel") and len(pk.data) >= 3 and pk.data[0] == reply:
                seen.append(int.from_bytes(bytes(pk.data[1:3]), "little"))
                got.set()

        self.cf.add_port_callback(CRTPPort.SUPERVISOR, cb)
        try:
            pk = CRTPPacket()
            pk.set_header(CRTPPort.SUPERVISOR, int(fact("supervisor_info_channel")))
            pk.data = bytes([firmware.SUPERVISOR_CMD_GET_STATE_BITFIELD])
            # asked again after each io_timeout_s without an answer (a request or its answer lost on
            # the radio, as cflib resends the requests it expects answers to)
            for _ in range(SUPERVISOR_REQUESTS):
                self._send("supervisor state", self.cf.send_packet, pk)
                if self.clock.wait(got, self._io.timeout_s):
                    break
            else:
                raise LinkError("preflight: the vehicle does not answer the supervisor state request (old firmware?)")
        finally:
            self.cf.remove_port_callback(CRTPPort.SUPERVISOR, cb)
        return seen[-1]

    def close(self) -> None:
        if self.cf is not None:
            if not self.link_lost.is_set() and self.restore:  # the settings changed back as they were (best effort)
                self._io.call(self._restore_settings, timeout_s=self._io.timeout_s * 8)
            # bounded like the sends; cflib joins its packet thread here (up to 1 s), hence the
            # longer bound. Errors must not mask the flight's outcome.
            error = self._io.call(self.cf.close_link, timeout_s=max(2.0, self._io.timeout_s))
            if isinstance(error, TimeoutError):
                self._on_lost(self.uri, f"close: {error}")

    def _restore_settings(self) -> None:
        """Write back the values the parameters set at connect held before, newest first; cflib
        sends queued writes one at a time, so a read behind them waits until all have landed."""
        for name, value in reversed(list(self.restore.items())):
            self._set_value(name, value)
        self.read_param(next(iter(self.restore)))

    # -- state -----------------------------------------------------------------------------
    def wait_state_after(self, t_s: float, timeout_s: float) -> None:
        """Wait (at most ``timeout_s``) until both log blocks have arrived after ``t_s``."""
        deadline = self.clock.monotonic() + timeout_s
        while True:
            self._fresh.clear()
            with self._lock:
                if min(self._t_a, self._t_b) > t_s:
                    return
            left = deadline - self.clock.monotonic()
            if left <= 0:
                return
            self.clock.wait(self._fresh, left)

    def state(self) -> StateSample | None:
        """Latest estimate (None before both log blocks arrived); ``t_s`` = older block's arrival."""
        with self._lock:
            a, b = self._a, self._b
            t = min(self._t_a, self._t_b)
            stamp_ms = self._stamp_a
        if a is None or b is None:
            return None
        return StateSample(
            t_s=t,
            pos_m=(a["stateEstimate.x"], a["stateEstimate.y"], a["stateEstimate.z"]),
            vel_mps=(a["stateEstimate.vx"], a["stateEstimate.vy"], a["stateEstimate.vz"]),
            quat=(b["stateEstimate.qw"], b["stateEstimate.qx"], b["stateEstimate.qy"], b["stateEstimate.qz"]),
            vbat_v=b["pm.vbat"],
            vehicle_s=None if stamp_ms is None else stamp_ms / 1000.0,
        )

    # -- the onboard app (deploy.onboard=true) --------------------------------------------------
    def has_param(self, name: str) -> bool:
        """The vehicle's firmware has the parameter ``name`` (e.g. ``datt.run``: the DATT app)."""
        return self._in_toc(name)

    def set_param(self, name: str, value: float) -> None:
        """Set ``name`` without reading it back (within ``io_timeout_s``; a failure marks the link lost)."""
        self._send(f"param {name}", self._set_value, name, value)

    def _set_value(self, name: str, value: float) -> None:
        """A parameter write: cflib's (queued on its parameter thread), or on the lockstep clock a
        write packet of the link's own, the same bytes, sent now."""
        if not self.clock.lockstep:
            self.cf.param.set_value(name, value)
            return
        element = self.cf.param.toc.get_element_by_complete_name(name)
        self._param_packet(PARAM_WRITE_CHANNEL, struct.pack("<H", element.ident) + _packed_value(element, value))

    def _param_packet(self, channel: int, data: bytes) -> None:
        from cflib.crtp.crtpstack import CRTPPacket, CRTPPort

        pk = CRTPPacket()
        pk.set_header(CRTPPort.PARAM, channel)
        pk.data = data
        self.cf.send_packet(pk)

    def send_app_packet(self, data: bytes) -> None:
        """One app-channel packet (at most 30 bytes) to the app."""
        self._send("app channel", self.cf.appchannel.send_packet, bytes(data))

    def on_app_packet(self, callback) -> None:
        """``callback(data: bytes)`` for every app-channel packet from the vehicle."""
        self.cf.appchannel.packet_received.add_callback(lambda data: callback(bytes(data)))

    def log_block(self, name: str, variables: list[str], period_ms: int, callback) -> None:
        """Start a log block; ``callback(values: dict)`` per sample (types from the vehicle's TOC)."""
        _, _, LogConfig = _cflib()
        lc = LogConfig(name=name, period_in_ms=int(period_ms))
        for v in variables:
            group, short = v.split(".")
            lc.add_variable(v, self.cf.log.toc.get_element(group, short).ctype)
        self.cf.log.add_config(lc)
        lc.data_received_cb.add_callback(lambda timestamp, data, logconf: callback(dict(data)))
        lc.start()

    # -- commands --------------------------------------------------------------------------
    def send_rates(self, roll_degps: float, pitch_degps: float, yaw_arg_degps: float, thrust_cmd: int) -> None:
        self._send("setpoint", self.cf.commander.send_setpoint, roll_degps, pitch_degps, yaw_arg_degps, int(thrust_cmd))

    def send_extpos(self, pos_m) -> None:
        self._send("extpos", self.cf.extpos.send_extpos, float(pos_m[0]), float(pos_m[1]), float(pos_m[2]))

    def send_extpose(self, pos_m, quat_wxyz) -> None:
        """Mocap position and attitude (the Kalman filter then knows the yaw in the mocap frame;
        with positions alone onboard yaw stays relative to the heading at start-up)."""
        w, x, y, z = (float(v) for v in quat_wxyz)
        px, py, pz = (float(v) for v in pos_m)
        self._send("extpose", self.cf.extpos.send_extpose, px, py, pz, x, y, z, w)

    def arm(self, on: bool = True) -> None:
        self._send("arm", self.cf.supervisor.send_arming_request, bool(on))

    def send_estop_watchdog(self) -> None:
        """Once sent, the firmware stops the motors (emergency stop, locked) if 1 s passes without
        another (``supervisor.c``): a dead link cannot leave the vehicle flying on its last setpoint."""
        self._send("e-stop watchdog", self.cf.supervisor.send_emergency_stop_watchdog)

    def emergency_stop(self) -> None:
        self._send("emergency stop", self.cf.supervisor.send_emergency_stop)
