"""A first real flight that cannot go wrong: the simulated Crazyflie disagrees with the host where
the firmware would (controller ids, flight-mode holds, write echoes, arming, the app channel's
queue), and the host's settings refuse what would disable a check. One test (or more) per way a
first flight went wrong when read against crazyflie-firmware 2026.08 (docs/deploy.md)."""

import csv
import json
import math
import os
import shutil
import signal
import time

import pytest

pytest.importorskip("cflib")

from datt.configuration import compose  # noqa: E402
from datt.deploy import firmware, onboard  # noqa: E402
from datt.deploy.link import CrazyflieLink, LinkError  # noqa: E402
from datt.deploy.runner import FlightParams  # noqa: E402
from datt.deploy.safety import tilt_deg  # noqa: E402
from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams  # noqa: E402
from datt.errors import ConfigError  # noqa: E402

from . import SHORT_FLIGHT, fly_sim, ports  # noqa: E402

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc: the onboard app cannot be built here")


def fly(tmp_path, overrides=(), hook=None):
    summary, server, _ = fly_sim(tmp_path, next(ports), overrides, hook)
    return summary, server


def tilt_after(server, link, seconds, roll_degps):
    """Stream a roll-rate setpoint at hover thrust for ``seconds``; the vehicle's tilt (deg) then."""
    link.arm(True)
    assert link.wait_armed(1.0)
    link.send_rates(0.0, 0.0, 0.0, 0)  # thrust lock
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        link.send_rates(roll_degps, 0.0, 0.0, 55000)  # climbing: off the ground
        time.sleep(0.02)
    return tilt_deg(server.true_state()["quat"])


