"""A simulated Crazyflie that real cflib connects to over UDP (``udp://127.0.0.1:19850``).

It answers CRTP one packet per datagram (cflib's ``udpdriver``) on the ports cflib uses while
connecting and flying: link (magic string), platform (protocol version 12), log (TOC v2, blocks,
periodic data), param (TOC v2, read, write), mem (no memories), commander (legacy RPYT setpoints),
localization (external position), supervisor (arm, emergency stop). Behind it one drone of
:mod:`datt.sim` flies at ``dt_s`` on the flight's clock (``clock``: real time, or lockstep with
the host) with a disturbance model and a ground plane.

Firmware behaviour that matters for safety is emulated:

* **the legacy commander's thrust** (``crtp_commander_rpyt.c``): after start-up (and after an
  emergency stop is cleared by a restart) the thrust is locked, every setpoint flies thrust 0 (its
  rates still apply) until one with thrust 0 arrives; a thrust under ``MIN_THRUST`` (1000) flies 0,
  one above ``MAX_THRUST`` (60000) flies 60000;
* **setpoint watchdog**: 0.5 s without a setpoint -> level attitude at the last thrust; 2 s ->
  motors off and the supervisor **locked** (latched: later setpoints are ignored until the
  server restarts), as ``supervisor.c`` does in flight;
* **emergency stop**: motors off and locked until the server restarts; also when the host has
  sent the emergency-stop watchdog once and then not for 1 s (``supervisor.c``,
  ``DEFAULT_EMERGENCY_STOP_WATCHDOG_TIMEOUT``);
* **supervisor state**: the info channel answers the state bitfield (can be armed, armed, can
  fly, flying, locked);
* **motors**: the firmware's battery-compensated linear thrust map on the vehicle's own mass and
  motors (:mod:`datt.deploy.sim.motors`), never the controller's map;
* **yaw**: the legacy commander's yaw rate is integrated into a yaw-angle setpoint and the
  attitude PID (``controller_pid.c``: kp 6, ki 1 per second) turns the error into the yaw rate
  flown, so yaw lags the command;
* **below the commander** (``rate_loop``, by default the vehicle preset's: ``deploy.vehicle``):
  ``firmware`` (a stock Crazyflie) flies the rate setpoint through the firmware's rate PIDs, motor
  mixing with its cap, per-motor forces and a rigid body (:mod:`datt.deploy.sim.stabilizer`), where
  a hard rate demand near full thrust takes its torque from the collective; ``pi_first_order``
  through the training simulator's first-order rate response (:mod:`datt.sim`), the model of the
  paper's custom PI rate controller;
* **radio**: every packet is delayed by ``radio_latency_s`` each way, and setpoints, mocap and
  log data are lost with probability ``radio_loss`` (the radio's own retries make other losses
  rare; cflib resends requests that expect a reply);
* **the DATT app** (``onboard_library``: the app's C, :mod:`datt.deploy.sim.onboard_app`): its
  ``datt`` parameters and log variables, the app channel, and its 20 ms task before each physics
  step; its setpoints hold the commander (radio setpoints are dropped) and feed the watchdog;
  ``radio_cut_after_start_s`` silences the radio both ways that long after it starts;
* **battery**: ``pm.vbat`` falls linearly with motor-on time (``battery_drain_vps``); tests can
  set it (``server.battery_v``).

The onboard estimate follows the firmware's estimators (``stabilizer.estimator``: 0 = any, which
runs the complementary filter unless a positioning deck asks for the Kalman filter; 1 =
complementary; 2 = Kalman):

* **complementary**: attitude, height and vertical speed only; x, y, vx, vy stay 0 and external
  positions are dropped (as ``estimator_complementary.c`` does);
* **Kalman**: every external position (``extpos``) or pose (``extpose``) packet is a measurement
  fused with the scalar Kalman gain ``var / (var + extPosStdDev²)`` of the logged variance;
  between measurements it dead-reckons, with its error growing at
  ``dead_reckoning_drift_mps`` (a real filter on the IMU alone drifts faster). Onboard yaw is
  relative to the heading at start-up (``boot_yaw_deg`` from the mocap frame's x axis) until an
  ``extpose`` gives the filter the mocap attitude (a Lighthouse deck measures yaw itself; Loco
  and Flow decks do not).
"""

from __future__ import annotations

import collections
import errno
import heapq
import math
import random
import socket
import struct
import threading
import zlib
from dataclasses import dataclass, field, fields, replace

import torch

from datt.configuration import NOISE, POSITION_M, SEED, SPEED_MPS, Range, ranged
from datt.deploy import crtp
from datt.deploy.clock import WALL, LockstepClock
from datt.deploy.onboard import READ_ONLY as APP_READ_ONLY
from datt.deploy.sim.motors import FirmwareMotors, MotorParams
from datt.deploy.sim.onboard_app import OnboardApp
from datt.deploy.sim.stabilizer import Stabilizer
from datt.deploy.thrust import ThrustMap
from datt.errors import ConfigError
from datt.sim.frames import body_z_floats, quat_body_z, quat_exp_rotvec, quat_mul, quat_turned_floats
from datt.sim.quadrotor import Quadrotor, QuadrotorParams

