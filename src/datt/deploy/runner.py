"""Flight state machine: CONNECT -> PREFLIGHT -> ARM -> TAKEOFF -> HOVER -> TRACK -> LAND -> DISARM.

Every tick (``rate_hz``, 50 by default) the runner reads the onboard estimate from the link,
forwards the mocap position, asks :mod:`datt.deploy.safety` for OK / LAND / KILL, computes the
phase's controller output and sends it as a rate setpoint (thrust through
:mod:`datt.deploy.thrust`). TAKEOFF and LAND fly the PID baseline along a straight ramp, HOVER
holds the hover point with it (the hover trim rescales the thrust map after TAKEOFF and HOVER); TRACK
flies the configured controller (DATT + L1 by default) along the configured reference, starting
at the hover point.

Controllers run on a one-drone :class:`~datt.envs.TrackingEnv` used as a flight model: each tick
its simulator state is overwritten with the measurement (in the controller frame, whose origin is
the hover point, because the policy was trained on references starting at the origin), the
adaptation is updated with the command sent last tick, and the reference window advances by one
step. KILL sends the emergency stop before anything else. Every flight writes ``flight.csv`` (one
row per tick), ``events.json`` (phases, safety decisions, timing), and track plots to the run dir.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import gc
import math
import signal
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from datt.configuration import POSITION_M, Range, check_ranges, ranged
from datt.deploy import firmware
from datt.deploy.ceiling_guard import keep_altitude_at_ceiling
from datt.deploy.clock import WALL
from datt.deploy.feasibility import peak_ask, slow_factor, slowed
from datt.deploy.flight_log import FlightLog, errors_when_measured, measured_at
from datt.deploy.mocap import FrameLead
from datt.deploy.outcome import Kind, Outcome
from datt.deploy.safety import CELL, KILL, LAND, OK, BatteryFilter, SafetyParams, check, tilt_deg
from datt.deploy.thrust import ThrustMap, commands_acting, hover_command_from_hover
from datt.errors import LinkError
from datt.refs.base import RefFamily
from datt.runs import stop_signals


@contextlib.contextmanager
def frozen_heap():
    """Every object alive now moves to the collector's permanent generation until the block ends.

    A full (generation 2) collection walks every tracked object while holding the interpreter
    lock: with torch, torchrl, hydra and cflib loaded, a pause of every thread of the host as long
    as several control ticks (``benchmarks/host_pause.py``), while the vehicle flies its last rate
    setpoint. Frozen, a collection walks only what the flight itself allocated."""
    gc.freeze()
    try:
        yield
    finally:
        gc.unfreeze()


def _raise_interrupt(signum: int, frame: object) -> None:
    """Any stop request during a flight (SIGINT, SIGTERM; also where the process inherited them
    ignored, started in the background) KILLs it and writes the log."""
    raise KeyboardInterrupt("Ctrl-C" if signum == signal.SIGINT else signal.Signals(signum).name)


class Ramp(RefFamily):
    """Straight line from ``start`` to ``end`` (controller frame) over ``duration_s``, then hold."""

    def __init__(self, start, end, duration_s: float) -> None:
        self.start, self.end = torch.tensor(start, dtype=torch.float64), torch.tensor(end, dtype=torch.float64)
        self.duration_s = max(float(duration_s), 1e-6)

    def sample(self, n, t_s, generator):
        u = (t_s / self.duration_s).clamp(0.0, 1.0).unsqueeze(-1)
        return (self.start + u * (self.end - self.start)).to(t_s.dtype).expand(n, len(t_s), 3).clone()


PRE_ARM_PHASES = ("CONNECT", "PREFLIGHT")  # a stop here ends the flight with nothing armed
UNLOCK_TICKS = 5  # setpoints with thrust 0 sent after arming, one per control tick (FlightRunner._arm)


class FlightModel:
    """A controller flying from measurements: a one-drone env whose state is set each tick."""

    def __init__(
        self, make_env, controller, family: RefFamily, thrust_ceiling_mps2: float = math.inf, guard=None
    ) -> None:
        self.env = make_env(family)
        # keep_altitude_at_ceiling with its settings bound (thrust, rates, quat, ceiling) -> (rates,
        # guarded), or None: datt.deploy.ceiling_guard
        self.guard = guard
        self.guarded = 0  # commands the guard changed
        # the thrust map clips at max_command: the adaptation and the history get what is sent
        self.command_high = self.env.command_high.clone()
        self.command_high[0] = min(float(self.command_high[0]), thrust_ceiling_mps2)
        self.controller = controller
        self.env.reset()
        controller.reset(self.env)
        self.last_cmd = self.env.hover_action.clone()
        self.last_state_t: float | None = None  # arrival time of the estimate the last command answered

    def act(self, pos_m, vel_mps, quat, predicted=None, lead_steps: float = 0.0) -> np.ndarray:
        """The command for the measured state; ``predicted`` ((pos, vel, quat), the state rolled
        over the loop's latency) is what the controller then sees, with the policy's reference
        window read ``lead_steps`` ticks (a fraction interpolates) ahead, the predicted state's
        time, while the adaptation is updated from the measurement."""
        self.env.set_state(pos_m, vel_mps, quat)
        self.env.adaptation.update(self.env.sim.state, self.last_cmd, None)
        self.env.set_reference_lead(lead_steps)
        if predicted is not None:
            self.env.set_state(*predicted)
        td = None if self.controller.builds_observation else self.env.observe()
        action = self.controller.act(self.env, td)
        cmd = torch.clamp(action, self.env.action_low, self.command_high)
        if self.guard is not None:  # the attitude the controller saw (the predicted one, when predicting)
            cmd = self._keep_altitude(cmd, self.env.sim.state.quat[0].tolist())
        self.env.sim.latency.push(cmd)  # model-based controllers see the command in flight
        self.env.record_command(cmd)  # policies with obs.action_history see the commands sent
        self.last_cmd = cmd
        return cmd[0].detach().numpy().astype(float)  # as the env would apply it (NaN stays NaN)

    def hold(self) -> np.ndarray:
        """The last command again, for a tick whose estimate is the one the last command answered
        (its log packet was lost or late): there is nothing new to act on, and a policy fed the
        same state again, rolled over a longer latency, answers it with rates it never learned
        (measured: the stock loop's oscillation at the ceiling). The adaptation is not updated;
        the command history and the commands in flight record it as sent."""
        cmd = self.last_cmd
        self.env.sim.latency.push(cmd)
        self.env.record_command(cmd)
        return cmd[0].detach().numpy().astype(float)

    def _keep_altitude(self, cmd: torch.Tensor, quat: list[float]) -> torch.Tensor:
        """``cmd`` (1, 4) with the roll and pitch rates :func:`keep_altitude_at_ceiling` leaves."""
        values = cmd[0].tolist()
        rates, guarded = self.guard(values[0], values[1:4], quat, float(self.command_high[0]))
        if not guarded:
            return cmd
        self.guarded += 1
        # the guard's levelling rate stays within the rate bounds the policy's commands have
        rates_t = torch.tensor(rates, dtype=cmd.dtype).clamp(self.env.action_low[1:4], self.command_high[1:4])
        return torch.cat([cmd[:, :1], rates_t.unsqueeze(0)], dim=1)

    def set_thrust_ceiling(self, thrust_ceiling_mps2: float) -> None:
        """The most collective thrust the map will now command (after :meth:`FlightRunner._trim`)."""
        self.command_high[0] = min(float(self.env.command_high[0]), thrust_ceiling_mps2)

    def reference(self) -> np.ndarray:
        return self.env.reference_now_m()[0].numpy().astype(float)

    def advance(self) -> None:
        self.env.advance_reference()

    @property
    def d_hat(self) -> np.ndarray:
        return self.env.adaptation.d_hat[0].numpy().astype(float)


INFEASIBLE = ("refuse", "slow")  # deploy.flight.infeasible


# The flight's ranges say what a setting can mean, so that none makes a wait without end or a check
# that never fires (each with its reason; a value outside is refused in one line).
PHASE_S = Range(0.0, 60.0, low_open=True)  # a takeoff, landing or wait longer than a minute is a mistake
HOLD_S = Range(0.0, 600.0)  # a hover is at most a battery's flight (~7 min)


@dataclass
class FlightParams:
    # the radio carries about 1000 packets/s, shared with the log and mocap: beyond 500 Hz the
    # setpoints cannot get through and every tick runs late
    rate_hz: float = ranged(50.0, Range(1.0, 500.0))
    takeoff_height_m: float = ranged(1.0, Range(0.0, 5.0, low_open=True))  # a room's height
    takeoff_s: float = ranged(2.5, PHASE_S)
    hover_s: float = ranged(1.0, HOLD_S)
    track_s: float | None = ranged(None, Range(0.0, 600.0, low_open=True, optional=True))  # None = the env's episode
    land_s: float = ranged(2.5, PHASE_S)
    preflight_timeout_s: float = ranged(3.0, PHASE_S)
    arm_timeout_s: float = ranged(1.0, PHASE_S)  # the supervisor must report "armed" within this
    min_battery_v: float = ranged(3.7, CELL)  # preflight: a Crazyflie 2.x cell (datt.deploy.safety.CELL)
    late_tick_ms: float = ranged(5.0, Range(0.0, 1000.0, low_open=True))
    estop_watchdog: bool = True  # send the firmware's e-stop watchdog every tick (motors off 1 s after the last)
    origin_m: list = ranged([0.0, 0.0], POSITION_M)  # hover point x, y (z = takeoff_height_m)
    onboard_max_pos_std_m: float = ranged(0.1, Range(0.0, 1.0))  # deploy.onboard: the app lands above this (0: never)
    # rescale the thrust map to the command the takeoff's hover needed, before TRACK (FlightRunner._climb)
    hover_trim: bool = True
    hover_trim_window_s: float = ranged(0.5, PHASE_S)  # the end of the hover the trim averages over
    hover_trim_max: float = ranged(0.25, Range(0.0, 1.0, low_open=True, high_open=True))  # larger change: LAND
    # HOVER on the trim, trimmed again, before TRACK (0: none)
    hover_trim_settle_s: float = ranged(2.0, Range(0.0, 60.0))
    # how long after it is sent a command shows in the logged velocity (s): the trim pairs each window's
    # velocity change with the commands sent this much earlier; null = the radio round trip measured at
    # connect + one control tick (the vehicle's actuation)
    hover_trim_lag_s: float | None = ranged(None, Range(0.0, 0.5, optional=True))
    # altitude first at the thrust ceiling (datt.deploy.ceiling_guard): a command at the map's ceiling
    # from an attitude tilted past acos((g + reserve) / ceiling) levels instead of tilting further
    # (off by default: not better in the transfer test, docs/results/deploy_studies.md)
    ceiling_guard: bool = False
    ceiling_climb_reserve_mps2: float = ranged(0.0, Range(0.0, 10.0))
    ceiling_level_gain_per_s: float = ranged(4.0, Range(0.0, 100.0))
    # before TRACK, the reference's thrust ask against the ceiling the hover trim measured
    # (datt.deploy.feasibility): a reference the vehicle cannot follow is refused (LAND from the
    # hover) or, with "slow", flown slower in time until it fits (at most max_slow_factor)
    infeasible: str = ranged("refuse", Range(choices=INFEASIBLE))
    thrust_window_s: float = ranged(0.4, Range(0.02, 2.0))  # corners averaged over this (a tracker's response time)
    thrust_reserve_mps2: float = ranged(0.5, Range(0.0, 10.0))  # kept under the ceiling for the feedback
    max_slow_factor: float = ranged(2.0, Range(1.0, 10.0))

    def validate(self) -> None:
        from datt.errors import ConfigError

        check_ranges(self, "deploy.flight")
        if len(self.origin_m) != 2:
            raise ConfigError(f"deploy.flight.origin_m: need 2 values (x, y), got {self.origin_m!r}")
        if self.hover_trim and self.hover_trim_window_s > self.hover_s:
            raise ConfigError(
                f"deploy.flight.hover_trim_window_s: must be at most deploy.flight.hover_s ({self.hover_s:g} s) "
                f"while deploy.flight.hover_trim is on, got {self.hover_trim_window_s:g}"
            )
        if self.hover_trim and 0 < self.hover_trim_settle_s < self.hover_trim_window_s:
            raise ConfigError(
                "deploy.flight.hover_trim_settle_s: must be 0 or at least deploy.flight.hover_trim_window_s "
                f"({self.hover_trim_window_s:g} s) while deploy.flight.hover_trim is on, "
                f"got {self.hover_trim_settle_s:g}"
            )


class FlightRunner:
    """An off-board flight: CONNECT -> PREFLIGHT -> ARM -> TAKEOFF -> HOVER -> TRACK -> LAND -> DISARM, the
    configured controller flying over the radio at ``rate_hz``. :class:`~datt.deploy.onboard_flight.OnboardFlight`
    hands TRACK to the vehicle's app, :class:`~datt.deploy.calibration.CalibrationFlight` hovers
    with a thrust excitation instead."""

    sends_estop_watchdog = True  # the firmware's e-stop watchdog every tick (onboard: the app flies on without us)
    # deploy.mocap.lead_s null: off-board the host's predictor rolls the estimate over the latency; the
    # vehicle's filter is not led (onboard flights lead it by half the radio round trip)
    leads_mocap_by_half_round_trip = False
    _forwarding = False  # mocap frames go to the vehicle (from CONNECT until the log is written)
    clock = WALL  # set from the link in __init__ (a runner built without one, for its bookkeeping: real time)

    def __init__(
        self,
        link,
        mocap,
        make_env,
        track_controller,
        pid_factory,
        track_family: RefFamily,
        params: FlightParams,
        safety: SafetyParams,
        thrust: ThrustMap,
        run_dir: Path,
        estop: threading.Event | None = None,
        console=None,
        stop_request=None,
        summary_extra: dict | None = None,
        predictor=None,
    ) -> None:
        self.link, self.mocap = link, mocap
        self.clock = getattr(link, "clock", WALL)  # the flight's (the link's): every wait goes through it
        self.make_env, self.track_controller, self.pid_factory = make_env, track_controller, pid_factory
        self.track_family = track_family
        self.p, self.safety, self.thrust = params, safety, thrust
        self.configured_hover_command = thrust.hover_command  # before any hover trim
        self.run_dir = Path(run_dir)
        self.estop = estop or threading.Event()
        self.log = FlightLog(self.run_dir, console, params.rate_hz, params.late_tick_ms, self.clock)
        self.outcome = Outcome(Kind.INCOMPLETE)
        self.battery = BatteryFilter(safety.battery_filter_s)
        self._mocap_sent_t: float | None = None  # time stamp of the last mocap sample forwarded
        self._frame_lock = threading.Lock()
        self._frame_ready = self.clock.event()
        self._pending_frame = None  # the newest mocap frame not yet forwarded
        self._lead = None  # datt.deploy.mocap.FrameLead of the forwarded positions (set at CONNECT)
        self.predictor = predictor  # off-board latency compensation (datt.deploy.predictor), or None
        self._excitation = None  # calibration: extra thrust (m/s²) as a function of the tick index
        self.stop_request = stop_request  # datt.runs.StopRequest active while the flight was prepared
        self.summary_extra = dict(summary_extra or {})  # recorded in events.json with the summary
        self._track_table = None  # the track's reference table as drawn (the thrust check slows a copy)

    # -- helpers ---------------------------------------------------------------------------
    @property
    def phase(self) -> str:
        return self.log.phase

    @property
    def t0(self) -> float:
        return self.log.t0

    @property
    def rows(self) -> list[dict]:
        return self.log.rows

    @property
    def events(self) -> list[dict]:
        return self.log.events

    def _event(self, kind: str, text: str = "", **extra) -> None:
        self.log.event(kind, text, **extra)

    def _set_phase(self, phase: str) -> None:
        self.log.set_phase(phase)

    def _origin(self) -> np.ndarray:
        return np.array([self.p.origin_m[0], self.p.origin_m[1], self.p.takeoff_height_m])

    def _has_mocap(self) -> bool:
        return self.mocap is not None and self.mocap.name != "none"

    def _mocap_age(self) -> float | None:
        """The age of the latest mocap frame (None without a mocap source, inf before one)."""
        if not self._has_mocap():
            return None
        sample = self.mocap.read()
        return math.inf if sample is None else self.clock.monotonic() - sample[2]

    def _forward_frame(self, sample) -> None:
        """A new mocap frame (the source's thread): led (``deploy.mocap.lead_s``) and kept as the one
        to forward next; a frame not yet forwarded when a newer one arrives is dropped (the newest is
        the one worth sending)."""
        if self._lead is not None:
            pos, quat, t = sample
            sample = (self._lead(pos, t), quat, t)
        with self._frame_lock:
            self._pending_frame = sample
        self._frame_ready.set()

    def _forward_frames(self) -> None:
        """Each mocap frame to the vehicle as it arrives (own thread, so a slow send never holds
        the mocap source back), once, and never one older than ``safety.max_mocap_age_s``: the
        Kalman filter takes every packet as a fresh measurement, so resending an old one would
        pin the estimate where the vehicle was."""
        while self._forwarding:
            if not self.clock.wait(self._frame_ready, 0.05):
                continue
            self._frame_ready.clear()
            with self._frame_lock:
                sample, self._pending_frame = self._pending_frame, None
            if sample is None or not self._forwarding:
                continue
            pos, quat, t = sample
            if t == self._mocap_sent_t or self.clock.monotonic() - t > self.safety.max_mocap_age_s:
                continue
            self._mocap_sent_t = t
            if quat is None:
                self.link.send_extpos(pos)
            else:
                self.link.send_extpose(pos, quat)

    def _send(self, action) -> int:
        roll, pitch, yaw = self.thrust.rates_deg(float(action[1]), float(action[2]), float(action[3]))
        command = self.thrust.command(float(action[0]))
        self.link.send_rates(roll, pitch, yaw, command)
        return command

    def _refuse(self, detail: str) -> None:
        """End the flight before arming: ``detail`` says why (a setting's refusal names its key,
        ``deploy.…``), is logged and becomes the flight's outcome."""
        kind = Kind.REFUSED_SETTING if detail.startswith("deploy.") else Kind.REFUSED
        self.outcome = Outcome(kind, detail)
        self._event("preflight failed", detail)
        raise _Abort(self.outcome.text)

    def _kill(self, reason: str) -> None:
        self.link.emergency_stop()  # first, before logging or anything else
        self._event("KILL", reason)
        self.outcome = Outcome(Kind.KILLED, reason)

    # -- flight ----------------------------------------------------------------------------
    def _flight(self, build, airborne) -> dict:
        """CONNECT -> PREFLIGHT -> ``build(start)`` -> ARM -> ``airborne(origin, built)`` -> DISARM;
        the flight log is written whatever happens. Models are built (and the policy traced)
        before the motors spin, and the heap is frozen from CONNECT to DISARM (``frozen_heap``: a
        full collection of a large heap pauses every thread, the link's and the preflight's
        too), so nothing stalls the control loop mid-flight. A stop request
        before arming (also one made while the flight was being prepared: ``stop_request``) ends
        the flight unarmed; after arming it KILLs."""
        try:
            with stop_signals(_raise_interrupt):
                self._stop_if_requested()
                with frozen_heap():
                    self._connect()
                    self._set_phase("PREFLIGHT")
                    start = self._preflight()
                    origin = self._origin()
                    built = build(start - origin)
                    self._stop_if_requested()
                    self._arm()
                    airborne(origin, built)
        except _Abort:
            pass
        except KeyboardInterrupt as exc:
            why = exc.args[0] if exc.args else "Ctrl-C"
            if self.phase in PRE_ARM_PHASES:
                self._stopped(why)
            else:
                self._kill(f"operator interrupt ({why})")
        except LinkError as exc:
            if self.phase == "CONNECT":
                raise  # the vehicle could not be reached or refused a setting: the command's error
            if self.phase in PRE_ARM_PHASES:
                self.outcome = Outcome(Kind.LINK_LOST, str(exc))
                self._event("link lost", str(exc))
            else:
                self._kill(str(exc))
        finally:
            summary = self._disarm_and_write()
        return summary

    def _connect(self) -> None:
        """CONNECT: open the link (the vehicle's settings read back), hand the predictor the
        measured round trip, and start forwarding motion capture."""
        self._set_phase("CONNECT")
        self.link.connect(external_position=self._has_mocap())
        if self.predictor is not None:  # the radio round trip, measured by connect's param reads
            self.predictor.round_trip_s = self.link.round_trip_s
            self._event("predictor", f"latency {self.predictor.latency_s * 1000:.0f} ms compensated")
        if self._has_mocap():
            self._lead = self._mocap_lead()
            self.mocap.subscribe(self._forward_frame)
            self._forwarding = True
            self.clock.start_thread(self._forward_frames, "mocap-forward")
        if self.mocap is not None:
            self.mocap.start()

    def _mocap_lead(self):
        """The lead of the forwarded mocap positions: ``deploy.mocap.lead_s``, or by the flight's
        rule when null; None when there is none (logged either way)."""
        lead_s = self.mocap.lead_s
        if lead_s is None:
            rtt = self.link.round_trip_s
            lead_s = rtt / 2 if self.leads_mocap_by_half_round_trip and math.isfinite(rtt) else 0.0
        if lead_s <= 0.0:
            return None
        self._event("mocap lead", f"each forwarded mocap position led {lead_s * 1000:.0f} ms along its velocity")
        return FrameLead(lead_s, self.mocap.lead_window_s)

    def _disarm_and_write(self) -> dict:
        """DISARM whatever happened, write the flight log, then close mocap and the link;
        returns the summary."""
        with stop_signals(signal.SIG_IGN):  # a second Ctrl-C must not cut the disarm or the log short
            self._set_phase("DISARM")
            try:
                self.link.send_rates(0.0, 0.0, 0.0, 0)
                self.link.arm(False)
            except Exception as exc:  # a dead link cannot disarm; the vehicle's watchdog does
                self._event("disarm failed", str(exc))
            if self.link.link_lost.is_set():  # the sends above were skipped; say why
                self._event("link lost", self.link.lost_reason)
            summary = self._write()  # before closing anything: a hanging close keeps the log
            if self._forwarding:
                self._forwarding = False
                self._frame_ready.set()  # the forwarding thread sees it at once
            try:
                if self.mocap is not None:
                    self.mocap.stop()
                self.link.close()
            except Exception as exc:
                self._event("close failed", str(exc))
                summary = self._write()
        return summary

    def _stop_if_requested(self) -> None:
        """A stop signal that arrived while the flight was being prepared (before the runner
        took the signals over) ends it here, before anything is armed."""
        if self.stop_request is not None and self.stop_request.signal is not None:
            raise KeyboardInterrupt(self.stop_request.signal)

    def _stopped(self, why: str) -> None:
        self.outcome = Outcome(Kind.STOPPED, why)
        self._event("stopped", self.outcome.text)

    def _arm(self) -> None:
        """Arm, and take off only once the supervisor reports the vehicle armed: a firmware
        that refuses (or needs longer) would otherwise fly the track on the ground."""
        self._set_phase("ARM")
        self.link.arm(True)
        try:
            armed = self.link.wait_armed(self.p.arm_timeout_s)
        except LinkError as exc:
            armed, why = False, str(exc)
        else:
            why = f"the supervisor did not report the vehicle armed within {self.p.arm_timeout_s:g} s"
        if not armed:
            self.link.arm(False)
            self.outcome = Outcome(Kind.ARMING_FAILED, f"{why} (supervisor.info); nothing flew")
            self._event("arming failed", self.outcome.text)
            raise _Abort(self.outcome.text)
        self._event("armed", "the supervisor reports the vehicle armed")
        # crtp_commander_rpyt.c: the thrust stays locked (motors at 0) until a setpoint with thrust
        # 0 arrives. One such packet lost on the radio left the vehicle on the ground at full
        # command for the whole takeoff, so the unlock goes out once per control tick for
        # UNLOCK_TICKS ticks: all of them lost on a link that drops 2 % is ~3e-9.
        period_s = 1.0 / self.p.rate_hz
        for _ in range(UNLOCK_TICKS):
            self.link.send_rates(0.0, 0.0, 0.0, 0)
            self.clock.sleep(period_s)

    def _takeoff(self, start_rel: np.ndarray) -> tuple:
        model = self._model(self.pid_factory(), Ramp(start_rel, [0.0, 0.0, 0.0], self.p.takeoff_s))
        return ("TAKEOFF", model, self.p.takeoff_s + self.p.hover_s)

    def _hover_after_trim(self) -> tuple | None:
        """The HOVER phase flown on the trimmed map before TRACK (the PID, a fresh integral), or None."""
        if not (self.p.hover_trim and self.p.hover_trim_settle_s > 0):
            return None
        return ("HOVER", self._model(self.pid_factory(), Ramp([0.0] * 3, [0.0] * 3, 1.0)), self.p.hover_trim_settle_s)

    def _climb(self, origin: np.ndarray, takeoff: tuple, hover: tuple | None, later: list[FlightModel]) -> str:
        """TAKEOFF, the hover trim (:meth:`_trim`; ``later``: the models still to fly) and HOVER.
        Returns OK, or how the flight ended (KILL, or LAND: already landed)."""
        name, model, duration = takeoff
        self._set_phase(name)
        result = self._fly_phase(model, duration, origin)
        if result != OK:
            return result
        if not self._lifted_off(name):
            self._land(origin)
            return LAND
        if not self.p.hover_trim:
            return OK
        # two passes: the takeoff's hover on the configured map (its PID may be saturated, its
        # integral winding up), then HOVER on that trim, steadier, refines it
        if self._trim(name, later + ([hover[1]] if hover is not None else []), final=hover is None) != OK:
            self._land(origin)
            return LAND
        if hover is None:
            return OK
        self._set_phase(hover[0])
        result = self._fly_phase(hover[1], hover[2], origin)
        if result != OK:
            return result
        if not self._lifted_off(hover[0]) or self._trim(hover[0], later, final=True) != OK:
            self._land(origin)
            return LAND
        return OK

    def fly(self) -> dict:
        """Takeoff, track the reference with the configured controller, land."""

        def build(start_rel):
            track = self._model(self.track_controller, self.track_family)
            self._check_reference_in_geofence(track, self.p.track_s)
            return self._takeoff(start_rel), self._hover_after_trim(), track

        def airborne(origin, built):
            takeoff, hover, track = built
            if self._climb(origin, takeoff, hover, [track]) != OK:
                return  # killed, or already landed
            refusal = self._thrust_check(track, self.thrust.ceiling_mps2, can_slow=True)
            if refusal is not None:
                self._land(origin, refused=refusal)
                return
            self._set_phase("TRACK")
            ended = self._fly_phase(track, self.p.track_s, origin)
            self._note_guard(track)
            if ended != OK:
                return
            self._land(origin)

        return self._flight(build, airborne)

    def _thrust_check(self, track: FlightModel, ceiling_mps2: float, can_slow: bool) -> str | None:
        """Before TRACK: :meth:`_fit_reference`; a reference that does not fit is not flown (a LAND
        event names both figures and the option). Returns None (fly) or the refusal, for
        :meth:`_land` (the outcome ``refused_reference``)."""
        refusal = self._fit_reference(track, ceiling_mps2, can_slow)
        if refusal is not None:
            self._event("LAND", refusal)
        return refusal

    def _fit_reference(self, track: FlightModel, ceiling_mps2: float, can_slow: bool) -> str | None:
        """Whether the vehicle can follow the track's reference (:mod:`datt.deploy.feasibility`):
        its peak thrust ask plus ``thrust_reserve_mps2`` against ``ceiling_mps2``. A reference that
        asks for more is flown slower when ``infeasible`` is ``slow`` and ``can_slow`` (the track's
        table replaced in place: the same duration covers less of the path). Returns None (flown,
        a "thrust check" event says how) or the refusal's text."""
        steps = self._steps(track, self.p.track_s)
        if self._track_table is None:  # the reference as drawn (a second check slows the original)
            self._track_table = track.env.ref_table[0].double().numpy().copy()
        table, dt_s, gravity = self._track_table, float(track.env.dt_s), self.thrust.p.gravity_mps2
        # the TRACK phase's points (a track longer than the table holds its last), the table after them its future
        path = np.concatenate((table, np.repeat(table[-1:], max(0, steps + 1 - len(table)), axis=0)))
        ask = peak_ask(path, dt_s, self.p.thrust_window_s, gravity, points=steps + 1)
        limit = ceiling_mps2 - self.p.thrust_reserve_mps2
        text = (
            f"the reference asks for {ask.peak_mps2:.2f} m/s² of thrust (at t={ask.at_s:.2f} s, its acceleration "
            f"over deploy.flight.thrust_window_s {self.p.thrust_window_s:g} s) + {self.p.thrust_reserve_mps2:g} "
            f"reserve; the vehicle's ceiling is {ceiling_mps2:.2f} m/s² (thrust-to-weight {ceiling_mps2 / gravity:.2f})"
        )
        check = {"ask_mps2": ask.peak_mps2, "ceiling_mps2": ceiling_mps2, "reserve_mps2": self.p.thrust_reserve_mps2}
        self.summary_extra["thrust_check"] = check
        if ask.peak_mps2 <= limit:
            self._event("thrust check", f"{text}: flown")
            return None
        slow = can_slow and self.p.infeasible == "slow"
        factor = (
            slow_factor(path, dt_s, self.p.thrust_window_s, gravity, limit, self.p.max_slow_factor) if slow else None
        )
        if factor is not None:
            track.env.replace_reference(
                torch.as_tensor(slowed(table, dt_s, factor)).unsqueeze(0).to(track.env.ref_table)
            )
            check["slow_factor"] = factor
            self._event("thrust check", f"{text}: flown {factor:.2f} times slower (deploy.flight.infeasible=slow)")
            return None
        if slow:
            hint = f"not even {self.p.max_slow_factor:g} times slower (deploy.flight.max_slow_factor)"
        else:
            hint = "deploy.flight.infeasible=slow flies it slower"
        return f"{text}: not flown; {hint}, or fly a gentler traj or a stronger vehicle"

    def _note_guard(self, track: FlightModel) -> None:
        """How many TRACK commands the ceiling guard levelled (the summary's ``ceiling_guarded_ticks``)."""
        if track.guard is None:
            return
        self.summary_extra["ceiling_guarded_ticks"] = track.guarded
        if track.guarded:
            self._event(
                "ceiling guard",
                f"{track.guarded} TRACK commands at the thrust ceiling levelled the vehicle "
                "instead of tilting it further",
            )

    def _preflight(self) -> np.ndarray:
        deadline = self.clock.monotonic() + self.p.preflight_timeout_s
        state, mocap_pos = None, None
        self.link.reset_kalman()  # start the filter from this position, with the mocap stream
        while self.clock.monotonic() < deadline:  # a fresh estimate, settled, converged on mocap when there is one
            self._mocap_age()
            state = self.link.state()
            mocap_pos = self._mocap_position()
            fresh = state is not None and self.clock.monotonic() - state.t_s < self.safety.max_state_age_s
            if not fresh:
                agrees = False
            elif mocap_pos is None:  # no mocap source: nothing to agree with; a source: wait for its first frame
                agrees = not self._has_mocap()
            else:
                agrees = self._estimate_error_m(state, mocap_pos) < self.safety.max_estimate_mocap_m
            if agrees and self.link.kalman_settled():
                break
            self.clock.sleep(0.02)
        checks = self._supervisor_checks()
        if not self.link.kalman_settled():
            checks.append(
                f"Kalman filter not settled after {self.p.preflight_timeout_s:g} s (position variances still "
                "changing: is the mocap stream or the positioning deck reaching the vehicle?)"
            )
        if state is None:
            checks.append("no state estimate from the vehicle")
        else:
            age_s = self.clock.monotonic() - state.t_s
            if age_s >= self.safety.max_state_age_s:  # the log stream stopped: every check below is of the past
                checks.append(
                    f"no fresh state estimate (the last arrived {age_s * 1e3:.0f} ms ago, > "
                    f"{self.safety.max_state_age_s * 1e3:.0f} ms)"
                )
            if self._has_mocap() and mocap_pos is None:
                checks.append("no mocap frame for the vehicle")
            elif mocap_pos is not None:
                err = self._estimate_error_m(state, mocap_pos)
                limit_cm = self.safety.max_estimate_mocap_m * 100
                if err * 100 >= limit_cm:
                    checks.append(
                        f"onboard estimate {err * 100:.0f} cm from mocap (> {limit_cm:.0f} cm; is stabilizer.estimator "
                        "the Kalman filter, the mocap frame the vehicle's?)"
                    )
                lo, hi = self.safety.geofence_min_m, self.safety.geofence_max_m
                if not all(lo[i] <= mocap_pos[i] <= hi[i] for i in range(3)):
                    checks.append("mocap position outside the geofence")
            if state.vbat_v < self.p.min_battery_v:
                checks.append(f"battery {state.vbat_v:.2f} V < {self.p.min_battery_v} V")
            if tilt_deg(state.quat) > 10:
                checks.append("vehicle not level")
            lo, hi = self.safety.geofence_min_m, self.safety.geofence_max_m
            if not all(lo[i] <= state.pos_m[i] <= hi[i] for i in range(3)):
                checks.append("start position outside the geofence")
            goal = self._origin()
            if not all(lo[i] <= goal[i] <= hi[i] for i in range(3)):
                checks.append("hover point outside the geofence")
        if checks:
            self._refuse("; ".join(checks))
        self._event("preflight ok", f"battery {state.vbat_v:.2f} V")
        return np.array(state.pos_m)

    def _mocap_position(self) -> np.ndarray | None:
        sample = self.mocap.read() if self._has_mocap() else None
        return None if sample is None else np.array(sample[0], dtype=float)

    @staticmethod
    def _estimate_error_m(state, mocap_pos: np.ndarray) -> float:
        return float(np.linalg.norm(np.array(state.pos_m) - mocap_pos))

    def _supervisor_checks(self) -> list[str]:
        bits = self.link.supervisor_bits()
        checks = []
        if bits & firmware.SUPERVISOR_BIT_LOCKED:
            checks.append("vehicle locked (an emergency stop or watchdog timeout earlier): restart it")
        if bits & (firmware.SUPERVISOR_BIT_CRASHED | firmware.SUPERVISOR_BIT_TUMBLED):
            checks.append("vehicle crashed or tumbled")
        return checks

    def _check_reference_in_geofence(self, model: FlightModel, duration_s: float | None) -> None:
        """Refuse before arming a reference that would leave the geofence (it would be KILLed mid-air)."""
        path = self._held_table(model, self._steps(model, duration_s) + 1) + self._origin()
        lo, hi = np.asarray(self.safety.geofence_min_m), np.asarray(self.safety.geofence_max_m)
        outside = np.nonzero(((path < lo) | (path > hi)).any(axis=1))[0]
        if len(outside):
            k = int(outside[0])
            axis = int(np.nonzero((path[k] < lo) | (path[k] > hi))[0][0])
            bound = "geofence_min_m" if path[k, axis] < lo[axis] else "geofence_max_m"
            self._refuse(
                f"deploy.safety.{bound}: the reference leaves the geofence at "
                f"t={k / self.p.rate_hz:.2f} s ({'xyz'[axis]}={path[k, axis]:.2f} m; "
                f"fence {lo[axis]:.2f}..{hi[axis]:.2f} m)"
            )

    def _act(self, model: FlightModel, state, now: float, origin: np.ndarray, k: int, predict: bool) -> np.ndarray:
        """The controller's command for a finite measured ``state`` (world frame; the model flies
        relative to ``origin``), seen through the latency predictor when ``predict``, plus the
        calibration's thrust excitation at tick ``k``. The estimate the last command already answered
        (no fresh one came this tick) gets that command again (:meth:`FlightModel.hold`)."""
        if state.t_s == model.last_state_t:
            action = model.hold()
        else:
            model.last_state_t = state.t_s
            action = self._answer(model, state, now, origin, predict)
        if self._excitation is not None:
            action[0] += self._excitation(k)
        return action

    def _answer(self, model: FlightModel, state, now: float, origin: np.ndarray, predict: bool) -> np.ndarray:
        """The controller's command for a fresh ``state``, through the predictor when ``predict``."""
        predicted, lead_steps = None, 0.0
        if predict:
            p, v, q = self.predictor.predict(
                now, state.t_s, state.pos_m, state.vel_mps, state.quat, model.d_hat, state.vehicle_s
            )
            predicted = (np.array(p) - origin, v, q)
            lead_steps = self.predictor.lead_at(now) * self.p.rate_hz
        return model.act(np.array(state.pos_m) - origin, state.vel_mps, state.quat, predicted, lead_steps)

    def _send_tick(self, model: FlightModel, action) -> int:
        """Send the tick's command (and the e-stop watchdog); the predictor records what was sent.
        Returns the thrust command sent."""
        command = self._send(action)
        if self.predictor is not None:  # what was sent: a command clipped at the map's ceiling gives less
            self.predictor.record(self.clock.monotonic(), self.thrust.as_sent(*(float(a) for a in action[:4])))
        if self.p.estop_watchdog and self.sends_estop_watchdog:
            self.link.send_estop_watchdog()
        return command

    def _act_on(self, decision, jitter_ms: float, allow_land: bool) -> str | None:
        """The safety decision's effect on this tick: KILL or LAND ends the phase (returned), a LAND
        while already landing is noted and the landing goes on (None)."""
        if decision.action != OK and jitter_ms > self.p.late_tick_ms:
            # a stalled host sees stale state and mocap: say so beside the decision it caused
            self._event("warning", f"this tick ran {jitter_ms:.0f} ms behind schedule (the host stalled)")
        if decision.action == KILL:
            self._kill(decision.reason)
            return KILL
        if decision.action == LAND and allow_land:
            self._event("LAND", decision.reason)
            return LAND
        if decision.action == LAND:  # already landing: keep landing, note why
            self._event("warning", decision.reason)
        return None

    def _tick_loop(self, model: FlightModel, steps: int, origin: np.ndarray, allow_land: bool = True) -> str:
        dt = 1.0 / self.p.rate_hz
        next_t = self.clock.monotonic()
        used_t = -math.inf  # arrival of the estimate the last tick used
        # the predictor serves the tracking controller; the PID (takeoff, hover and its trim, landing,
        # the calibration) flies the raw loop it was tuned on
        predict = self.predictor is not None and self.phase == "TRACK"
        for k in range(steps):
            scheduled = next_t
            jitter_ms = (self.clock.monotonic() - scheduled) * 1e3
            # the tick runs on a fresh estimate: wait (at most one log period) for one newer than the last
            self.link.wait_state_after(used_t, self.link.log_period_ms / 1000.0)
            now = self.clock.monotonic()
            state = self.link.state()
            if state is not None:  # the decision sees the low-passed voltage (the log keeps the raw one)
                state_for_check = dataclasses.replace(state, vbat_v=self.battery.update(state.vbat_v, dt))
            else:
                state_for_check = None
            mocap_age = self._mocap_age()
            action = None
            if state is not None and all(math.isfinite(v) for v in (*state.pos_m, *state.vel_mps, *state.quat)):
                used_t = state.t_s
                action = self._act(model, state, now, origin, k, predict)
            decision = check(
                self.safety,
                now_s=self.clock.monotonic(),
                state=state_for_check,
                command=action,
                estop=self.estop.is_set(),
                link_lost=self.link.link_lost.is_set(),
                mocap_age_s=mocap_age,
                tracking=self.phase == "TRACK",
                reference_z_m=float(model.reference()[2] + origin[2]),
            )
            ended = self._act_on(decision, jitter_ms, allow_land)
            if ended is not None:
                return ended
            command = self._send_tick(model, action)
            self._record(model, state, origin, action, command, decision, now, scheduled, jitter_ms)
            model.advance()
            next_t += dt
            if predict and k == 0:  # commands land mid-way between vehicle ticks (from the schedule: late stays late)
                next_t = self.predictor.send_slot(next_t - dt / 2)
            self.clock.sleep(max(0.0, next_t - self.clock.monotonic()))
        return OK

    def _record(
        self, model: FlightModel, state, origin, action, command: int, decision, now, scheduled, jitter_ms
    ) -> None:
        """One flight-log row: the tick's estimate, reference, command and timing (flight-log times)."""
        self.rows.append(
            {
                "t_s": now - self.log.t0,
                "sched_t_s": scheduled - self.log.t0,  # when this tick's reference point is due
                "arrived_s": state.t_s - self.log.t0,  # the estimate: its arrival, its vehicle stamp
                "vehicle_s": state.vehicle_s,
                "phase": self.phase,
                "pos": list(state.pos_m),
                "vel": list(state.vel_mps),
                "quat": list(state.quat),
                "ref": list(model.reference() + origin),
                "action": [float(a) for a in action],
                "thrust_cmd": command,
                "d_hat": list(model.d_hat),
                "vbat": state.vbat_v,
                "decision": decision.action,
                "jitter_ms": jitter_ms,
                "compute_ms": (self.clock.monotonic() - now) * 1e3,
            }
        )

    def _lifted_off(self, phase: str) -> bool:
        """Whether ``phase`` (the takeoff, or the hover after it) ended at least half of
        ``takeoff_height_m`` up (the ground is z = 0); if not, a LAND event says so. A vehicle on
        the ground would otherwise have the hover trim read a hover command off the floor and
        TRACK start there."""
        rows = [r for r in self.rows if r["phase"] == phase]
        height_m = rows[-1]["pos"][2] if rows else 0.0
        if height_m >= 0.5 * self.p.takeoff_height_m:
            return True
        top = max((r["thrust_cmd"] for r in rows), default=0)
        ended = (
            f"the {phase.lower()} ended at z {round(height_m, 2) + 0.0:.2f} m "  # + 0.0: no -0.00
            f"(hover at {self.p.takeoff_height_m:g} m) with commands up to {top}"
        )
        if phase == "TAKEOFF":
            why = "the vehicle did not lift off: " + ended + "; the firmware's thrust lock (no setpoint with thrust 0 "
            why += "arrived after arming), or motors and propellers"
        else:
            why = "the vehicle could not hold its hover: " + ended + "; it needs more thrust than it has "
            why += "(deploy.thrust.mass_kg, the battery, the motors)"
        self._event("LAND", why)
        return False

    def _trim(self, phase: str, models: list[FlightModel], final: bool) -> str:
        """Hover trim (``deploy.flight.hover_trim``): rescale the thrust map so that it passes
        through the command the hover just flown in ``phase`` needed
        (:func:`~datt.deploy.thrust.hover_command_from_hover` over its last
        ``hover_trim_window_s``); the ``models`` still to fly get the new ceiling. The ``final``
        trim (the one TRACK flies) more than ``hover_trim_max`` from the configured map (a wrong
        ``deploy.thrust.mass_kg``, a flat battery) is not flown: LAND. An earlier pass, measured on
        the configured map while the PID may still be saturated, is only clamped to
        ``hover_trim_max``: HOVER flies it and measures again. Returns OK or LAND."""
        n = max(2, int(round(self.p.hover_trim_window_s * self.p.rate_hz)))
        hover = [r for r in self.rows if r["phase"] == phase][-n:]
        lag_s = self._trim_lag_s()
        t_s = [r["t_s"] for r in hover]
        sent_t_s, sent = [r["t_s"] for r in self.rows], [r["thrust_cmd"] for r in self.rows]
        measured = hover_command_from_hover(
            t_s, [r["vel"][2] for r in hover], commands_acting(t_s, sent_t_s, sent, lag_s), self.thrust.p.gravity_mps2
        )
        text = (
            f"the hover needed command {measured:.0f} (commands {lag_s * 1e3:.0f} ms before the velocities), "
            f"the thrust map {self.thrust.hover_command:.0f}"
        )
        change = measured / self.configured_hover_command - 1.0
        if not final and math.isfinite(change) and abs(change) > self.p.hover_trim_max:
            # a rough first pass: fly HOVER at the limit and let the steadier second pass decide
            raw, change = change, math.copysign(self.p.hover_trim_max, change)
            text += f" ({100 * raw:+.0f} % from deploy.thrust, clamped to {100 * change:+.0f} %: HOVER measures again)"
            measured = self.configured_hover_command * (1.0 + change)
        scale = measured / self.thrust.hover_command
        if not abs(change) <= self.p.hover_trim_max:
            self._event(
                "LAND",
                f"{text} ({100 * change:+.0f} % from deploy.thrust), beyond deploy.flight.hover_trim_max "
                f"({100 * self.p.hover_trim_max:.0f} %); check deploy.thrust.mass_kg and the battery, or calibrate",
            )
            return LAND
        self.thrust.rescale(scale)
        for model in models:
            model.set_thrust_ceiling(self.thrust.ceiling_mps2)
        self._event("trim", f"{text}: map rescaled by {100 * (scale - 1):+.1f} %", hover_command=measured)
        return OK

    def _trim_lag_s(self) -> float:
        """``deploy.flight.hover_trim_lag_s``, or null: the measured radio round trip (the estimate's
        way up, the command's way down) + one control tick (the vehicle's actuation)."""
        if self.p.hover_trim_lag_s is not None:
            return float(self.p.hover_trim_lag_s)
        round_trip = self.link.round_trip_s if math.isfinite(self.link.round_trip_s) else 0.0
        return round_trip + 1.0 / self.p.rate_hz

    def _ceiling_guard(self):
        """:func:`keep_altitude_at_ceiling` with ``deploy.flight.ceiling_*`` and the thrust map's
        gravity bound, or None when ``deploy.flight.ceiling_guard`` is off."""
        if not self.p.ceiling_guard:
            return None
        return functools.partial(
            keep_altitude_at_ceiling,
            gravity_mps2=self.thrust.p.gravity_mps2,
            climb_reserve_mps2=self.p.ceiling_climb_reserve_mps2,
            level_gain_per_s=self.p.ceiling_level_gain_per_s,
        )

    def _model(self, controller, family: RefFamily) -> FlightModel:
        model = FlightModel(self.make_env, controller, family, self.thrust.ceiling_mps2, self._ceiling_guard())
        model.act([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])  # warm-up (traces the policy)
        model.env.reset()
        controller.reset(model.env)
        model.last_cmd = model.env.hover_action.clone()
        return model

    def _fly_phase(self, model: FlightModel, duration_s: float | None, origin: np.ndarray) -> str:
        result = self._tick_loop(model, self._steps(model, duration_s), origin)
        if result == LAND:
            self._land(origin)
        return result

    def _steps(self, model: FlightModel, duration_s: float | None) -> int:
        """Control ticks of a phase lasting ``duration_s``; None = the reference's episode
        (``env.episode_steps`` steps)."""
        duration = model.env.params.episode_steps * model.env.dt_s if duration_s is None else float(duration_s)
        return int(round(duration * self.p.rate_hz))

    @staticmethod
    def _held_table(model: FlightModel, points: int) -> np.ndarray:
        """The first ``points`` points of the reference table (controller frame, ``[points, 3]``);
        a flight longer than the table holds its last point, as the flight model does."""
        table = model.env.ref_table[0, :points].double().numpy()
        if len(table) < points:
            table = np.concatenate((table, np.repeat(table[-1:], points - len(table), axis=0)))
        return table

    def _land(self, origin: np.ndarray, refused: str | None = None) -> None:
        """LAND with the PID from where the vehicle is; ``refused``: the thrust check's refusal
        (the outcome: landed without tracking)."""
        self._set_phase("LAND")
        state = self.link.state()
        here = (np.array(state.pos_m) if state is not None else origin) - origin
        ground = np.array([here[0], here[1], -origin[2] + 0.05])
        model = self._model(self.pid_factory(), Ramp(here, ground, self.p.land_s))
        result = self._tick_loop(model, int((self.p.land_s + 0.5) * self.p.rate_hz), origin, allow_land=False)
        if result == OK:
            self.link.send_rates(0.0, 0.0, 0.0, 0)
            reasons = [e["text"] for e in self.events if e["kind"] == "LAND"]
            if refused is not None:
                self.outcome = Outcome(Kind.REFUSED_REFERENCE, refused)
            else:
                self.outcome = Outcome(Kind.LANDED_EARLY, reasons[0]) if reasons else Outcome(Kind.LANDED)

    # -- records ---------------------------------------------------------------------------
    def _track_errors(self) -> list[float]:
        """‖estimate − reference‖ of each TRACK tick, the reference at the time the estimate was
        measured (:func:`~datt.deploy.flight_log.errors_when_measured`; the onboard flight: the
        app's own per-step error, both of one instant)."""
        return errors_when_measured(self._track_rows())

    def _received_errors(self) -> list[float]:
        """‖estimate − reference‖ of each TRACK tick, the tick's own reference point (the estimate
        an up-link old): what ``track_error_m`` was before it took the reference when measured."""
        return [float(np.linalg.norm(np.array(r["pos"]) - np.array(r["ref"]))) for r in self._track_rows()]

    def _track_rows(self) -> list[dict]:
        return [r for r in self.rows if r["phase"] == "TRACK"]

    def _write(self) -> dict:
        for row, t in zip(self.rows, measured_at(self.rows, self.link.round_trip_s)):
            row["state_t_s"] = t
        err = self._track_errors()
        received = self._received_errors()
        summary = {
            "outcome": self.outcome.text,
            "outcome_kind": self.outcome.kind.value,
            "track_steps": len(err),
            "track_error_m": float(np.mean(err)) if err else None,
            "track_error_received_m": float(np.mean(received)) if received else None,
            **self.summary_extra,
        }
        return self.log.write(summary, self._track_rows())


class _Abort(RuntimeError):
    pass