# -- 1 and 2: the controller that flies the setpoints ------------------------------------------
@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
@pytest.mark.parametrize(
    "controller, rates_flown", [("PID", True), ("INDI", True), ("Lee", False), ("Mellinger", False)]
)
def test_only_rate_controllers_fly_rate_setpoints(controller, rates_flown):
    """Lee, Mellinger (and Brescianini) hold the setpoint's attitude: a roll-rate setpoint leaves
    the vehicle level; the PID and INDI roll it."""
    port = next(ports)
    ident = firmware.fact(f"controller_{controller.lower()}")
    server = SimCrazyflie(SimCrazyflieParams(port=port, boot_params={"stabilizer.controller": ident})).start()
    try:
        link = CrazyflieLink(f"udp://127.0.0.1:{port}")
        link.connect()
        server.params["stabilizer.controller"] = ident  # as a vehicle that keeps it would
        server._settle_params()
        assert server.controller == controller
        tilt = tilt_after(server, link, 0.3, 90.0)
        link.close()
    finally:
        server.stop()
    assert (tilt > 10.0) == rates_flown, tilt


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
def test_off_board_selects_the_pid_and_clears_the_holds_then_restores_them(tmp_path):
    """A vehicle left in Lee with the altitude and position holds on (parameters persist until a
    reboot: an earlier flight, a cfclient session) flies the PID in rate mode, and gets its
    settings back after the flight."""
    left = {"stabilizer.controller": 5, "flightmode.althold": 1, "flightmode.poshold": 1, "flightmode.posSet": 1}
    flown = {}

    def watch(server, runner):
        server.params.update(left)  # what the vehicle holds when the host connects
        server._settle_params()

        def during_track():
            while runner.phase != "TRACK":
                runner.clock.sleep(0.01)
            flown.update({k: server.params[k] for k in left})

        runner.clock.start_thread(during_track, "fault")

    # the training model's loop, on which the 0.15 m bound was set (a 3 s star on the stock loop: 0.18 m)
    summary, server = fly(tmp_path, ["deploy.server.rate_loop=pi_first_order"], hook=watch)
    assert summary["outcome"] == "landed", summary["outcome"]
    assert summary["track_error_m"] < 0.15
    assert flown == {"stabilizer.controller": firmware.CONTROLLER_PID, "flightmode.althold": 0,
                     "flightmode.poshold": 0, "flightmode.posSet": 0}  # fmt: skip
    assert {k: server.params[k] for k in left} == left  # restored on close


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
@needs_gcc
def test_onboard_selects_the_controller_the_app_publishes(tmp_path):
    """The app publishes ``datt.controllerId`` (``ControllerTypeOot`` of its firmware, 6 in
    2026.08); the host selects it and reads it back; the app's hook then runs and it flies."""
    seen = {}

    def watch(server, runner):

        def during_track():
            while runner.phase != "TRACK":
                runner.clock.sleep(0.01)
            runner.clock.sleep(0.3)
            seen.update(controller=server.controller, phase=server.app.phase)

        runner.clock.start_thread(during_track, "fault")
        seen["runner"], seen["sent"] = runner, []  # this flight's (a stalled one is flown again)
        send_rates = runner.link.send_rates

        def record(*args):
            seen["sent"].append((runner.phase, args))
            send_rates(*args)

        runner.link.send_rates = record

    summary, server = fly(tmp_path, ["deploy.onboard=true"], hook=watch)
    assert summary["outcome"] == "landed (onboard)", summary["outcome"]
    assert server.app.get("controllerId") == firmware.CONTROLLER_OOT == 6
    runner = seen.pop("runner")
    # from the hand-over the host sends no setpoint; once the app has landed, one with zero thrust
    assert [args for phase, args in seen.pop("sent") if phase == "TRACK"] == [(0.0, 0.0, 0.0, 0)]
    assert seen == {"controller": "OutOfTree", "phase": onboard.TRACK}
    said = [(e["kind"], e["text"]) for e in summary["events"]]
    assert ("onboard", "stabilizer.controller = 6 (the app's out-of-tree controller), read back") in said
    # the table holds the track's points and the policy's window after its last one
    window = runner.make_env(runner.track_family).window
    points = f"reference uploaded: {runner._onboard_steps + window} points in "
    assert window > 0 and runner._onboard_steps == 150  # SHORT_FLIGHT's 3 s at 50 Hz
    # the upload's time is recorded and logged; the app's own errors score the track
    uploaded = [e for e in summary["events"] if e["text"].startswith("reference uploaded: ")]
    assert len(uploaded) == 1 and uploaded[0]["kind"] == "onboard" and summary["upload_s"] > 0
    assert uploaded[0]["text"].startswith(points), uploaded[0]["text"]
    assert f"in {summary['upload_s']:.2f} s" in uploaded[0]["text"]
    assert 0.0 < summary["track_error_m"] < 0.2
    # the host computes nothing while the app flies: its TRACK rows carry no command and no compute time
    with open(tmp_path / "flight.csv") as f:
        track = [r for r in csv.DictReader(f) if r["phase"] == "TRACK"]
    assert track and all((r["compute_ms"], r["thrust_cmd"], r["wx"]) == ("0.000", "0", "nan") for r in track)
    # the host's tick timing in milliseconds: a sleeping loop is off its schedule by tens of µs
    assert any(abs(float(r["jitter_ms"])) >= 0.001 for r in track)


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
@needs_gcc
def test_the_app_refuses_to_start_without_its_hook(tmp_path):
    """Under any controller but the out-of-tree one the hook never runs: the app refuses
    ``datt.run`` instead of flying a zero state, and the host lands with the PID."""

    def lee_after_handover(server, runner):
        real = runner.link.set_params_checked

        def switch_then_set(values):
            if values.get("datt.run") == 1:
                with server._lock:  # something switches the controller to Lee after the host checked it
                    server.params["stabilizer.controller"] = 5
            real(values)

        runner.link.set_params_checked = switch_then_set

    summary, server = fly(tmp_path, ["deploy.onboard=true"], hook=lee_after_handover)
    assert "the app refused to start" in " ".join(e["text"] for e in summary["events"])
    assert summary["outcome"].startswith("landed early"), summary["outcome"]
    assert server.app.phase == onboard.IDLE


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
@needs_gcc
def test_an_app_that_stops_stepping_is_taken_over_by_the_host(tmp_path):
    """The controller switched away mid-track: the hook's state goes stale, the app pushes no
    setpoint; the host sees its step counter stop and lands with the PID at once instead of
    waiting for the commander's watchdog to cut the motors."""

    def lee_mid_track(server, runner):

        def switch():
            while server.app.phase != onboard.TRACK:
                server.clock.sleep(0.005)
            server.clock.sleep(0.5)
            with server._lock:
                server.params["stabilizer.controller"] = 5

        server.clock.start_thread(switch, "fault")

    summary, server = fly(tmp_path, ["deploy.onboard=true"], hook=lee_mid_track)
    assert summary["outcome"].startswith("landed early: the app stopped stepping"), summary["outcome"]
    assert not server.locked and server.true_state()["pos_m"][2] < 0.15


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
@needs_gcc
def test_an_app_that_does_not_keep_the_trimmed_map_is_not_started_and_the_pid_lands(tmp_path):
    """After the hover trim, the host hands the app the trimmed map with ``datt.run = 1`` and
    reads them back: a vehicle that keeps its old ``datt.hoverCmd`` fails the read-back while the
    PID hovers it. Nothing is KILLed (the vehicle would drop): ``datt.run`` goes back to 0 and
    the PID lands; the log says why."""

    def keep_the_old_hover_command(server, runner):
        app_set = server.app.set

        def stubborn(name, value):
            if name == "hoverCmd" and runner.phase == "TRACK":
                return  # an app of another version that no longer takes the trim here
            app_set(name, value)

        server.app.set = stubborn

    summary, server = fly(tmp_path, ["deploy.onboard=true"], hook=keep_the_old_hover_command)
    assert summary["outcome"].startswith("landed early: the app's start was not confirmed: datt.hoverCmd reads back"), (
        summary["outcome"]
    )
    assert not any(e["kind"] == "KILL" for e in summary["events"])
    assert server.app.phase == onboard.IDLE and server.app.run_request == 0
    assert not server.locked and server.true_state()["pos_m"][2] < 0.15


