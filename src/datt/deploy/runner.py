"""Flight state machine: CONNECT -> PREFLIGHT -> ARM -> TAKEOFF -> TRACK -> LAND -> DISARM.

Every tick (``rate_hz``, 50 by default) the runner reads the onboard estimate from the link,
forwards the mocap position, asks :mod:`datt.deploy.safety` for OK / LAND / KILL, computes the
phase's controller output and sends it as a rate setpoint (thrust through
:mod:`datt.deploy.thrust`). TAKEOFF and LAND fly the PID baseline along a straight ramp; TRACK
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

import csv
import dataclasses
import json
import math
import signal
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from datt.configuration import FINITE, NON_NEGATIVE, POSITIVE, Range, check_ranges, ranged
from datt.deploy import firmware, onboard
from datt.deploy.safety import KILL, LAND, OK, BatteryFilter, SafetyParams, check, tilt_deg
from datt.deploy.thrust import ThrustMap
from datt.errors import LinkError
from datt.refs.base import RefFamily
from datt.runs import stop_signals


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


APP_STALL_S = 0.3  # onboard: the app's step counter still this long while it should fly: the host takes over
PRE_ARM_PHASES = ("CONNECT", "PREFLIGHT")  # a stop here ends the flight with nothing armed
LINK_LOST = "LINK_LOST"  # onboard flights: the host lost the vehicle while the app flew on


class FlightModel:
    """A controller flying from measurements: a one-drone env whose state is set each tick."""

    def __init__(self, make_env, controller, family: RefFamily, thrust_ceiling_mps2: float = math.inf) -> None:
        self.env = make_env(family)
        # the thrust map clips at max_command: the adaptation and the history get what is sent
        self.command_high = self.env.command_high.clone()
        self.command_high[0] = min(float(self.command_high[0]), thrust_ceiling_mps2)
        self.controller = controller
        self.env.reset()
        controller.reset(self.env)
        self.last_cmd = self.env.hover_action.clone()

    def act(self, pos_m, vel_mps, quat) -> np.ndarray:
        self.env.set_state(pos_m, vel_mps, quat)
        self.env.adaptation.update(self.env.sim.state, self.last_cmd, None)
        td = None if self.controller.builds_observation else self.env.observe()
        action = self.controller.act(self.env, td)
        cmd = torch.clamp(action, self.env.action_low, self.command_high)
        self.env.sim.latency.push(cmd)  # model-based controllers see the command in flight
        self.env.record_command(cmd)  # policies with obs.action_history see the commands sent
        self.last_cmd = cmd
        return cmd[0].detach().numpy().astype(float)  # as the env would apply it (NaN stays NaN)

    def reference(self) -> np.ndarray:
        return self.env.reference_now_m()[0].numpy().astype(float)

    def advance(self) -> None:
        self.env.advance_reference()

    @property
    def d_hat(self) -> np.ndarray:
        return self.env.adaptation.d_hat[0].numpy().astype(float)


@dataclass
class FlightParams:
    rate_hz: float = ranged(50.0, POSITIVE)
    takeoff_height_m: float = ranged(1.0, POSITIVE)
    takeoff_s: float = ranged(2.5, POSITIVE)
    hover_s: float = ranged(1.0, NON_NEGATIVE)
    track_s: float | None = ranged(None, Range(0.0, low_open=True, optional=True))  # None = the env's episode
    land_s: float = ranged(2.5, POSITIVE)
    preflight_timeout_s: float = ranged(3.0, POSITIVE)
    arm_timeout_s: float = ranged(1.0, POSITIVE)  # the supervisor must report "armed" within this
    min_battery_v: float = ranged(3.7, NON_NEGATIVE)
    late_tick_ms: float = ranged(5.0, POSITIVE)
    estop_watchdog: bool = True  # send the firmware's e-stop watchdog every tick (motors off 1 s after the last)
    origin_m: list = ranged([0.0, 0.0], FINITE)  # hover point x, y (z = takeoff_height_m)
    onboard_max_pos_std_m: float = ranged(0.1, NON_NEGATIVE)  # deploy.onboard: the app lands above this (0: never)

    def validate(self) -> None:
        from datt.errors import ConfigError

        check_ranges(self, "deploy.flight")
        if len(self.origin_m) != 2:
            raise ConfigError(f"deploy.flight.origin_m: need 2 values (x, y), got {self.origin_m!r}")


class FlightRunner:
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
        onboard: bool = False,
        onboard_policy_id: int | None = None,
        stop_request=None,
        summary_extra: dict | None = None,
    ) -> None:
        self.link, self.mocap = link, mocap
        self.make_env, self.track_controller, self.pid_factory = make_env, track_controller, pid_factory
        self.track_family = track_family
        self.p, self.safety, self.thrust = params, safety, thrust
        self.run_dir = Path(run_dir)
        self.estop = estop or threading.Event()
        self.console = console
        self.rows: list[dict] = []
        self.events: list[dict] = []
        self.phase = "CONNECT"
        self.t0 = time.monotonic()
        self.outcome = "incomplete"
        self.battery = BatteryFilter(safety.battery_filter_s)
        self._mocap_sent_t: float | None = None  # time stamp of the last mocap sample forwarded
        self._excitation = None  # calibration: extra thrust (m/s²) as a function of the tick index
        self.onboard = onboard  # TRACK runs in the vehicle's DATT app (datt.deploy.onboard)
        self._app: dict = {"samples": {}, "last": None}  # the app's log: step -> its error, latest values
        self._onboard_steps = 0  # TRACK steps the app flies (set when the reference is uploaded)
        self.onboard_policy_id = onboard_policy_id  # the app must carry this policy (datt.export.c_code.policy_id)
        self.stop_request = stop_request  # datt.runs.StopRequest active while the flight was prepared
        self.upload_s: float | None = None  # onboard: the reference upload's duration
        self.summary_extra = dict(summary_extra or {})  # recorded in events.json with the summary

    # -- helpers ---------------------------------------------------------------------------
    def _event(self, kind: str, text: str = "", **extra) -> None:
        item = {"t_s": round(time.monotonic() - self.t0, 4), "phase": self.phase, "kind": kind, "text": text, **extra}
        self.events.append(item)
        if self.console is not None:
            self.console.print(f"[{item['t_s']:7.2f} s] {self.phase:8s} {kind}: {text}")

    def _set_phase(self, phase: str) -> None:
        self.phase = phase
        self._event("phase", phase)

    def _origin(self) -> np.ndarray:
        return np.array([self.p.origin_m[0], self.p.origin_m[1], self.p.takeoff_height_m])

    def _has_mocap(self) -> bool:
        return self.mocap is not None and self.mocap.name != "none"

    def _mocap_age(self) -> float | None:
        """Forward the mocap sample to the vehicle if it is new and not older than
        ``safety.max_mocap_age_s`` (the Kalman filter takes every packet as a fresh measurement:
        resending an old sample would pin the estimate where the vehicle was); return its age."""
        if not self._has_mocap():
            return None
        sample = self.mocap.read()
        if sample is None:
            return math.inf
        pos, quat, t = sample
        age = time.monotonic() - t
        if t != self._mocap_sent_t and age <= self.safety.max_mocap_age_s:
            if quat is None:
                self.link.send_extpos(pos)
            else:
                self.link.send_extpose(pos, quat)
            self._mocap_sent_t = t
        return age

    def _send(self, action) -> int:
        roll, pitch, yaw = self.thrust.rates_deg(float(action[1]), float(action[2]), float(action[3]))
        command = self.thrust.command(float(action[0]))
        self.link.send_rates(roll, pitch, yaw, command)
        return command

    def _refuse(self, outcome: str) -> None:
        """End the flight before arming: ``outcome`` (a "preflight failed: ..." line) is logged
        and becomes the flight's outcome."""
        self.outcome = outcome
        self._event("preflight failed", outcome)
        raise _Abort(outcome)

    def _kill(self, reason: str) -> None:
        self.link.emergency_stop()  # first, before logging or anything else
        self._event("KILL", reason)
        self.outcome = f"killed: {reason}"

    # -- flight ----------------------------------------------------------------------------
    def _flight(self, build, airborne) -> dict:
        """CONNECT -> PREFLIGHT -> ``build(start)`` -> ARM -> ``airborne(origin, built)`` -> DISARM;
        the flight log is written whatever happens. Models are built (and the policy traced)
        before the motors spin, so nothing stalls the control loop mid-flight. A stop request
        before arming (also one made while the flight was being prepared: ``stop_request``) ends
        the flight unarmed; after arming it KILLs."""
        try:
            with stop_signals(_raise_interrupt):
                self._stop_if_requested()
                self._set_phase("CONNECT")
                self.link.connect(external_position=self._has_mocap())
                if self.mocap is not None:
                    self.mocap.start()
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
            self.outcome = f"link lost: {exc}"
            self._event("link lost", str(exc))
            if self.phase not in PRE_ARM_PHASES:
                self._kill(str(exc))
        finally:
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
        self.outcome = f"stopped before arming ({why}): nothing was armed"
        self._event("stopped", self.outcome)

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
            self.outcome = f"arming failed: {why} (supervisor.info); nothing flew"
            self._event("arming failed", self.outcome)
            raise _Abort(self.outcome)
        self._event("armed", "the supervisor reports the vehicle armed")
        self.link.send_rates(0.0, 0.0, 0.0, 0)  # unlocks the firmware's thrust lock

    def _takeoff(self, start_rel: np.ndarray) -> tuple:
        model = self._model(self.pid_factory(), Ramp(start_rel, [0.0, 0.0, 0.0], self.p.takeoff_s))
        return ("TAKEOFF", model, self.p.takeoff_s + self.p.hover_s)

    def fly(self) -> dict:
        """Takeoff, track the reference with the configured controller, land."""

        def build(start_rel):
            track = self._model(self.track_controller, self.track_family)
            self._check_reference_in_geofence(track, self.p.track_s)
            return [self._takeoff(start_rel), ("TRACK", track, self.p.track_s)]

        def airborne(origin, phases):
            for name, model, duration in phases:
                self._set_phase(name)
                if self._fly_phase(model, duration, origin) != OK:
                    return  # killed, or already landed
            self._land(origin)

        return self._flight(build, airborne)

    def fly_onboard(self) -> dict:
        """Takeoff (PID, off-board), then the vehicle's DATT app tracks the reference and lands
        by itself: the reference is uploaded before arming, ``datt.run = 1`` hands it the flight,
        and the host only streams mocap and watches (KILL on a safety breach; a LAND decision
        stops the app and lands with the PID). A lost link leaves the app flying to the end."""

        def build(start_rel):
            track = self._model(self.track_controller, self.track_family)
            self._check_reference_in_geofence(track, self.p.track_s)
            self._onboard_prepare(track)
            return self._takeoff(start_rel)

        def airborne(origin, takeoff):
            name, model, duration = takeoff
            self._set_phase(name)
            if self._fly_phase(model, duration, origin) != OK:
                return
            self._set_phase("TRACK")
            result = self._onboard_track(origin)
            if result == LAND:
                self._land(origin)
            elif result == OK:
                self.link.send_rates(0.0, 0.0, 0.0, 0)
                self.outcome = "landed (onboard)"

        return self._flight(build, airborne)

    def _onboard_track_steps(self, model: FlightModel) -> int:
        duration = self._duration_s(model, self.p.track_s)
        return int(round(duration * self.p.rate_hz))

    def _onboard_prepare(self, track: FlightModel) -> None:
        """Check the app is there, select its controller hook, set its parameters, upload the
        reference (controller frame) and follow its log."""
        if not self.link.has_param("datt.run"):
            self._refuse(
                "preflight failed: deploy.onboard: the vehicle's firmware has no DATT app (no parameter datt.run): "
                "build and flash it (datt export format=app; docs/onboard.md), or fly off-board (deploy.onboard=false)"
            )
        if self.onboard_policy_id is not None:
            carried = int(self.link.read_param("datt.policyId"))
            if carried != self.onboard_policy_id:
                self._refuse(
                    f"preflight failed: deploy.onboard: the vehicle's app carries policy {carried:#010x}, the "
                    f"checkpoint is {self.onboard_policy_id:#010x}: flash the app exported from it "
                    "(datt export format=app checkpoint=...), or pass the checkpoint the app was built from"
                )
        steps = self._onboard_track_steps(track)
        env = track.env
        table = env.ref_table[0, : min(steps + env.window, env.table_len)].double().numpy()
        if len(table) <= steps:  # a track longer than the reference: hold its last point, as off-board
            table = np.concatenate((table, np.repeat(table[-1:], steps + 1 - len(table), axis=0)))
        if len(table) > onboard.TABLE_MAX:
            self._refuse(
                f"preflight failed: deploy.flight.track_s: the app holds {onboard.TABLE_MAX} reference points "
                f"({(onboard.TABLE_MAX - env.window) / self.p.rate_hz:.1f} s of track at {self.p.rate_hz:g} Hz); "
                f"this track needs {len(table)}"
            )
        origin = self._origin()
        values = {
            "originX": origin[0],
            "originY": origin[1],
            "originZ": origin[2],
            "nPoints": len(table),
            "trackSteps": steps,
            "landZ": -origin[2] + 0.05,
            "landS": self.p.land_s,
            "landHoldS": 0.5,
            "hoverCmd": self.thrust.hover_command,
            "slope": self.thrust.slope,
            "maxCmd": self.thrust.p.max_command,
            "maxRateRoll": self.thrust.p.max_rate_degps[0],
            "maxRatePitch": self.thrust.p.max_rate_degps[1],
            "maxRateYaw": self.thrust.p.max_rate_degps[2],
            "maxTiltDeg": self.safety.max_tilt_deg,
            "maxPosStdM": self.p.onboard_max_pos_std_m,
        }
        controller = self._app_controller_id()
        try:  # every setting the onboard flight depends on, read back fresh
            self.link.set_params_checked({"datt.run": 0, **{f"datt.{name}": value for name, value in values.items()}})
            self.link.set_param_checked(str(firmware.fact("param_controller")), controller)
        except LinkError as exc:
            self._refuse(f"preflight failed: deploy.onboard: {str(exc).removeprefix('connect: ')}")
        self._event("onboard", f"stabilizer.controller = {controller} (the app's out-of-tree controller), read back")
        upload = onboard.Upload(self.link.send_app_packet, table)
        self.link.on_app_packet(upload.on_packet)
        started = time.monotonic()
        try:
            upload.run()
        except RuntimeError as exc:
            self._refuse(f"preflight failed: the reference upload to the app failed: {exc}")
        self.upload_s = time.monotonic() - started
        self._event("onboard", f"reference uploaded: {len(table)} points in {self.upload_s:.2f} s")
        self._onboard_steps = steps
        self.link.log_block("datt", onboard.LOG_BLOCK, self.link.log_period_ms, self._on_app_log)

    def _app_controller_id(self) -> int:
        """The controller id the app's hook runs under, as the app publishes it
        (``datt.controllerId``: ``ControllerTypeOot`` of the firmware it was built into)."""
        if not self.link.has_param("datt.controllerId"):
            self._refuse(
                "preflight failed: deploy.onboard: the vehicle's app does not publish datt.controllerId (built by an "
                "older datt export): rebuild and flash it (datt export format=app; docs/onboard.md)"
            )
        controller = int(self.link.read_param("datt.controllerId"))
        if controller != firmware.CONTROLLER_OOT:
            self._event(
                "warning",
                f"the app runs under controller {controller}, the host's table ({firmware.FIRMWARE_VERSION}) says "
                f"{firmware.CONTROLLER_OOT}: that firmware numbers its controllers otherwise; the app's id is used",
            )
        return controller

    def _on_app_log(self, values: dict) -> None:
        phase, step = int(values["datt.phase"]), int(values["datt.step"])
        ref = (values["datt.refX"], values["datt.refY"], values["datt.refZ"])
        self._app["last"] = (phase, step, ref, time.monotonic())
        if phase in (onboard.TRACK, onboard.LAND, onboard.DONE) and step > 0:
            # datt.errM / datt.ref* belong to the step before datt.step (the app counts after stepping)
            self._app["samples"][step - 1] = float(values["datt.errM"])

    def _onboard_track(self, origin: np.ndarray) -> str:
        """Hand the flight to the app and watch until it has landed (or the time it needs has
        passed). Returns OK (the app landed), LAND (stopped: the host lands) or KILL."""
        self.link.set_param_checked("datt.run", 1)
        dt = 1.0 / self.p.rate_hz
        budget_s = self._onboard_steps * dt + self.p.land_s + 0.5 + 2.0
        deadline = time.monotonic() + budget_s
        quiet = False
        stepping = [-1, time.monotonic()]  # the app's last step seen, and when it changed
        next_t = time.monotonic()
        while time.monotonic() < deadline:
            now = time.monotonic()
            state = self.link.state()
            mocap_age = self._mocap_age()
            last = self._app["last"]
            phase = last[0] if last is not None else onboard.IDLE
            if phase == onboard.REFUSED:
                self._event("LAND", "the app refused to start (table incomplete or a parameter invalid)")
                self.link.set_param("datt.run", 0)
                return LAND
            if phase == onboard.ABORTED:  # the app holds the motors off (stop setpoints) until datt.run = 0
                self.outcome = "killed: the onboard app aborted (tilt or a non-finite state/action), motors stopped"
                self._event("KILL", self.outcome)
                return KILL
            if phase == onboard.DONE:
                self.link.set_param("datt.run", 0)
                self._event("onboard", "the app has landed")
                return OK
            if last is not None and phase in (onboard.TRACK, onboard.LAND):
                if last[1] != stepping[0]:
                    stepping[:] = [last[1], now]
                elif now - stepping[1] > APP_STALL_S and not self.link.link_lost.is_set():
                    self._event("LAND", f"the app stopped stepping at step {last[1]} (its state is stale: no hook)")
                    self.link.set_param("datt.run", 0)  # the commander back to the radio's setpoints
                    return LAND
            fresh = state is not None and now - state.t_s < self.safety.max_state_age_s
            if self.link.link_lost.is_set() or not fresh:
                if not quiet:  # nothing the host can do: the app flies on by itself
                    self._event("warning", "no fresh state from the vehicle: the onboard app flies on")
                    quiet = True
            else:
                quiet = False
                state_for_check = dataclasses.replace(state, vbat_v=self.battery.update(state.vbat_v, dt))
                decision = check(
                    self.safety,
                    now_s=now,
                    state=state_for_check,
                    command=None,
                    estop=self.estop.is_set(),
                    link_lost=False,
                    mocap_age_s=mocap_age,
                )
                if decision.action == KILL:
                    self._kill(decision.reason)
                    return KILL
                if decision.action == LAND:
                    self._event("LAND", decision.reason)
                    self.link.set_param("datt.run", 0)  # the app hands the commander back
                    return LAND
                ref = np.array(last[2]) + origin if last is not None else np.full(3, np.nan)
                self.rows.append(
                    {
                        "t_s": now - self.t0,
                        "phase": "TRACK" if phase != onboard.LAND else "LAND",
                        "pos": list(state.pos_m),
                        "vel": list(state.vel_mps),
                        "quat": list(state.quat),
                        "ref": list(ref),
                        "action": [math.nan] * 4,  # computed onboard
                        "thrust_cmd": 0,
                        "d_hat": [math.nan] * 3,
                        "vbat": state.vbat_v,
                        "decision": decision.action,
                        "jitter_ms": (now - next_t) * 1e3,
                        "compute_ms": 0.0,
                    }
                )
            next_t += dt
            time.sleep(max(0.0, next_t - time.monotonic()))
        state = self.link.state()
        if self.link.link_lost.is_set() or state is None or time.monotonic() - state.t_s > self.safety.max_state_age_s:
            # an e-stop could not arrive, and would drop a vehicle that may still be flying well
            self.outcome = (
                "link lost during the onboard flight: the app flew on by itself; the host cannot confirm it landed"
            )
            self._event("warning", self.outcome)
            return LINK_LOST
        self._event("LAND", f"the app did not report landing within {budget_s:.1f} s")
        self.link.set_param("datt.run", 0)
        return LAND

    def calibrate(self, hover_s: float = 4.0, excitation_mps2: float = 1.0) -> dict:
        """Hover calibration flight: takeoff, then hold the hover point with the PID while a slow
        square wave of ±``excitation_mps2`` is added to its thrust. From the logged velocity:
        the loop's response latency (ticks from a command to the state showing its effect,
        :func:`~datt.deploy.thrust.response_lag_ticks`), then, with the commands shifted by it,
        the command at which the vertical acceleration is zero and the slope of acceleration
        against command (:func:`~datt.deploy.thrust.fit_hover`); then land. Returns the summary
        with ``calibration`` = ``{hover_command, slope_mps2_per_command, response_latency_ms}``
        (set the first two as ``deploy.thrust.*``)."""
        from datt.deploy.thrust import fit_hover, response_lag_ticks

        fitted = {}

        def build(start_rel):
            return self._takeoff(start_rel), self._model(self.pid_factory(), Ramp([0.0] * 3, [0.0] * 3, 1.0))

        def airborne(origin, built):
            (name, takeoff, duration), hold = built
            self._set_phase(name)
            if self._fly_phase(takeoff, duration, origin) != OK:
                return
            self._set_phase("CALIBRATE")
            half_period = int(self.p.rate_hz / 2)
            self._excitation = lambda k: excitation_mps2 * self._square(k, half_period)
            first = len(self.rows)
            result = self._tick_loop(hold, int(hover_s * self.p.rate_hz), origin)
            self._excitation = None
            if result == OK:
                rows = self.rows[first:]
                acc = list(np.diff([r["vel"][2] for r in rows]) * self.p.rate_hz)
                lag = response_lag_ticks([self._square(k, half_period) for k in range(len(acc))], acc)
                shift = int(round(lag))
                cmds = [float(r["thrust_cmd"]) for r in rows[: len(acc) - shift]]
                hover, slope = fit_hover(cmds, acc[shift:])
                latency_ms = lag / self.p.rate_hz * 1000.0
                fitted.update(hover_command=hover, slope_mps2_per_command=slope, response_latency_ms=latency_ms)
                self._event(
                    "calibrated",
                    f"hover command {hover:.0f}, slope {slope:.3e} m/s² per unit, "
                    f"command-to-response latency {latency_ms:.0f} ms",
                )
            if result != KILL:
                self._land(origin)

        summary = self._flight(build, airborne)
        summary["calibration"] = fitted or None
        return summary

    @staticmethod
    def _square(k: int, half_period: int) -> float:
        return 1.0 if (k // half_period) % 2 else -1.0

    def _preflight(self) -> np.ndarray:
        deadline = time.monotonic() + self.p.preflight_timeout_s
        state, mocap_pos = None, None
        self.link.reset_kalman()  # start the filter from this position, with the mocap stream
        while time.monotonic() < deadline:  # a fresh estimate, settled, converged on mocap when there is one
            self._mocap_age()
            state = self.link.state()
            mocap_pos = self._mocap_position()
            fresh = state is not None and time.monotonic() - state.t_s < self.safety.max_state_age_s
            if not fresh:
                agrees = False
            elif mocap_pos is None:  # no mocap source: nothing to agree with; a source: wait for its first frame
                agrees = not self._has_mocap()
            else:
                agrees = self._estimate_error_m(state, mocap_pos) < self.safety.max_estimate_mocap_m
            if agrees and self.link.kalman_settled():
                break
            time.sleep(0.02)
        checks = self._supervisor_checks()
        if not self.link.kalman_settled():
            checks.append(
                f"Kalman filter not settled after {self.p.preflight_timeout_s:g} s (position variances still "
                "changing: is the mocap stream or the positioning deck reaching the vehicle?)"
            )
        if state is None:
            checks.append("no state estimate from the vehicle")
        else:
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
            self.outcome = "preflight failed: " + "; ".join(checks)
            self._event("preflight failed", "; ".join(checks))
            raise _Abort(self.outcome)
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
        env = model.env
        steps = int(round(self._duration_s(model, duration_s) * self.p.rate_hz))
        table = env.ref_table[0, : steps + 1].double().numpy()
        if len(table) <= steps:  # a flight longer than the table holds its last point
            table = np.concatenate((table, np.repeat(table[-1:], steps + 1 - len(table), axis=0)))
        path = table + self._origin()
        lo, hi = np.asarray(self.safety.geofence_min_m), np.asarray(self.safety.geofence_max_m)
        outside = np.nonzero(((path < lo) | (path > hi)).any(axis=1))[0]
        if len(outside):
            k = int(outside[0])
            axis = int(np.nonzero((path[k] < lo) | (path[k] > hi))[0][0])
            bound = "geofence_min_m" if path[k, axis] < lo[axis] else "geofence_max_m"
            self._refuse(
                f"preflight failed: deploy.safety.{bound}: the reference leaves the geofence at "
                f"t={k / self.p.rate_hz:.2f} s ({'xyz'[axis]}={path[k, axis]:.2f} m; "
                f"fence {lo[axis]:.2f}..{hi[axis]:.2f} m)"
            )

    def _tick_loop(self, model: FlightModel, steps: int, origin: np.ndarray, allow_land: bool = True) -> str:
        dt = 1.0 / self.p.rate_hz
        next_t = time.monotonic()
        for k in range(steps):
            scheduled = next_t
            now = time.monotonic()
            jitter_ms = (now - scheduled) * 1e3
            state = self.link.state()
            if state is not None:  # the decision sees the low-passed voltage (the log keeps the raw one)
                state_for_check = dataclasses.replace(state, vbat_v=self.battery.update(state.vbat_v, dt))
            else:
                state_for_check = None
            mocap_age = self._mocap_age()
            action, command = None, 0
            if state is not None and all(math.isfinite(v) for v in (*state.pos_m, *state.vel_mps, *state.quat)):
                pos = np.array(state.pos_m) - origin
                action = model.act(pos, state.vel_mps, state.quat)
                if self._excitation is not None:
                    action[0] += self._excitation(k)
            decision = check(
                self.safety,
                now_s=time.monotonic(),
                state=state_for_check,
                command=action,
                estop=self.estop.is_set(),
                link_lost=self.link.link_lost.is_set(),
                mocap_age_s=mocap_age,
            )
            if decision.action == KILL:
                self._kill(decision.reason)
                return KILL
            if decision.action == LAND and allow_land:
                self._event("LAND", decision.reason)
                return LAND
            if decision.action == LAND:  # already landing: keep landing, note why
                self._event("warning", decision.reason)
            command = self._send(action)
            if self.p.estop_watchdog and not self.onboard:  # onboard: a lost link must not stop the app's flight
                self.link.send_estop_watchdog()
            compute_ms = (time.monotonic() - now) * 1e3
            self.rows.append(
                {
                    "t_s": now - self.t0,
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
                    "compute_ms": compute_ms,
                }
            )
            model.advance()
            next_t += dt
            time.sleep(max(0.0, next_t - time.monotonic()))
        return OK

    def _model(self, controller, family: RefFamily) -> FlightModel:
        model = FlightModel(self.make_env, controller, family, self.thrust.ceiling_mps2)
        model.act([0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])  # warm-up (traces the policy)
        model.env.reset()
        controller.reset(model.env)
        model.last_cmd = model.env.hover_action.clone()
        return model

    def _fly_phase(self, model: FlightModel, duration_s: float | None, origin: np.ndarray) -> str:
        steps = int(round(self._duration_s(model, duration_s) * self.p.rate_hz))
        result = self._tick_loop(model, steps, origin)
        if result == LAND:
            self._land(origin)
        return result

    @staticmethod
    def _duration_s(model: FlightModel, duration_s: float | None) -> float:
        """A phase's duration; None = the reference's episode (``env.episode_steps`` steps)."""
        return model.env.params.episode_steps * model.env.dt_s if duration_s is None else float(duration_s)

    def _land(self, origin: np.ndarray) -> None:
        self._set_phase("LAND")
        state = self.link.state()
        here = (np.array(state.pos_m) if state is not None else origin) - origin
        ground = np.array([here[0], here[1], -origin[2] + 0.05])
        model = self._model(self.pid_factory(), Ramp(here, ground, self.p.land_s))
        result = self._tick_loop(model, int((self.p.land_s + 0.5) * self.p.rate_hz), origin, allow_land=False)
        if result == OK:
            self.link.send_rates(0.0, 0.0, 0.0, 0)
            reasons = [e["text"] for e in self.events if e["kind"] == "LAND"]
            self.outcome = "landed" + (f" early: {reasons[0]}" if reasons else "")

    # -- records ---------------------------------------------------------------------------
    def _write(self) -> dict:
        self.run_dir.mkdir(parents=True, exist_ok=True)
        with open(self.run_dir / "flight.csv", "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(
                [
                    "t_s",
                    "phase",
                    "x",
                    "y",
                    "z",
                    "vx",
                    "vy",
                    "vz",
                    "qw",
                    "qx",
                    "qy",
                    "qz",
                    "ref_x",
                    "ref_y",
                    "ref_z",
                    "thrust_mps2",
                    "wx",
                    "wy",
                    "wz",
                    "thrust_cmd",
                    "dhat_x",
                    "dhat_y",
                    "dhat_z",
                    "vbat_v",
                    "decision",
                    "jitter_ms",
                    "compute_ms",
                ]
            )
            for r in self.rows:
                w.writerow(
                    [
                        f"{r['t_s']:.4f}",
                        r["phase"],
                        *r["pos"],
                        *r["vel"],
                        *r["quat"],
                        *r["ref"],
                        *r["action"],
                        r["thrust_cmd"],
                        *r["d_hat"],
                        r["vbat"],
                        r["decision"],
                        f"{r['jitter_ms']:.3f}",
                        f"{r['compute_ms']:.3f}",
                    ]
                )
        track = [r for r in self.rows if r["phase"] == "TRACK"]
        err = [float(np.linalg.norm(np.array(r["pos"]) - np.array(r["ref"]))) for r in track]
        app_steps = {k: e for k, e in self._app["samples"].items() if k < self._onboard_steps}
        if self.onboard:  # the app's own per-step error (the estimate it flew on vs p_d at that step)
            err = list(app_steps.values())
        jitter = np.array([r["jitter_ms"] for r in self.rows]) if self.rows else np.zeros(1)
        compute = np.array([r["compute_ms"] for r in self.rows]) if self.rows else np.zeros(1)
        summary = {
            "outcome": self.outcome,
            "track_steps": len(app_steps) if self.onboard else len(track),
            "track_error_m": float(np.mean(err)) if err else None,
            "ticks": len(self.rows),
            "jitter_ms": {
                "median": float(np.median(np.abs(jitter))),
                "p99": float(np.percentile(np.abs(jitter), 99)),
                "max": float(np.max(np.abs(jitter))),
            },
            "late_ticks": int(np.sum(jitter > self.p.late_tick_ms)),
            "upload_s": self.upload_s,
            "compute_ms": {"median": float(np.median(compute)), "p99": float(np.percentile(compute, 99))},
            "events": self.events,
            **self.summary_extra,
        }
        (self.run_dir / "events.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
        if track:
            self._plot(track)
        return summary

    def _plot(self, track: list[dict]) -> None:
        from types import SimpleNamespace

        from datt.eval.plots import plot_group_axes, plot_tracks

        pos = torch.tensor([r["pos"] for r in track]).unsqueeze(0)
        ref = torch.tensor([r["ref"] for r in track]).unsqueeze(0)
        trace = SimpleNamespace(pos_m=pos, ref_m=ref, crashed_at=torch.tensor([len(track) - 1]))
        plot_tracks(
            trace, ["track"], [1], self.run_dir / "tracks_flight.png", title="flight: reference vs flown", per_group=1
        )
        plot_group_axes(trace, ["track"], [1], 1.0 / self.p.rate_hz, self.run_dir / "axes_flight.png", title="flight")


class _Abort(RuntimeError):
    pass