LOG_VARS = [  # (group, name, type)
    ("stateEstimate", "x", "float"),
    ("stateEstimate", "y", "float"),
    ("stateEstimate", "z", "float"),
    ("stateEstimate", "vx", "float"),
    ("stateEstimate", "vy", "float"),
    ("stateEstimate", "vz", "float"),
    ("stateEstimate", "qx", "float"),
    ("stateEstimate", "qy", "float"),
    ("stateEstimate", "qz", "float"),
    ("stateEstimate", "qw", "float"),
    ("pm", "vbat", "float"),
    ("sys", "armed", "uint8_t"),
    ("kalman", "varPX", "float"),
    ("kalman", "varPY", "float"),
    ("kalman", "varPZ", "float"),
]
PARAMS = [  # (group, name, type, default)
    ("flightmode", "stabModeRoll", "uint8_t", 1),
    ("flightmode", "stabModePitch", "uint8_t", 1),
    ("stabilizer", "estimator", "uint8_t", 0),
    ("stabilizer", "controller", "uint8_t", 1),
    ("flightmode", "althold", "uint8_t", 0),
    ("flightmode", "poshold", "uint8_t", 0),
    ("flightmode", "posSet", "uint8_t", 0),
    ("commander", "enHighLevel", "uint8_t", 0),
    ("locSrv", "extPosStdDev", "float", 0.01),
    ("locSrv", "extQuatStdDev", "float", 4.5e-3),
    ("kalman", "resetEstimation", "uint8_t", 0),
    ("deck", "bcLighthouse4", "uint8_t", 0),
    ("deck", "bcDWM1000", "uint8_t", 0),
    ("deck", "bcFlow2", "uint8_t", 0),
]
POSITIONING_DECKS = ("bcLighthouse4", "bcDWM1000", "bcFlow2")  # the decks simulated (all ask for Kalman)
COMPLEMENTARY, KALMAN = 1, 2
# The simulated firmware's own model of controller.h's enum (its order is the id), independent of
# the host's table: a host that types an id this firmware does not mean flies the wrong controller
# here too. OutOfTree exists only in a build with CONFIG_CONTROLLER_OOT (the DATT app's).
CONTROLLERS = ("AutoSelect", "PID", "Mellinger", "INDI", "Brescianini", "Lee", "OutOfTree")
RATE_LOOPS = ("firmware", "pi_first_order")  # datt.sim.vehicles.RATE_LOOPS, the simulated firmware's own copy
RATE_CONTROLLERS = ("PID", "INDI", "OutOfTree")  # fly roll/pitch-rate setpoints (OutOfTree: the PID)
ATTITUDE_KP = 8.0  # the attitude-holding controllers' levelling gain (rad/s per rad), as the watchdog's
APP_CHANNEL_QUEUE = 10  # app_channel.c: xQueueCreate(10, sizeof(CRTPPacket)); a full queue drops
SUPERVISOR_PERIOD_S = 0.04  # supervisor.c runs at RATE_SUPERVISOR (25 Hz): arming takes effect there
PARAM_RO_FLAG = 0x40  # param TOC type byte: read-only
# kalman_core_params_defaults.h: stdDevInitialPosition_xy 100 m, _z 1 m (the variances after a reset)
KALMAN_RESET_VAR_M2 = (100.0**2, 100.0**2, 1.0)
KALMAN_PROCESS_M2PS = 0.01  # the position variance's growth per second between measurements
# supervisor.c isTumbledCheck (platform_defaults.h): body-z specific force under 0.5 g for 1 s, or
# under -0.2 g (upside down) for 0.1 s, is a tumble: motors off, crashed until a restart
TUMBLE_ACCZ_G, TUMBLE_S, UPSIDE_DOWN_ACCZ_G, UPSIDE_DOWN_S, FREE_FALL_G = 0.5, 1.0, -0.2, 0.1, 0.1
APP_CHANNEL = 2  # platform port channel of the app channel (app_channel.c)
EXT_POSE = 8  # localization generic channel message type (cflib Localization.EXT_POSE)
WATCHDOG_LEVEL_S, WATCHDOG_OFF_S = 0.5, 2.0
# crtp_commander_rpyt.c: a legacy setpoint's thrust under MIN_THRUST is 0, above MAX_THRUST it is MAX_THRUST
RPYT_MIN_THRUST, RPYT_MAX_THRUST = 1000, 60000
ESTOP_WATCHDOG_S = 1.0  # supervisor.c: DEFAULT_EMERGENCY_STOP_WATCHDOG_TIMEOUT
CMD_ARM, CMD_ESTOP, CMD_ESTOP_WATCHDOG, CMD_GET_STATE_BITFIELD = 1, 3, 4, 12  # crtp_supervisor.c
BIT_CAN_BE_ARMED, BIT_ARMED, BIT_CAN_FLY, BIT_FLYING, BIT_TUMBLED, BIT_LOCKED, BIT_CRASHED = 0, 1, 3, 4, 5, 6, 7


def _yaw_rotated(q: list[float], angle_rad: float) -> list[float]:
    """``q`` (w, x, y, z) pre-multiplied by a rotation of ``angle_rad`` about the world z axis."""
    c, s = math.cos(angle_rad / 2), math.sin(angle_rad / 2)
    w, x, y, z = q
    return [c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w]


def _wrap(angle_rad: float) -> float:
    return (angle_rad + math.pi) % (2 * math.pi) - math.pi


def _pack(fmt: str, value: float) -> bytes:
    """One log value in its wire type (integers for the integer types)."""
    return struct.pack(fmt, value if fmt[-1] in "fd" else int(value))


def _toc_crc(entries: list[tuple]) -> int:
    return zlib.crc32(repr(entries).encode()) & 0xFFFFFFFF


CLOCKS = ("real_time", "lockstep")


@dataclass
class SimCrazyflieParams:
    host: str = "127.0.0.1"
    port: int = 19850
    dt_s: float = ranged(0.02, Range(0.0, 1.0, low_open=True))
    # True: each loop logs the estimate of now, then steps (what a real vehicle can know); False
    # (the former order, kept to reproduce earlier figures): the step first, so the
    # state of t + dt_s leaves at t, a step earlier than a real vehicle knows it (docs/results/deploy_studies.md)
    log_before_step: bool = True
    battery_v: float = ranged(4.1, Range(2.5, 4.5))  # a 1S LiPo
    battery_drain_vps: float = ranged(0.002, Range(0.0, 1.0))
    start_pos_m: tuple = ranged((0.0, 0.0, 0.0), replace(POSITION_M, length=3))
    motors: MotorParams = field(default_factory=MotorParams)  # the vehicle's own (datt.deploy.sim.motors)
    decks: tuple = ()  # deck param names present, e.g. ("bcLighthouse4",): 0 = any then picks Kalman
    boot_yaw_deg: float = ranged(
        0.0, Range(-360.0, 360.0)
    )  # heading at start-up in the mocap frame (onboard yaw is relative to it)
    dead_reckoning_drift_mps: float = ranged(
        0.2, SPEED_MPS
    )  # Kalman estimate error growth without measurements (along x)
    radio_latency_s: float = ranged(
        0.005, Range(0.0, 1.0)
    )  # each way (host -> vehicle, vehicle -> host): 10 ms round trip
    radio_loss: float = ranged(
        0.0, Range(0.0, 1.0, high_open=True)
    )  # probability a setpoint, mocap or log packet is lost (after the radio's retries)
    radio_seed: int = ranged(0, SEED)
    onboard_library: str | None = None  # the DATT app's C as a shared library (datt.export.app); None = no app
    radio_cut_after_start_s: float | None = ranged(
        None, Range(0.0, 3600.0, optional=True)
    )  # the radio goes silent this long after the app starts
    refuse_arming: bool = False  # the supervisor refuses to arm (a firmware whose preflight checks fail)
    radio_jitter_s: float = ranged(
        0.0, Range(0.0, 1.0)
    )  # each packet's delay: radio_latency_s + U(0, radio_jitter_s), in order
    radio_burst_len: float = ranged(
        1.0, Range(1.0, 1000.0)
    )  # mean length of a run of lost packets (<= 1 / (1 - radio_loss): independent)
    vel_noise_std_mps: float = ranged(0.0, NOISE)  # the estimate's velocity error (first-order, 0.2 s correlation)
    att_noise_std_rad: float = ranged(
        0.0, NOISE
    )  # the estimate's roll/pitch/yaw error (first-order, 0.2 s correlation)
    boot_params: dict = field(default_factory=dict)  # parameter values at power-on ("group.name": value),
    # e.g. what an earlier flight left: parameters persist until a reboot
    # below the commander; None: the vehicle preset's (deploy.vehicle): firmware = rate PIDs, mixing,
    # motors, rigid body (datt.deploy.sim.stabilizer); pi_first_order = the training simulator's
    # first-order rate response, a model of the paper's custom PI rate controller
    rate_loop: str | None = ranged(None, Range(choices=RATE_LOOPS, optional=True))
    motor_time_constant_s: float = ranged(0.03, Range(0.0, 1.0))  # each motor's spin-up (an estimate; 0: instant)
    # real_time: the vehicle flies in real time beside the host (its stalls and compute time land in
    # the flight); lockstep: it and the host share one virtual clock (datt.deploy.clock), so a
    # flight's outcome does not depend on the machine's load (the host's compute takes no time)
    clock: str = ranged("real_time", Range(choices=CLOCKS))