@needs_gcc
def test_an_app_that_does_not_keep_a_setting_is_refused_before_arming(tmp_path):
    """The app's settings are written before arming and read back fresh: an app that keeps its
    old number of track steps (0) fails the read, and the flight is refused in the link's words
    (without its ``connect:`` prefix); nothing is armed."""

    def keep_no_track_steps(server, runner):
        app_set = server.app.set

        def stubborn(name, value):
            if name != "trackSteps":
                app_set(name, value)

        server.app.set = stubborn

    summary, server = fly(tmp_path, ["deploy.onboard=true"], hook=keep_no_track_steps)
    assert summary["outcome"].startswith("preflight failed: deploy.onboard: datt.trackSteps reads back"), summary[
        "outcome"
    ]
    assert "ARM" not in [e["text"] for e in summary["events"] if e["kind"] == "phase"]
    assert not server.armed


# -- 3: a read that can fail ------------------------------------------------------------------
def test_a_setting_the_vehicle_does_not_keep_is_refused():
    """Without the app the firmware has no out-of-tree controller: writing its id is echoed as
    written, but the stabilizer loop keeps the PID, and the fresh read says so."""
    port = next(ports)
    server = SimCrazyflie(SimCrazyflieParams(port=port)).start()
    try:
        link = CrazyflieLink(f"udp://127.0.0.1:{port}").connect()
        with pytest.raises(LinkError, match=r"stabilizer.controller reads back 1 after setting 6"):
            link.set_param_checked("stabilizer.controller", 6)
        link.close()
    finally:
        server.stop()


def test_the_simulated_firmware_echoes_a_write_as_sent_and_ignores_read_only_writes():
    from datt.deploy import crtp

    server = SimCrazyflie(SimCrazyflieParams(port=next(ports)))
    sent = []
    server._send = sent.append
    ident = next(i for i, p in enumerate(server.param_toc) if p[:2] == ("stabilizer", "controller"))
    request = bytes([ident & 255, ident >> 8, 6])
    server._on_param(2, request)
    assert sent == [crtp.packet(crtp.PORT_PARAM, 2, request)]  # the echo says 6 ...
    server._settle_params()
    server._on_param(1, request[:2])
    assert sent[-1] == crtp.packet(crtp.PORT_PARAM, 1, request[:2] + b"\0\x01")  # ... the vehicle runs 1
    deck = next(i for i, p in enumerate(server.param_toc) if p[:2] == ("deck", "bcLighthouse4"))
    server._on_param(2, bytes([deck, 0, 1]))
    assert len(sent) == 2 and server.params["deck.bcLighthouse4"] == 0  # read-only: no answer, unchanged


