"""An onboard flight (``deploy.onboard=true``): the PID takes off over the radio, then the
vehicle's DATT app (``datt export format=app``, docs/onboard.md) tracks the reference and lands
by itself while the host streams mocap and watches.

Before arming the host checks the app is there and carries the flight's policy
(``datt.policyId``), selects the controller the app's hook runs under (``datt.controllerId``),
sets the app's parameters and uploads the reference, each read back or acknowledged. In flight it
follows the app's log: a LAND decision (or an app that stops stepping) hands the commander back
and lands with the PID; a KILL stops the motors; a lost link leaves the app flying to the end.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from datt.deploy import firmware, onboard
from datt.deploy.outcome import Kind, Outcome
from datt.deploy.runner import FlightModel, FlightRunner
from datt.deploy.safety import KILL, LAND, OK, check
from datt.errors import LinkError

APP_STALL_S = 0.3  # the app's step counter still this long while it should fly (its log arriving): the host takes over
LINK_LOST = "LINK_LOST"  # the host lost the vehicle while the app flew on


APP_LAND_HOLD_S = 0.5  # the app holds at its landing height this long before it stops the motors
# beyond the app's own time (its track, landing ramp and hold) the host waits this long for "done"
APP_LANDED_MARGIN_S = 2.0


class OnboardFlight(FlightRunner):
    sends_estop_watchdog = False  # a lost link must not stop the app's flight
    leads_mocap_by_half_round_trip = True  # the app answers its own estimate: no host predictor behind it

    def __init__(self, *args, policy_id: int | None = None, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.onboard_policy_id = policy_id  # the app must carry this policy (datt.export.c_code.policy_id)
        self._app: dict = {"samples": {}, "last": None}  # the app's log: step -> its error, latest values
        self._onboard_steps = 0  # TRACK steps the app flies (set when the reference is uploaded)

    def fly(self) -> dict:
        """Takeoff (PID, off-board), then the vehicle's DATT app tracks the reference and lands
        by itself: the reference is uploaded before arming, ``datt.run = 1`` hands it the flight,
        and the host only streams mocap and watches (KILL on a safety breach; a LAND decision
        stops the app and lands with the PID). A lost link leaves the app flying to the end."""

        def build(start_rel):
            track = self._model(self.track_controller, self.track_family)
            self._check_reference_in_geofence(track, self.p.track_s)
            self._onboard_prepare(track)
            return self._takeoff(start_rel), self._hover_after_trim(), track

        def airborne(origin, built):
            takeoff, hover, track = built
            if self._climb(origin, takeoff, hover, []) != OK:
                return  # killed, or already landed
            # the uploaded reference (slowed before the upload if it had to be) against the trimmed map's
            # ceiling at the app's own maxCmd; the app cannot be given another table now: fit or LAND
            refusal = self._thrust_check(track, self._app_ceiling_mps2(), can_slow=False)
            if refusal is not None:
                self._land(origin, refused=refusal)
                return
            if not self._app_heard():
                self._land(origin)
                return
            self._set_phase("TRACK")
            result = self._onboard_track(origin)
            if result == LAND:
                self._land(origin)
            elif result == OK:
                self.link.send_rates(0.0, 0.0, 0.0, 0)
                self.outcome = Outcome(Kind.LANDED_ONBOARD)

        return self._flight(build, airborne)

    def _onboard_prepare(self, track: FlightModel) -> None:
        """Check the app is there, select its controller hook, set its parameters, upload the
        reference (controller frame) and follow its log."""
        if not self.link.has_param("datt.run"):
            self._refuse(
                "deploy.onboard: the vehicle's firmware has no DATT app (no parameter datt.run): "
                "build and flash it (datt export format=app; docs/onboard.md), or fly off-board (deploy.onboard=false)"
            )
        if self.onboard_policy_id is not None:
            carried = int(self.link.read_param("datt.policyId"))
            if carried != self.onboard_policy_id:
                self._refuse(
                    f"deploy.onboard: the vehicle's app carries policy {carried:#010x}, the "
                    f"checkpoint is {self.onboard_policy_id:#010x}: flash the app exported from it "
                    "(datt export format=app checkpoint=...), or pass the checkpoint the app was built from"
                )
        if self.p.infeasible == "slow":  # slowed before the upload, on the configured map's ceiling
            refusal = self._fit_reference(track, self._app_ceiling_mps2(), can_slow=True)
            if refusal is not None:
                self._refuse(f"deploy.flight.infeasible: {refusal}")
        steps = self._steps(track, self.p.track_s)
        env = track.env
        # the track's points and the window after them, as far as the reference goes (at least the track)
        table = self._held_table(track, max(min(steps + env.window, env.table_len), steps + 1))
        if len(table) > onboard.TABLE_MAX:
            self._refuse(
                f"deploy.flight.track_s: the app holds {onboard.TABLE_MAX} reference points "
                f"({(onboard.TABLE_MAX - env.window) / self.p.rate_hz:.1f} s of track at {self.p.rate_hz:g} Hz); "
                f"this track needs {len(table)}"
            )
        values = self._app_settings(self._origin(), len(table), steps)
        controller = self._app_controller_id()
        try:  # every setting the onboard flight depends on, read back fresh
            self.link.set_params_checked({"datt.run": 0, **{f"datt.{name}": value for name, value in values.items()}})
            self.link.set_param_checked(str(firmware.fact("param_controller")), controller)
        except LinkError as exc:
            self._refuse(f"deploy.onboard: {str(exc).removeprefix('connect: ')}")
        self._event("onboard", f"stabilizer.controller = {controller} (the app's out-of-tree controller), read back")
        self._upload(table)
        self._onboard_steps = steps
        self.link.log_block("datt", onboard.LOG_BLOCK, self.link.log_period_ms, self._on_app_log)

    def _app_ceiling_mps2(self) -> float:
        """The most collective thrust the app commands: its ``maxCmd`` on the thrust map (trimmed, after the hover)."""
        return self.thrust.thrust_mps2(self.thrust.p.app_max_command)

    def _app_heard(self) -> bool:
        """Whether the app's log (block ``datt``, followed since before arming) has reached the
        host. Without it the host cannot see the app's phase, its abort or its landing, so the app
        is not started and the PID, still hovering, lands (a LAND event says so)."""
        if self._app["last"] is not None:
            return True
        self._event(
            "LAND",
            "the onboard app's log (block datt) has not reached the host since before arming: "
            "the app is not started (the host could not watch it)",
        )
        return False

    def _app_settings(self, origin: np.ndarray, n_points: int, steps: int) -> dict:
        """The app's parameters (``datt.<name>``) for this flight: origin (world frame, m), table
        length, track steps, landing, thrust map, rate limits and safety limits."""
        return {
            "originX": origin[0],
            "originY": origin[1],
            "originZ": origin[2],
            "nPoints": n_points,
            "trackSteps": steps,
            "landZ": -origin[2] + 0.05,
            "landS": self.p.land_s,
            "landHoldS": APP_LAND_HOLD_S,
            "hoverCmd": self.thrust.hover_command,
            "slope": self.thrust.slope,
            "maxCmd": self.thrust.p.app_max_command,
            "maxRateRoll": self.thrust.p.max_rate_degps[0],
            "maxRatePitch": self.thrust.p.max_rate_degps[1],
            "maxRateYaw": self.thrust.p.max_rate_degps[2],
            "maxTiltDeg": self.safety.max_tilt_deg,
            "maxPosStdM": self.p.onboard_max_pos_std_m,
        }

    def _upload(self, table) -> None:
        """Send the reference table to the app over the app channel, refusing the flight if it fails."""
        upload = onboard.Upload(self.link.send_app_packet, table, clock=self.clock)
        self.link.on_app_packet(upload.on_packet)
        started = self.clock.monotonic()
        try:
            upload.run()
        except RuntimeError as exc:
            self._refuse(f"the reference upload to the app failed: {exc}")
        upload_s = self.clock.monotonic() - started
        self.summary_extra["upload_s"] = upload_s
        self._event("onboard", f"reference uploaded: {len(table)} points in {upload_s:.2f} s")

    def _app_controller_id(self) -> int:
        """The controller id the app's hook runs under, as the app publishes it
        (``datt.controllerId``: ``ControllerTypeOot`` of the firmware it was built into)."""
        if not self.link.has_param("datt.controllerId"):
            self._refuse(
                "deploy.onboard: the vehicle's app does not publish datt.controllerId (built by an "
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
        self._app["last"] = (phase, step, ref, self.clock.monotonic())
        if phase in (onboard.TRACK, onboard.LAND, onboard.DONE) and step > 0:
            # datt.errM / datt.ref* belong to the step before datt.step (the app counts after stepping)
            self._app["samples"][step - 1] = float(values["datt.errM"])

    def _onboard_track(self, origin: np.ndarray) -> str:
        """Hand the flight to the app and watch until it has landed (or the time it needs has
        passed). Returns OK (the app landed), LAND (stopped: the host lands) or KILL."""
        # the hover trim's map goes with the start (in order: the app reads it when it starts)
        try:
            self.link.set_params_checked(
                {"datt.hoverCmd": self.thrust.hover_command, "datt.slope": self.thrust.slope, "datt.run": 1}
            )
        except LinkError as exc:  # the app may not fly on the trimmed map: the PID, still hovering, lands
            self._event("LAND", f"the app's start was not confirmed: {str(exc).removeprefix('connect: ')}")
            self.link.set_param("datt.run", 0)
            return LAND
        dt = 1.0 / self.p.rate_hz
        budget_s = self._app_budget_s()
        deadline = self.clock.monotonic() + budget_s
        quiet = False
        stepping = [-1, self.clock.monotonic()]  # the app's last step seen, and when it changed
        next_t = self.clock.monotonic()
        while self.clock.monotonic() < deadline:
            now = self.clock.monotonic()
            state = self.link.state()
            verdict = self._app_verdict(now, stepping)
            if verdict is not None:
                return verdict
            fresh = state is not None and now - state.t_s < self.safety.max_state_age_s
            if self.link.link_lost.is_set() or not fresh:
                if not quiet:  # nothing the host can do: the app flies on by itself
                    self._event("warning", "no fresh state from the vehicle: the onboard app flies on")
                    quiet = True
            else:
                quiet = False
                verdict = self._watch_step(state, now, (now - next_t) * 1e3, origin)
                if verdict is not None:
                    return verdict
            next_t += dt
            self.clock.sleep(max(0.0, next_t - self.clock.monotonic()))
        state = self.link.state()
        if (
            self.link.link_lost.is_set()
            or state is None
            or self.clock.monotonic() - state.t_s > self.safety.max_state_age_s
        ):
            # an e-stop could not arrive, and would drop a vehicle that may still be flying well
            self.outcome = Outcome(
                Kind.LINK_LOST, "during the onboard flight the app flew on by itself; the host cannot confirm it landed"
            )
            self._event("warning", self.outcome.text)
            return LINK_LOST
        self._event("LAND", f"the app did not report landing within {budget_s:.1f} s")
        self.link.set_param("datt.run", 0)
        return LAND

    def _app_budget_s(self) -> float:
        """How long the host waits for the app to report landing: its track steps at the flight's
        rate, the landing ramp (``land_s``) and hold, and :data:`APP_LANDED_MARGIN_S`."""
        return self._onboard_steps / self.p.rate_hz + self.p.land_s + APP_LAND_HOLD_S + APP_LANDED_MARGIN_S

    def _app_verdict(self, now: float, stepping: list) -> str | None:
        """What the app's own log says about the flight: OK (landed), LAND (refused to start, or
        heard without its step moving for ``APP_STALL_S``: not started or stopped stepping), KILL
        (aborted), or None (flying on). ``stepping`` is the app's last step seen and when it
        changed, updated in place."""
        last = self._app["last"]  # set: the host starts the app only once it has heard it (_app_heard)
        phase = last[0]
        if phase == onboard.REFUSED:
            self._event("LAND", "the app refused to start (table incomplete or a parameter invalid)")
            self.link.set_param("datt.run", 0)
            return LAND
        if phase == onboard.ABORTED:  # the app holds the motors off (stop setpoints) until datt.run = 0
            self.outcome = Outcome(
                Kind.KILLED, "the onboard app aborted (tilt or a non-finite state/action), motors stopped"
            )
            self._event("KILL", self.outcome.text)
            return KILL
        if phase == onboard.DONE:
            self.link.set_param("datt.run", 0)
            self._event("onboard", "the app has landed")
            return OK
        # idle, tracking or landing: the step must move. Idle after datt.run = 1 is a stall too:
        # nothing sends the vehicle setpoints (the host stopped at the hand-over, the app has not started)
        hearing = now - last[3] < APP_STALL_S / 2  # the app's log arrives: the link is up
        if last[1] != stepping[0]:
            stepping[:] = [last[1], now]
        elif now - stepping[1] > APP_STALL_S and hearing:
            if phase == onboard.IDLE:
                why = f"the app did not start within {APP_STALL_S:g} s of datt.run = 1 (still idle)"
            else:
                why = f"the app stopped stepping at step {last[1]} (its state is stale: no hook)"
            self._event("LAND", why)
            self.link.set_param("datt.run", 0)  # the commander back to the radio's setpoints,
            # flown by a controller that honours rates (the app's hook ran under another)
            self.link.set_param(str(firmware.fact("param_controller")), firmware.CONTROLLER_PID)
            return LAND
        return None

    def _watch_step(self, state, now: float, jitter_ms: float, origin: np.ndarray) -> str | None:
        """The host's safety check on a fresh state while the app flies, and the log row:
        KILL or LAND when the check says so (the app hands the commander back), else None."""
        dt = 1.0 / self.p.rate_hz
        state_for_check = dataclasses.replace(state, vbat_v=self.battery.update(state.vbat_v, dt))
        last = self._app["last"]  # set: the host starts the app only once it has heard it (_app_heard)
        phase = last[0]
        decision = check(
            self.safety,
            now_s=now,
            state=state_for_check,
            command=None,
            estop=self.estop.is_set(),
            link_lost=False,
            mocap_age_s=self._mocap_age(),
            tracking=phase == onboard.TRACK,
            reference_z_m=float(last[2][2] + origin[2]) if phase == onboard.TRACK else None,
        )
        if decision.action == KILL:
            self._kill(decision.reason)
            return KILL
        if decision.action == LAND:
            self._event("LAND", decision.reason)
            self.link.set_param("datt.run", 0)  # the app hands the commander back
            return LAND
        # an idle app has no reference yet (its log holds the last one it flew, or zeros)
        ref = np.array(last[2]) + origin if phase != onboard.IDLE else np.full(3, np.nan)
        self.rows.append(
            {
                "t_s": now - self.log.t0,
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
                "jitter_ms": jitter_ms,
                "compute_ms": 0.0,
            }
        )
        return None

    def _received_errors(self) -> list[float]:
        """None: the app's error is of one instant already (no estimate crosses the radio)."""
        return []

    def _track_errors(self) -> list[float]:
        """The app's own per-step error (the estimate it flew on vs p_d at that step)."""
        return [e for k, e in sorted(self._app["samples"].items()) if k < self._onboard_steps]