def udp_port_free(port: int, host: str = "127.0.0.1") -> bool:
    """Nothing holds UDP ``port`` on ``host`` now: a probe binds it as :meth:`SimCrazyflie.start`
    does (no SO_REUSEADDR) and lets it go."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        try:
            probe.bind((host, port))
        except OSError:
            return False
    return True


def check_server_settings(node: dict, key: str = "deploy.server") -> None:
    """``deploy.server`` (the vehicle's keys of :class:`SimCrazyflieParams` and its motors'
    :class:`~datt.deploy.sim.motors.MotorParams`): every key known, every value in its range."""
    known = {f.name: f for f in fields(SimCrazyflieParams) if f.name not in ("host", "port", "motors")}
    known.update({f.name: f for f in fields(MotorParams)})
    for name, value in node.items():
        if name not in known:
            raise ConfigError(f"{key}.{name}: no such setting; allowed: {', '.join(sorted(known))}")
        rng = known[name].metadata.get("range")
        if rng is not None:
            rng.check(list(value) if isinstance(value, (list, tuple)) else value, f"{key}.{name}")
        if known[name].type in (bool, "bool") and not isinstance(value, bool):  # every switch, not a truthy string
            raise ConfigError(f"{key}.{name}: must be true or false, got {value!r}")
        if name == "decks" and (
            not isinstance(value, (list, tuple)) or any(deck not in POSITIONING_DECKS for deck in value)
        ):
            raise ConfigError(f"{key}.decks: must be a list of {', '.join(POSITIONING_DECKS)} (or []), got {value!r}")


class SimCrazyflie:
    """UDP CRTP server + real-time physics thread. ``start()`` / ``stop()``; ``kill()`` drops the
    link without a goodbye (fault injection: "server died mid-flight")."""

    def __init__(self, params: SimCrazyflieParams | None = None, disturbance=None, quad: QuadrotorParams | None = None):
        self.p = params or SimCrazyflieParams()
        # the flight's clock: the host's link, mocap and runner take it from here
        self.clock = LockstepClock() if self.p.clock == "lockstep" else WALL
        self.motors = FirmwareMotors(self.p.motors)
        self.stabilizer = Stabilizer(self.motors, self.p.motor_time_constant_s)
        self.quad = Quadrotor(1, quad or QuadrotorParams(), dt_s=self.p.dt_s)
        self.quad.reset(pos_m=torch.tensor([list(self.p.start_pos_m)]))
        self.quad.state.thrust_mps2.zero_()
        self.quad.latency.fill_all(torch.zeros(4))
        self.disturbance = disturbance
        if disturbance is not None:
            disturbance.bind(1, self.p.dt_s, torch.Generator().manual_seed(0), "cpu", torch.float32)
            disturbance.reset(torch.arange(1), self.quad.state)
        self.battery_v = self.p.battery_v
        self.params = {f"{g}.{n}": v for g, n, _, v in PARAMS}
        # a build with the app has the out-of-tree controller: its id is its place in the enum
        self.controllers = CONTROLLERS if self.p.onboard_library else CONTROLLERS[:-1]
        oot = CONTROLLERS.index("OutOfTree")
        self.app = OnboardApp(self.p.onboard_library, controller_id=oot) if self.p.onboard_library else None
        self.app_rx: list[bytes] = []  # the app channel's receive queue (APP_CHANNEL_QUEUE packets)
        self.app_rx_dropped = 0
        self.hook_t = -math.inf  # sim time the out-of-tree controller hook last ran
        self.arm_request: bool | None = None  # applied at the supervisor's next update
        self.param_toc = PARAMS + (self.app.param_toc if self.app else [])
        self.log_toc = LOG_VARS + (self.app.log_toc if self.app else [])
        self.app_priority = False  # the app's setpoints hold the commander (radio setpoints are dropped)
        self.app_started_t: float | None = None  # sim time the app first started tracking
        self.radio_down = False  # radio_cut_after_start_s passed: nothing gets through either way
        self._boot_params()
        self._init_estimator_and_supervisor()
        self.log_blocks: dict[int, dict] = {}
        self.armed = False
        self.thrust_locked = True
        self.emergency_stopped = False
        self.watchdog_locked = False  # the commander watchdog timed out in flight (latched)
        self.estop_watchdog_t: float | None = None  # sim time of the last e-stop watchdog notification
        self.cmd = (0.0, 0.0, 0.0, 0)  # wx, wy, wz (rad/s), thrust command
        self.last_setpoint_t = -math.inf
        self.client = None
        self.sim_time_s = 0.0
        self.events: list[tuple[float, str]] = []
        self.yaw_setpoint_rad = 0.0  # the firmware's attitudeDesired.yaw (legacy commander: integrated rate)
        self.yaw_integral = 0.0
        self._init_radio()
        self._lock = threading.Lock()
        self._running, self._stopping = threading.Event(), self.clock.event()
        self._threads: list[threading.Thread] = []
        # How far the physics loop fell behind its real-time schedule (s) from the host's first
        # supervisor request on (its preflight: the flight's part of the session): the host
        # machine's stall (a real vehicle's stabilizer runs on its own MCU and never falls behind),
        # after which the vehicle catches up flying the last setpoint, as one would after a host stall.
        # ``physics_lags``: (the clock's time, lag) of every step that ran over half a step late.
        self.physics_lag_max_s = 0.0
        self.physics_lags: list[tuple[float, float]] = []
        self._lag_watched = False
        # (the clock's time, true [x, y, z]) as each physics step begins, the last 10 min: the truth
        # tests measure the host's estimate-based figures against
        self.truth: collections.deque = collections.deque(maxlen=30000)

    def _init_radio(self) -> None:
        """The radio's queue (a heap of (due time on the clock, seq, direction, datagram)), its lock,
        the event a packet joining it sets, and its losses' generator."""
        self._radio: list = []
        self._radio_seq = 0
        self._radio_lock, self._radio_new = threading.Lock(), self.clock.event()
        self._radio_rng = random.Random(self.p.radio_seed)

    def _boot_params(self) -> None:
        """The vehicle's parameters at boot: the configured decks attached, the boot overrides
        applied (unknown names refused), and what the firmware derives from them settled."""
        for deck in self.p.decks:
            if f"deck.{deck}" not in self.params:
                raise ConfigError(
                    f"deploy.server.decks: unknown deck {deck!r}; allowed: {', '.join(POSITIONING_DECKS)}"
                )
            self.params[f"deck.{deck}"] = 1
        self.read_only = {f"{g}.{n}" for g, n, _, _ in PARAMS if g == "deck"} | {f"datt.{n}" for n in APP_READ_ONLY}
        for key, value in self.p.boot_params.items():
            if key not in self.params:
                raise ConfigError(
                    f"deploy.server.boot_params: unknown parameter {key!r}; allowed: {', '.join(self.params)}"
                )
            self.params[key] = value
        self._settle_params()

    def _init_estimator_and_supervisor(self) -> None:
        """The Kalman estimate's errors and variance, the supervisor's tumble timers and the
        radio's loss state, as at power-on."""
        self.pos_error_m = [0.0, 0.0, 0.0]  # Kalman: estimate - true position (held between measurements)
        self.kalman_var_m2 = list(KALMAN_RESET_VAR_M2)  # position variance: grows, shrinks with each measurement
        self.vel_error_mps = [0.0, 0.0, 0.0]  # the estimate's velocity error
        self.att_error_rad = [0.0, 0.0, 0.0]  # the estimate's attitude error (small rotation, world frame)
        self._noise_rng = random.Random(self.p.radio_seed + 1)
        self.crashed = False  # the supervisor found the vehicle tumbled: motors off until a restart
        self._tilted_s = 0.0  # how long the body-z specific force has been under the tumble limits
        self._upside_down_s = 0.0
        self._last_vel = None
        self._burst_lost = False  # the radio's loss state (a run of losses continues with 1 - 1 / burst_len)
        self._radio_last_due = 0.0  # packets stay in order: none is delivered before an earlier one
        self.yaw_aligned = False  # an extpose has told the Kalman filter the mocap yaw
        self.extpos_rx: list[tuple[float, tuple]] = []  # (monotonic time, position) of every ext position/pose

    # -- lifecycle -------------------------------------------------------------------------
    def start(self) -> SimCrazyflie:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        # No SO_REUSEADDR: on Linux it lets a second UDP server share the port and steal the
        # packets; UDP has no TIME_WAIT to wait out, so a free port binds without it.
        try:
            self.sock.bind((self.p.host, self.p.port))
        except OSError as exc:
            self.sock.close()
            if exc.errno == errno.EADDRINUSE:
                hint = "another simulated Crazyflie may be running: stop it or pick another port"
            else:  # a name that does not resolve, an address not of this machine
                hint = "the host must be an address of this machine"
            raise ConfigError(
                f"deploy.uri: udp://{self.p.host}:{self.p.port} cannot be bound ({exc.strerror}); {hint}, "
                "e.g. deploy.uri=udp://127.0.0.1:19851"
            ) from None
        self.sock.settimeout(0.05)
        self._running.set()
        self._t0 = self.clock.monotonic()
        self.clock.take_part()  # the thread that starts the vehicle flies it: the vehicle waits for it
        # the receive thread only hands datagrams on (accounted to the clock), so never waits on it
        rx = threading.Thread(target=self._rx_loop, name="sim-cf-rx", daemon=True)
        rx.start()
        self._threads = [
            rx,
            self.clock.start_thread(self._physics_loop, "sim-cf-physics"),
            self.clock.start_thread(self._radio_loop, "sim-cf-radio"),
        ]
        return self

    def stop(self) -> None:
        self._running.clear()
        self._stopping.set()
        self._radio_new.set()
        for t in self._threads:
            t.join(timeout=1.0)
        self.sock.close()

    kill = stop  # the link just goes silent, as when the vehicle loses power

    def __enter__(self) -> SimCrazyflie:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()

    # -- state -----------------------------------------------------------------------------
    @property
    def locked(self) -> bool:
        """The supervisor's Locked state: only a restart leaves it."""
        return self.emergency_stopped or self.watchdog_locked or self.crashed

    @property
    def motors_on(self) -> bool:
        return self.cmd[3] > 0 and not self.locked

    def state_bitfield(self) -> int:
        flying = self.armed and self.motors_on
        bits = {
            BIT_CAN_BE_ARMED: not self.locked and not self.armed and not self.p.refuse_arming,
            BIT_ARMED: self.armed,
            BIT_CAN_FLY: self.armed and not self.locked,
            BIT_FLYING: flying,
            BIT_LOCKED: self.emergency_stopped or self.watchdog_locked,
            BIT_TUMBLED: self.crashed,
            BIT_CRASHED: self.crashed,
        }
        return sum(1 << bit for bit, on in bits.items() if on)

    def true_state(self) -> dict:
        s = self.quad.state
        return {"pos_m": s.pos_m[0].tolist(), "vel_mps": s.vel_mps[0].tolist(), "quat": s.quat[0].tolist()}

    def _event(self, text: str) -> None:
        self.events.append((self.sim_time_s, text))

    @property
    def controller(self) -> str:
        """The controller running (``stabilizer.controller``, settled)."""
        return self.controllers[int(self.params["stabilizer.controller"])]

    def _settle_params(self) -> None:
        """What the stabilizer loop does with a written controller or estimator id
        (``stabilizer.c``): AutoSelect becomes the build's default (the PID, or the Kalman filter
        when a positioning deck asks for it); an id the build does not have is not switched to,
        and the parameter reads back the controller still running."""
        requested = int(self.params["stabilizer.controller"])
        if requested == 0:
            self.params["stabilizer.controller"] = CONTROLLERS.index("PID")
        elif not 0 < requested < len(self.controllers):
            self.params["stabilizer.controller"] = self._controller_running
        self._controller_running = int(self.params["stabilizer.controller"])
        estimator = int(self.params["stabilizer.estimator"])
        if estimator not in (COMPLEMENTARY, KALMAN):
            self.params["stabilizer.estimator"] = self.estimator

    _controller_running = 1  # the PID until a valid id is written

    # -- physics ---------------------------------------------------------------------------
    def _physics_loop(self) -> None:
        next_t = self.clock.monotonic()
        while self._running.is_set():
            if self._lag_watched or self.armed:
                now = self.clock.monotonic()
                self.physics_lag_max_s = max(self.physics_lag_max_s, now - next_t)
                if now - next_t > self.p.dt_s / 2:
                    self.physics_lags.append((now, now - next_t))
            with self._lock:
                # the step computes the next dt_s at once: logged after it, the state of t + dt_s
                # leaves at t (log_before_step=False), a step earlier than a real vehicle knows it
                if self.p.log_before_step:
                    self._send_logs()
                self._physics_step()
                if not self.p.log_before_step:
                    self._send_logs()
            next_t += self.p.dt_s
            self.clock.wait(self._stopping, next_t - self.clock.monotonic())

    def physics_lag_max_until(self, t_s: float) -> float:
        """How far the physics loop fell behind at most before the clock reached
        ``t_s`` (the end of the host's flight; after it a stall no longer meets the host's loop)."""
        return max((lag for t, lag in self.physics_lags if t - lag <= t_s), default=0.0)

    def _physics_step(self) -> None:
        self.truth.append((self.clock.monotonic(), self.quad.state.pos_m[0].tolist()))
        self._settle_params()
        if self.controller == "OutOfTree":
            self.hook_t = self.sim_time_s  # the hook runs in every stabilizer tick under this controller
        if self.arm_request is not None and self._supervisor_tick():
            self._apply_arming(self.arm_request)
            self.arm_request = None
        if self.app is not None:
            self._app_tick()
        command, (wx, wy, wz) = self._flown_setpoint()
        d = torch.zeros(1, 3)
        if self.disturbance is not None and self.motors_on:
            d = self.disturbance.current_mps2
        if self.rate_loop == "firmware":
            self._fly_stabilizer(command, (wx, wy, wz), d[0].tolist())
        else:
            thrust = self.motors.thrust_mps2(command, self.battery_v)
            self.quad.step(torch.tensor([[thrust, wx, wy, wz]]), d)
        if self.disturbance is not None:
            self.disturbance.update(self.quad.state)
        s = self.quad.state
        if s.pos_m[0, 2] < 0:  # ground: no penetration; at rest when not lifting off
            s.pos_m[0, 2] = 0.0
            s.vel_mps[0].zero_()
            s.rate_radps[0].zero_()
            s.quat[0] = torch.tensor([1.0, 0.0, 0.0, 0.0])
        self._tumble_check()
        self._estimate_noise_step()
        if self.motors_on:
            self.battery_v -= self.p.battery_drain_vps * self.p.dt_s
        self.kalman_var_m2 = [v + KALMAN_PROCESS_M2PS * self.p.dt_s for v in self.kalman_var_m2]
        if self.params["deck.bcLighthouse4"] or self.params["deck.bcDWM1000"]:
            self.pos_error_m = [0.0, 0.0, 0.0]  # the deck measures the position itself
            self._variance_update(0.01**2)
        else:  # dead reckoning until the next external measurement
            self.pos_error_m[0] += self.p.dead_reckoning_drift_mps * self.p.dt_s
        self.sim_time_s += self.p.dt_s

    @property
    def rate_loop(self) -> str:
        """The loop below the commander: ``deploy.server.rate_loop``, or (None) the vehicle preset's."""
        return self.p.rate_loop or self.motors.vehicle.rate_loop

    def _flown_setpoint(self) -> tuple[int, tuple[float, float, float]]:
        """The thrust command and body rates the firmware flies this step: the watchdogs, the
        e-stop watchdog, controllers that hold an attitude, yaw through the attitude PID, the
        position-hold modes; nothing unless armed."""
        now = self.sim_time_s
        wx, wy, wz, command = self.cmd
        age = now - self.last_setpoint_t
        if self.estop_watchdog_t is not None and now - self.estop_watchdog_t >= ESTOP_WATCHDOG_S and not self.locked:
            self.emergency_stopped = True
            self._event("emergency stop: no e-stop watchdog notification for 1 s")
        if not self.locked and age > WATCHDOG_OFF_S and command:
            self.watchdog_locked = True  # in flight: the supervisor locks
            self._event("watchdog: no setpoint for 2 s, motors off, locked")
        if self.locked or age > WATCHDOG_OFF_S:
            command, wx, wy, wz = 0, 0.0, 0.0, 0.0
            self.cmd = (0.0, 0.0, 0.0, 0)
        elif age > WATCHDOG_LEVEL_S:
            wx, wy, wz = self._level_rates()  # level the attitude at the last thrust, as the firmware's watchdog
        elif self.controller not in RATE_CONTROLLERS:
            # Mellinger, Brescianini, Lee: they fly the setpoint's attitude (level: the legacy
            # commander's rate-mode packet carries none) and ignore the rates
            wx, wy, wz = self._level_rates()
        else:
            wz = self._yaw_rate(wz, command)
        command = command if self.armed else 0
        if command and self._holds_position():
            # althold / poshold / posSet: the legacy commander turns the setpoint into velocity
            # commands around the hover; the vehicle holds level where it is
            wx, wy, wz = self._level_rates()
            command = self.motors.command_for_mps2(9.81 - 2.0 * float(self.quad.state.vel_mps[0, 2]))
        return command, (wx, wy, wz)

    def _fly_stabilizer(self, command: int, rate_sp_radps: tuple, d_mps2: list[float]) -> None:
        """One physics step of the vehicle below its commander (:mod:`datt.deploy.sim.stabilizer`):
        its 2 ms ticks of rate loop, motors and rotation, each with a translational step."""
        s = self.quad.state
        pos, vel, q = s.pos_m[0].tolist(), s.vel_mps[0].tolist(), s.quat[0].tolist()
        self.stabilizer.rate_radps = s.rate_radps[0].tolist()  # the ground (or a test) may have set it
        mass = self.p.motors.mass_kg
        force_n = 0.0
        ticks = max(1, round(self.p.dt_s / self.stabilizer.tick_s))
        h = self.p.dt_s / ticks
        for _ in range(ticks):
            force_n = self.stabilizer.tick(rate_sp_radps, command, self.battery_v)
            q = quat_turned_floats(q, [r * h for r in self.stabilizer.rate_radps])
            z = body_z_floats(q)
            acc = [z[i] * force_n / mass + d_mps2[i] for i in range(3)]
            acc[2] -= 9.81
            vel = [v + a * h for v, a in zip(vel, acc)]
            pos = [p + v * h for p, v in zip(pos, vel)]
        s.pos_m[0] = torch.tensor(pos)
        s.vel_mps[0] = torch.tensor(vel)
        s.quat[0] = torch.tensor(q)
        s.rate_radps[0] = torch.tensor(self.stabilizer.rate_radps)
        s.thrust_mps2[0] = force_n / mass

    def _apply_arming(self, wanted: bool) -> None:
        """The supervisor's arming transition: refused while locked, or always with
        ``refuse_arming`` (preflight checks that do not pass)."""
        if wanted and (self.locked or self.p.refuse_arming):
            self._event("arming refused")
            return
        if wanted != self.armed:
            self.armed = wanted
            self._event("armed" if self.armed else "disarmed")

    def _tumble_check(self) -> None:
        """``isTumbledCheck``: the accelerometer's body-z specific force (g) from the step's
        acceleration; free fall resets the clock."""
        s = self.quad.state
        vel = s.vel_mps[0].tolist()
        acc = (
            [0.0, 0.0, 0.0] if self._last_vel is None else [(v - u) / self.p.dt_s for v, u in zip(vel, self._last_vel)]
        )
        self._last_vel = vel
        z_world = quat_body_z(s.quat[0]).tolist()
        specific = [acc[0], acc[1], acc[2] + 9.81]
        acc_z_g = sum(a * b for a, b in zip(specific, z_world)) / 9.81
        if all(abs(a) / 9.81 < FREE_FALL_G for a in specific):
            self._tilted_s = self._upside_down_s = 0.0
            return
        self._tilted_s = self._tilted_s + self.p.dt_s if acc_z_g < TUMBLE_ACCZ_G and self.motors_on else 0.0
        self._upside_down_s = self._upside_down_s + self.p.dt_s if acc_z_g < UPSIDE_DOWN_ACCZ_G else 0.0
        if not self.crashed and (self._tilted_s > TUMBLE_S or self._upside_down_s > UPSIDE_DOWN_S):
            self.crashed = True
            self.cmd = (0.0, 0.0, 0.0, 0)
            self._event("supervisor: tumbled, motors off (crashed until a restart)")

    def _estimate_noise_step(self) -> None:
        """The estimate's velocity and attitude errors: first-order (Gauss-Markov) with a 0.2 s
        correlation time and the configured stationary std."""
        a = math.exp(-self.p.dt_s / 0.2)
        b = math.sqrt(1 - a * a)
        gauss = self._noise_rng.gauss
        self.vel_error_mps = [a * e + b * gauss(0.0, self.p.vel_noise_std_mps) for e in self.vel_error_mps]
        self.att_error_rad = [a * e + b * gauss(0.0, self.p.att_noise_std_rad) for e in self.att_error_rad]

    def _level_rates(self) -> tuple[float, float, float]:
        """Body rates that level the vehicle (P on the tilt, no yaw): what a controller that holds
        a level attitude flies."""
        q = self.quad.state.quat[0]
        return -ATTITUDE_KP * float(q[1]) * 2, -ATTITUDE_KP * float(q[2]) * 2, 0.0

    def _holds_position(self) -> bool:
        return any(int(self.params[f"flightmode.{k}"]) for k in ("althold", "poshold", "posSet"))

    def _supervisor_tick(self) -> bool:
        """True in the physics steps where the supervisor (25 Hz) updates."""
        return int(round(self.sim_time_s / self.p.dt_s)) % max(1, round(SUPERVISOR_PERIOD_S / self.p.dt_s)) == 0

    def _app_tick(self) -> None:
        """The app's 20 ms task: the state the out-of-tree controller hook handed over (zero
        unless ``stabilizer.controller`` selects it), one step, its setpoint to the commander at
        the app's priority (``COMMANDER_PRIORITY_EXTRX``: radio setpoints are then dropped)."""
        while self.app_rx:  # the task drains the app channel's queue, answering each packet
            self._send(crtp.packet(crtp.PORT_PLATFORM, APP_CHANNEL, self.app.receive(self.app_rx.pop(0))))
        if self.hook_t > -math.inf:
            pos, vel, quat = self._estimated_state()  # what the hook last handed over
        else:
            pos, vel, quat = [0.0] * 3, [0.0] * 3, [0.0] * 4  # never written
        # kalman.varPX/varPY as the app reads them; without the Kalman filter its position is unknown
        var = max(self.kalman_var_m2[:2]) if self.estimator == KALMAN else 1e6
        sp, relax = self.app.tick(pos, vel, quat, var, state_age_s=self.sim_time_s - self.hook_t)
        if relax:
            self.app_priority = False
            self._event("app: stopped, commander handed back")
        if sp is None:
            return
        if not self.app_priority:
            self._event("app: flying")
        self.app_priority = True
        self.last_setpoint_t = self.sim_time_s  # commanderSetSetpoint stamps it: the watchdog is fed
        if sp.stop:
            self.cmd = (0.0, 0.0, 0.0, 0)
        else:  # controller_pid.c: rateDesired tracked against (gyro.x, -gyro.y, gyro.z)
            self.cmd = (
                math.radians(sp.roll_degps),
                -math.radians(sp.pitch_degps),
                math.radians(sp.yaw_degps),
                sp.thrust,
            )
        if self.app_started_t is None:
            self.app_started_t = self.sim_time_s
        cut = self.p.radio_cut_after_start_s
        if cut is not None and not self.radio_down and self.sim_time_s - self.app_started_t >= cut:
            self.radio_down = True
            self._event("radio: link cut")

    def _yaw_rate(self, yaw_rate_cmd: float, command: int) -> float:
        """The yaw rate the firmware flies for a legacy yaw-rate setpoint: the setpoint integrates
        into a yaw angle (reset to the current yaw while thrust is 0) and the attitude PID turns
        the yaw error into a rate (``controller_pid.c``; PID_YAW_KP 6, KI 1, integral limit 360 deg)."""
        q = self.quad.state.quat[0].tolist()
        yaw = math.atan2(2 * (q[0] * q[3] + q[1] * q[2]), 1 - 2 * (q[2] ** 2 + q[3] ** 2))
        if command == 0:
            self.yaw_setpoint_rad, self.yaw_integral = yaw, 0.0
            return 0.0
        self.yaw_setpoint_rad = _wrap(self.yaw_setpoint_rad + yaw_rate_cmd * self.p.dt_s)
        error = _wrap(self.yaw_setpoint_rad - yaw)
        self.yaw_integral = max(-2 * math.pi, min(2 * math.pi, self.yaw_integral + error * self.p.dt_s))
        return 6.0 * error + 1.0 * self.yaw_integral

    def _variance_update(self, measurement_var_m2: float) -> None:
        """The scalar Kalman update of each axis' position variance for one position measurement."""
        r = measurement_var_m2
        self.kalman_var_m2 = [v * r / (v + r) for v in self.kalman_var_m2]

    @property
    def estimator(self) -> int:
        """The estimator running: the requested one, or for 0 (any) Kalman if a positioning deck
        is present, else complementary."""
        requested = int(self.params["stabilizer.estimator"])
        if requested in (COMPLEMENTARY, KALMAN):
            return requested
        return KALMAN if any(self.params[f"deck.{d}"] for d in POSITIONING_DECKS) else COMPLEMENTARY

    def _estimated_state(self) -> tuple[list[float], list[float], list[float]]:
        """The onboard estimate: position, velocity (world) and attitude (w, x, y, z)."""
        s = self.quad.state
        pos, vel = s.pos_m[0].tolist(), s.vel_mps[0].tolist()
        q = s.quat[0].tolist()  # (w, x, y, z)
        vel = [v + e for v, e in zip(vel, self.vel_error_mps)]
        if any(self.att_error_rad):  # a small world-frame rotation error
            error = quat_exp_rotvec(torch.tensor(self.att_error_rad, dtype=torch.float64))
            q = quat_mul(error, torch.tensor(q, dtype=torch.float64)).tolist()
        if self.estimator == COMPLEMENTARY:
            pos[0] = pos[1] = vel[0] = vel[1] = 0.0
        else:
            pos = [p + e for p, e in zip(pos, self.pos_error_m)]
        if not (self.yaw_aligned or self.params["deck.bcLighthouse4"]) and self.p.boot_yaw_deg:
            q = _yaw_rotated(q, -math.radians(self.p.boot_yaw_deg))
        return pos, vel, q

    def _estimate(self) -> list[float]:
        """The values of ``log_toc``, in its order."""
        pos, vel, q = self._estimated_state()
        # firmware order qx, qy, qz, qw
        values = [*pos, *vel, q[1], q[2], q[3], q[0], self.battery_v, float(self.armed), *self.kalman_var_m2]
        return values + (self.app.log_values() if self.app is not None else [])

    def _send_logs(self) -> None:
        if self.client is None:
            return
        values = self._estimate()
        ms = int(round(self.sim_time_s * 1000))  # the vehicle's tick count (ms) at this step
        for block_id, block in list(self.log_blocks.items()):
            if not block["started"]:
                continue
            block["acc_s"] += self.p.dt_s
            if block["acc_s"] + 1e-9 < block["period_s"]:
                continue
            block["acc_s"] = 0.0
            payload = b"".join(_pack(crtp.LOG_TYPES[self.log_toc[i][2]][1], values[i]) for i in block["vars"])
            self._send(crtp.log_data(block_id, ms, payload))

    # -- radio -----------------------------------------------------------------------------
    def _send(self, data: bytes) -> None:
        if self.radio_down:
            return
        if data[:1] == bytes([crtp.header(crtp.PORT_LOG, 2)]) and self._lost():
            return
        self._via_radio("out", data)

    def _lost(self) -> bool:
        """Losses in runs (a two-state chain): a lost packet is followed by another with
        probability 1 - 1 / radio_burst_len (at least ``radio_loss``: independent losses), and
        the runs start so that ``radio_loss`` of all packets are lost."""
        loss = self.p.radio_loss
        if loss <= 0:
            return False
        stay = max(loss, 1.0 - 1.0 / max(1.0, self.p.radio_burst_len))  # at least as likely as independent
        start = loss * (1.0 - stay) / (1.0 - loss)  # stationary loss fraction = loss
        self._burst_lost = self._radio_rng.random() < (stay if self._burst_lost else start)
        return self._burst_lost

    def _via_radio(self, direction: str, data: bytes) -> None:
        """Deliver ``data`` (to the host: "out"; to the firmware: "in") after the radio latency."""
        if self.p.radio_latency_s <= 0:
            self._deliver(direction, data)
            return
        with self._radio_lock:
            self._radio_seq += 1
            due = self.clock.monotonic() + self.p.radio_latency_s
            if self.p.radio_jitter_s > 0:
                due += self._radio_rng.uniform(0.0, self.p.radio_jitter_s)
            due = self._radio_last_due = max(due, self._radio_last_due)  # the radio keeps packets in order
            heapq.heappush(self._radio, (due, self._radio_seq, direction, data))
        self._radio_new.set()

    def _deliver(self, direction: str, data: bytes) -> None:
        if direction == "in":
            with self._lock:
                self._handle(data)
        elif self.client is not None:
            self.clock.begin()  # on its way to the host until cflib has handled it
            try:
                self.sock.sendto(data, self.client)
            except OSError:
                self.clock.end()

    def _radio_loop(self) -> None:
        """Delivers each packet of the radio's queue when it is due (the clock's time)."""
        while self._running.is_set():
            self._radio_new.clear()
            with self._radio_lock:
                due = self._radio[0][0] if self._radio else math.inf
                packet = heapq.heappop(self._radio) if due <= self.clock.monotonic() else None
            if packet is not None:
                self._deliver(packet[2], packet[3])
            else:
                self.clock.wait(self._radio_new, None if math.isinf(due) else due - self.clock.monotonic())

    def _rx_loop(self) -> None:
        while self._running.is_set():
            try:
                data, addr = self.sock.recvfrom(64)
            except TimeoutError:
                continue
            except OSError:
                return
            try:
                self._received(data, addr)
            finally:
                self.clock.end()  # the host's datagram is taken up: queued on the radio, or lost

    def _received(self, data: bytes, addr) -> None:
        if not data or self.radio_down:
            return
        self.client = addr
        port = crtp.split(data)[0] if data != b"\xff" else None
        if port in (crtp.PORT_COMMANDER, crtp.PORT_LOCALIZATION, crtp.PORT_PLATFORM) and self._lost():
            return
        self._via_radio("in", data)

    def _handle(self, datagram: bytes) -> None:
        if datagram == b"\xff":  # scan probe / null packet
            self._send(b"\xff")
            return
        port, ch, data = crtp.split(datagram)
        handler = {
            crtp.PORT_LINK: self._on_link,
            crtp.PORT_PLATFORM: self._on_platform,
            crtp.PORT_LOG: self._on_log,
            crtp.PORT_PARAM: self._on_param,
            crtp.PORT_MEM: self._on_mem,
            crtp.PORT_COMMANDER: self._on_commander,
            crtp.PORT_LOCALIZATION: self._on_localization,
            crtp.PORT_SUPERVISOR: self._on_supervisor,
            crtp.PORT_COMMANDER_GENERIC: self._on_generic_commander,
        }.get(port)
        if handler is not None:
            handler(ch, data)

    def _on_link(self, ch: int, data: bytes) -> None:
        if ch == 0:  # echo
            self._send(crtp.packet(crtp.PORT_LINK, 0, data))
        elif ch == 1:  # source: the magic string that says "protocol versioning supported"
            self._send(crtp.packet(crtp.PORT_LINK, 1, b"Bitcraze Crazyflie"))

    def _on_platform(self, ch: int, data: bytes) -> None:
        if ch == 1 and data and data[0] == 0:  # VERSION_GET_PROTOCOL
            self._send(crtp.packet(crtp.PORT_PLATFORM, 1, bytes([0, 12])))
        elif ch == APP_CHANNEL and self.app is not None:  # queued for the app's task; a full queue drops
            if len(self.app_rx) < APP_CHANNEL_QUEUE:
                self.app_rx.append(bytes(data))
            else:
                self.app_rx_dropped += 1

    def _toc(self, port: int, entries: list[tuple], types: dict, data: bytes) -> None:
        if data[0] == 3:  # info v2
            self._send(crtp.toc_info(port, len(entries), _toc_crc(entries)))
        elif data[0] == 2 and len(data) >= 3:  # item v2
            ident = data[1] | (data[2] << 8)
            if ident < len(entries):
                group, name, ctype = entries[ident][:3]
                type_id = types[ctype][0]
                if port == crtp.PORT_PARAM and f"{group}.{name}" in self.read_only:
                    type_id |= PARAM_RO_FLAG
                self._send(crtp.toc_item(port, ident, type_id, group, name))

    def _on_log(self, ch: int, data: bytes) -> None:
        if not data:
            return
        if ch == 0:
            self._toc(crtp.PORT_LOG, self.log_toc, crtp.LOG_TYPES, data)
            return
        cmd = data[0]
        if cmd == 5:  # reset
            self.log_blocks.clear()
            self._send(crtp.packet(crtp.PORT_LOG, 1, bytes([5, 0, 0])))
        elif cmd in (6, 7):  # create / append block v2: (type, id lo, id hi) triples
            block_id, items = data[1], data[2:]
            ids = [items[i + 1] | (items[i + 2] << 8) for i in range(0, len(items) - 2, 3)]
            block = self.log_blocks.setdefault(block_id, {"vars": [], "started": False, "period_s": 0.1, "acc_s": 0.0})
            block["vars"] += ids
            size = sum(struct.calcsize(crtp.LOG_TYPES[self.log_toc[i][2]][1]) for i in block["vars"])
            err = 7 if size > crtp.MAX_LOG_BLOCK_BYTES else 0  # E2BIG, as the firmware
            self._send(crtp.packet(crtp.PORT_LOG, 1, bytes([cmd, block_id, err])))
        elif cmd == 3:  # start: period in 10 ms units
            block = self.log_blocks.get(data[1])
            if block is not None:
                block["started"], block["period_s"] = True, max(data[2], 1) * 0.01
            self._send(crtp.packet(crtp.PORT_LOG, 1, bytes([3, data[1], 0 if block else 2])))
        elif cmd in (2, 4):  # delete / stop
            block = self.log_blocks.get(data[1])
            if block is not None:
                block["started"] = False
                if cmd == 2:
                    del self.log_blocks[data[1]]
            self._send(crtp.packet(crtp.PORT_LOG, 1, bytes([cmd, data[1], 0])))

    def _on_param(self, ch: int, data: bytes) -> None:
        if not data:
            return
        if ch == 0:
            self._toc(crtp.PORT_PARAM, self.param_toc, crtp.PARAM_TYPES, data)
            return
        if len(data) < 2:
            return
        ident = data[0] | (data[1] << 8)
        if ident >= len(self.param_toc):
            return
        group, name, ctype, _ = self.param_toc[ident]
        fmt = crtp.PARAM_TYPES[ctype][1]
        key = f"{group}.{name}"
        # the app's variables live in its C struct (read-only ones ignore the write there)
        get = (lambda: self.app.get(name)) if group == "datt" else (lambda: self.params[key])
        if ch == 2:  # write (param_logic.c): a read-only parameter is left alone and not answered;
            if key in self.read_only:  # any other is set and the request itself is the answer
                return
            value = struct.unpack(fmt, data[2 : 2 + struct.calcsize(fmt)])[0]
            if group == "datt":
                self.app.set(name, value)
            else:
                self.params[key] = value
            self._event(f"param {key} = {value}")
            if key == "kalman.resetEstimation" and value:
                self.kalman_var_m2 = list(KALMAN_RESET_VAR_M2)  # the firmware re-initialises the filter
                self.pos_error_m = [-v for v in self.quad.state.pos_m[0].tolist()]  # ... at the origin
                self.params[key] = 0  # and clears the flag
            self._send(crtp.packet(crtp.PORT_PARAM, 2, data))
        elif ch == 1:  # read: id, status 0, the value held now
            self._send(crtp.packet(crtp.PORT_PARAM, 1, data[:2] + b"\0" + struct.pack(fmt, get())))

    def _on_mem(self, ch: int, data: bytes) -> None:
        if ch == 0 and data and data[0] == 1:  # number of memories: none
            self._send(crtp.packet(crtp.PORT_MEM, 0, bytes([1, 0])))

    def _on_commander(self, ch: int, data: bytes) -> None:
        if ch != 0 or len(data) < 14 or self.locked or self.app_priority:
            return  # while the app holds the commander, lower-priority setpoints are dropped
        roll, pitch_wire, yaw, thrust = struct.unpack("<fffH", data[:14])
        self.last_setpoint_t = self.sim_time_s
        if thrust == 0 and self.thrust_locked:
            self.thrust_locked = False
            self._event("thrust unlocked")
        if self.params["flightmode.stabModeRoll"] != 0 or self.params["flightmode.stabModePitch"] != 0:
            self._event("setpoint ignored: not in rate mode (flightmode.stabModeRoll/Pitch must be 0)")
            return
        if self.thrust_locked or thrust < RPYT_MIN_THRUST:
            thrust = 0  # a locked commander's setpoint still holds the vehicle: motors at zero
        wx, wy, wz = ThrustMap.body_rates_from_wire(roll, pitch_wire, yaw)
        self.cmd = (wx, wy, wz, min(int(thrust), RPYT_MAX_THRUST))

    def _on_generic_commander(self, ch: int, data: bytes) -> None:
        if ch == 0 and data and data[0] == 0 and not self.app_priority:  # stop setpoint
            self.cmd = (0.0, 0.0, 0.0, 0)
            self.last_setpoint_t = self.sim_time_s

    def _on_localization(self, ch: int, data: bytes) -> None:
        if ch == 0 and len(data) >= 12:
            self._measure(struct.unpack("<fff", data[:12]), None)
        elif ch == 1 and len(data) >= 29 and data[0] == EXT_POSE:
            x, y, z, qx, qy, qz, qw = struct.unpack("<fffffff", data[1:29])
            self._measure((x, y, z), (qw, qx, qy, qz))

    def _measure(self, pos_m: tuple, quat_wxyz: tuple | None) -> None:
        """An external position (and attitude): the Kalman filter takes it; the complementary
        filter drops it."""
        self.extpos_rx.append((self.clock.monotonic(), tuple(pos_m)))
        if self.estimator != KALMAN:
            return
        true = self.quad.state.pos_m[0].tolist()
        r = float(self.params["locSrv.extPosStdDev"]) ** 2
        gains = [v / (v + r) for v in self.kalman_var_m2]  # the scalar Kalman gain per axis
        self.pos_error_m = [e + k * ((m - t) - e) for e, k, m, t in zip(self.pos_error_m, gains, pos_m, true)]
        self._variance_update(r)
        if quat_wxyz is not None:
            self.yaw_aligned = True

    def _on_supervisor(self, ch: int, data: bytes) -> None:
        if not data:
            return
        self._lag_watched = True  # the host's preflight or arming: from here its loop meets the vehicle's
        if ch == 0 and data[0] == CMD_GET_STATE_BITFIELD:  # info channel
            reply = bytes([0x80 | CMD_GET_STATE_BITFIELD]) + struct.pack("<H", self.state_bitfield())
            self._send(crtp.packet(crtp.PORT_SUPERVISOR, 0, reply))
        if ch != 1:
            return
        if data[0] == CMD_ARM:  # arm / disarm: acknowledged now, acted on at the supervisor's next update
            wanted = bool(data[1]) if len(data) > 1 else False
            self.arm_request = wanted
            self._send(crtp.packet(crtp.PORT_SUPERVISOR, 1, bytes([0x80 | CMD_ARM, 1, int(self.armed)])))
        elif data[0] == CMD_ESTOP:
            self.emergency_stopped = True
            self.cmd = (0.0, 0.0, 0.0, 0)
            self._event("emergency stop")
        elif data[0] == CMD_ESTOP_WATCHDOG:
            self.estop_watchdog_t = self.sim_time_s