# -- 4: arming confirmed -----------------------------------------------------------------------
@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
def test_a_vehicle_that_does_not_arm_does_not_take_off(tmp_path):
    summary, server = fly(tmp_path, ["deploy.server.refuse_arming=true"])
    assert summary["outcome"].startswith("arming failed: the supervisor did not report the vehicle armed")
    phases = [e["text"] for e in summary["events"] if e["kind"] == "phase"]
    assert "TAKEOFF" not in phases and not server.armed
    assert summary["ticks"] == 0 and server.true_state()["pos_m"][2] == 0.0


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
def test_a_vehicle_that_stops_answering_before_arming_is_a_lost_link_and_nothing_arms(tmp_path):
    """The preflight asks the supervisor for its state; a vehicle that never answers (the radio
    gone after connect) ends the flight as a lost link (the vehicle's or the radio's failure, exit
    4), with the link's own reason in the outcome and the log, and nothing armed."""
    from datt.deploy.outcome import Kind, Outcome

    def deaf_supervisor(server, runner):
        server._on_supervisor = lambda ch, data: None

    summary, server = fly(tmp_path, [], hook=deaf_supervisor)
    reason = "preflight: the vehicle does not answer the supervisor state request (old firmware?)"
    assert summary["outcome"] == f"link lost: {reason}", summary["outcome"]
    assert [e["text"] for e in summary["events"] if e["kind"] == "link lost"][0] == reason
    assert Outcome(Kind(summary["outcome_kind"]), reason).exit_code == 4
    assert not server.armed and summary["ticks"] == 0


def test_arming_takes_effect_at_the_supervisors_update():
    server = SimCrazyflie(SimCrazyflieParams(port=next(ports)))
    server._send = lambda data: None
    server.sim_time_s = 0.02  # between two 25 Hz supervisor updates
    server._on_supervisor(1, bytes([1, 1]))
    assert not server.armed
    server._physics_step()
    assert not server.armed and server.sim_time_s == pytest.approx(0.04)
    server._physics_step()
    assert server.armed


# -- 5: the app channel's queue ----------------------------------------------------------------
def test_the_app_channel_queues_ten_packets_and_drops_the_rest():
    server = SimCrazyflie(SimCrazyflieParams(port=next(ports)))
    server.app = object()  # any app: packets are queued for its task
    for k in range(16):
        server._on_platform(2, onboard.points_packet(2 * k, [(0.0, 0.0, 0.0)] * 2))
    assert len(server.app_rx) == firmware.APP_CHANNEL_RX_QUEUE == 10 and server.app_rx_dropped == 6


def test_the_upload_never_sends_more_than_the_queue_holds():
    sent = []
    upload = onboard.Upload(sent.append, [(0.0, 0.0, 0.0)] * 64, timeout_s=0.01, attempts=1)
    with pytest.raises(ValueError, match="app channel queues 1..10"):
        upload.run(window=16)
    with pytest.raises(RuntimeError, match="no acknowledgement"):
        upload.run()
    assert len(sent) == firmware.APP_CHANNEL_RX_QUEUE


@pytest.mark.flight  # a real flight through cflib (seconds): not in the mutation-testing selection
@needs_gcc
def test_onboard_upload_fits_the_queue_and_is_timed(tmp_path):
    summary, server = fly(tmp_path, ["deploy.onboard=true"])
    assert summary["outcome"] == "landed (onboard)"
    assert server.app_rx_dropped == 0
    assert 0 < summary["upload_s"] < 10


# -- 6: settings that would disable a check, and a stop before arming ---------------------------
@pytest.mark.parametrize("track_s", [0.0, -1.0, math.nan, math.inf])
def test_a_track_duration_that_is_not_positive_and_finite_is_refused(track_s):
    with pytest.raises(
        ConfigError, match=r"^deploy.flight.track_s: must be a finite number in \(0, 600\] or null, got"
    ):
        FlightParams(track_s=track_s).validate()


@pytest.mark.parametrize(
    "override, message",
    [
        ("deploy.flight.hover_trim_window_s=1.5", r"must be at most deploy.flight.hover_s \(1 s\) while"),
        ("deploy.flight.hover_trim_window_s=0", r"must be a finite number in \(0, 60\], got 0"),
        ("deploy.flight.hover_trim_max=1.0", r"must be a finite number in \(0, 1\), got 1.0"),
        ("deploy.flight.hover_trim_max=nan", r"must be a finite number in \(0, 1\), got nan"),
        ("deploy.flight.hover_trim_settle_s=-1", r"must be a finite number in \[0, 60\], got -1"),
        ("deploy.flight.hover_trim_settle_s=0.3", r"must be 0 or at least deploy.flight.hover_trim_window_s \(0.5 s\)"),
    ],
)
def test_hover_trim_settings_are_refused_in_one_line(override, message):
    from datt.deploy.schema import deploy_params

    key = override.split("=")[0]
    with pytest.raises(ConfigError, match=f"^{key}: {message}"):
        deploy_params(compose("deploy", [override]).deploy)


def test_a_hover_trim_window_longer_than_the_hover_is_accepted_when_the_trim_is_off():
    from datt.deploy.schema import deploy_params

    overrides = ["deploy.flight.hover_trim=false", "deploy.flight.hover_trim_window_s=1.5"]
    _, flight, _, _ = deploy_params(compose("deploy", overrides).deploy)
    assert flight.hover_trim is False and flight.hover_trim_window_s == 1.5


def test_safety_settings_from_the_command_line_are_refused_in_one_line():
    from datt.deploy.schema import deploy_params

    for override, key in [
        ("deploy.safety.max_tilt_deg=nan", "deploy.safety.max_tilt_deg"),
        ("deploy.safety.geofence_margin_m=nan", "deploy.safety.geofence_margin_m"),
        ("deploy.safety.geofence_max_m=[inf,inf,inf]", "deploy.safety.geofence_max_m"),
        ("deploy.flight.track_s=0", "deploy.flight.track_s"),
    ]:
        with pytest.raises(ConfigError, match=f"^{key}: must be"):
            deploy_params(compose("deploy", [override]).deploy)


def test_a_stop_signal_before_arming_arms_nothing(tmp_path):
    """SIGINT while the flight is being prepared (as while ``deploy.onboard=true`` builds the
    app): remembered, and the flight ends before arming with exit 130; the log is kept."""
    from datt.errors import FlightStopped
    from datt.tasks.deploy import run_deploy_command

    cfg = compose("deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", *SHORT_FLIGHT])
    seen = {}

    def interrupt(server, runner):
        seen["server"] = server
        os.kill(os.getpid(), signal.SIGINT)  # handled by the StopRequest active while preparing
        time.sleep(0.05)

    from datt.tasks import deploy as task

    real = task.run_deploy
    task.run_deploy = lambda c: real(c, run_dir=tmp_path, server_hook=interrupt)
    try:
        with pytest.raises(FlightStopped, match=r"stopped before arming \(SIGINT\): nothing was armed"):
            run_deploy_command(cfg)
    finally:
        task.run_deploy = real
    assert not seen["server"].armed and seen["server"].true_state()["pos_m"][2] == 0.0
    logged = json.loads((tmp_path / "events.json").read_text())
    stops = [e for e in logged["events"] if e["kind"] == "stopped"]  # the log says why it ended, once
    assert [e["text"] for e in stops] == ["stopped before arming (SIGINT): nothing was armed"]
    assert logged["outcome_kind"] == "stopped"


# -- the outcome type: one exit status per kind ---------------------------------------------------
def test_each_outcome_kind_has_its_text_and_exit_status():
    from datt.deploy.outcome import Kind, Outcome

    cases = {
        Outcome(Kind.LANDED): ("landed", 0),
        Outcome(Kind.LANDED_EARLY, "mocap stale"): ("landed early: mocap stale", 0),
        Outcome(Kind.LANDED_ONBOARD): ("landed (onboard)", 0),
        Outcome(Kind.REFUSED_SETTING, "deploy.safety.geofence_max_m: ..."): (
            "preflight failed: deploy.safety.geofence_max_m: ...",
            2,
        ),
        Outcome(Kind.REFUSED_REFERENCE, "asks for 11.4 m/s²"): ("landed without tracking: asks for 11.4 m/s²", 2),
        Outcome(Kind.REFUSED, "vehicle not level"): ("preflight failed: vehicle not level", 4),
        Outcome(Kind.ARMING_FAILED, "no"): ("arming failed: no", 4),
        Outcome(Kind.STOPPED, "SIGTERM"): ("stopped before arming (SIGTERM): nothing was armed", 130),
        Outcome(Kind.KILLED, "tilt"): ("killed: tilt", 4),
        Outcome(Kind.LINK_LOST, "timeout"): ("link lost: timeout", 4),  # the radio's failure, not the user's
        Outcome(Kind.INCOMPLETE): ("incomplete", 4),
    }
    assert {o.kind for o in cases} == set(Kind)
    for outcome, (text, code) in cases.items():
        assert (outcome.text, outcome.exit_code, outcome.landed) == (text, code, code == 0), outcome.kind


# -- the simulated vehicle's estimate, supervisor and radio ---------------------------------------
def test_losses_come_in_runs_of_the_set_mean_length_at_the_set_rate():
    server = SimCrazyflie(SimCrazyflieParams(port=next(ports), radio_loss=0.1, radio_burst_len=4.0, radio_seed=3))
    lost = [server._lost() for _ in range(200_000)]
    runs, length = [], 0
    for x in lost:
        if x:
            length += 1
        elif length:
            runs.append(length)
            length = 0
    assert sum(lost) / len(lost) == pytest.approx(0.1, abs=0.005)
    assert sum(runs) / len(runs) == pytest.approx(4.0, rel=0.05)
    independent = SimCrazyflie(SimCrazyflieParams(port=next(ports), radio_loss=0.1, radio_seed=3))
    lost = [independent._lost() for _ in range(200_000)]
    pairs = sum(a and b for a, b in zip(lost, lost[1:])) / (len(lost) - 1)
    assert pairs == pytest.approx(0.01, abs=0.002)  # P(lost, lost) = 0.1² when independent


def test_the_estimate_errors_have_the_set_spread_and_correlation():
    server = SimCrazyflie(SimCrazyflieParams(port=next(ports), vel_noise_std_mps=0.05, att_noise_std_rad=0.01))
    vel, att = [], []
    for _ in range(20_000):
        server._estimate_noise_step()
        vel.append(server.vel_error_mps[0])
        att.append(server.att_error_rad[2])
    import numpy as np

    vel, att = np.array(vel), np.array(att)
    assert vel.std() == pytest.approx(0.05, rel=0.1) and abs(vel.mean()) < 0.01
    assert att.std() == pytest.approx(0.01, rel=0.1)
    lag = round(0.2 / server.p.dt_s)  # one correlation time: correlation e^-1
    assert np.corrcoef(vel[:-lag], vel[lag:])[0, 1] == pytest.approx(math.exp(-1), abs=0.08)
    server.params["stabilizer.estimator"] = 2  # the complementary filter has no horizontal velocity
    truth = server.true_state()["vel_mps"]
    assert server._estimated_state()[1] == pytest.approx([t + e for t, e in zip(truth, server.vel_error_mps)])


def test_a_vehicle_tilted_past_the_limit_for_a_second_is_stopped_by_the_supervisor():
    import torch

    server = SimCrazyflie(SimCrazyflieParams(port=next(ports)))
    server.armed, server.thrust_locked = True, False
    server.quad.state.pos_m[0, 2] = 5.0
    half = math.radians(70) / 2  # body z 70 deg from vertical: specific force along it ~ thrust only
    server.quad.state.quat[0] = torch.tensor([math.cos(half), math.sin(half), 0.0, 0.0])
    server.cmd, server.last_setpoint_t = (0.0, 0.0, 0.0, 20000), 0.0  # a weak thrust: under 0.5 g
    for _ in range(40):  # 0.8 s: not yet
        server.last_setpoint_t = server.sim_time_s
        server._physics_step()
    assert not server.crashed
    for _ in range(15):
        server.last_setpoint_t = server.sim_time_s
        server._physics_step()
    assert server.crashed and server.cmd[3] == 0
    assert server.state_bitfield() & (1 << 5) and server.state_bitfield() & (1 << 7)  # tumbled, crashed


@pytest.mark.parametrize("origin_m", [[0.5], [0.0, 0.0, 1.0]])
def test_a_hover_point_needs_two_coordinates(origin_m):
    from datt.deploy.runner import FlightParams

    with pytest.raises(ConfigError) as refused:
        FlightParams(origin_m=origin_m).validate()
    assert str(refused.value) == f"deploy.flight.origin_m: need 2 values (x, y), got {origin_m!r}"


def test_a_hover_after_the_trim_of_zero_seconds_is_none_and_accepted():
    """``hover_trim_settle_s = 0`` means no HOVER on the trimmed map, not a too-short one."""
    from datt.deploy.runner import FlightParams

    FlightParams(hover_trim_settle_s=0.0).validate()
    with pytest.raises(ConfigError, match=r"^deploy.flight.hover_trim_settle_s: must be 0 or at least"):
        FlightParams(hover_trim_settle_s=0.01).validate()
