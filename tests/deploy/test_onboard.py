"""The onboard DATT app (datt_onboard.c, built for this machine and called as the simulated
Crazyflie calls it) and flights with the policy onboard (deploy.onboard=true)."""

import math
import re
import shutil
import struct
import threading
from importlib import resources

import numpy as np
import pytest
import torch

from datt.configuration import compose
from datt.control.factory import build_controller
from datt.deploy import onboard
from datt.deploy.sim.onboard_app import OnboardApp
from datt.deploy.thrust import ThrustMap
from datt.export import export_spec
from datt.export.app import build_sil_library, write_app

from . import HEAVY_WEAK, ports

pytestmark = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc: the onboard app cannot be built here")
LEVEL = [1.0, 0.0, 0.0, 0.0]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    spec, controller, merged = export_spec(compose("export", []))
    app_dir = tmp_path_factory.mktemp("app")
    files = write_app(spec, app_dir)
    return spec, controller, app_dir, files, build_sil_library(app_dir), merged


def loaded(built, n_points=40, track_steps=20, **params) -> OnboardApp:
    app = OnboardApp(built[4], controller_id=6)
    table = [(0.01 * k, -0.02 * k, 0.005 * k) for k in range(n_points)]
    for i in range(0, n_points, 2):
        assert app.receive(onboard.points_packet(i, table[i : i + 2])) == bytes([onboard.PKT_ACK, i & 255, i >> 8, 0])
    for name, value in {"nPoints": n_points, "trackSteps": track_steps, "originX": 0.0, "originY": 0.0, "originZ": 1.0,
                        "landZ": -0.95, "landS": 0.2, "landHoldS": 0.1, **params}.items():  # fmt: skip
        app.set(name, value)
    return app


def test_the_app_directory_builds_out_of_tree():
    """The files the firmware's out-of-tree build needs, and the app config it merges."""
    root = resources.files("datt.export") / "app"
    config = (root / "app-config").read_text()
    assert "CONFIG_APP_ENABLE=y" in config and "CONFIG_CONTROLLER_OOT=y" in config
    assert "tools/make/oot.mk" in (root / "Makefile").read_text()


def test_written_app_has_every_source(built):
    names = {p.relative_to(built[2]).as_posix() for p in built[3]}
    assert names == {
        "Makefile", "Kbuild", "app-config", "src/Kbuild", "src/datt_policy.c", "src/datt_policy.h",
        "src/datt_onboard.c", "src/datt_onboard.h", "src/app_datt.c",
    }  # fmt: skip
    header = (built[2] / "src" / "datt_policy.h").read_text()
    assert "#define DATT_REF_STRIDE 3" in header and "#define DATT_DT_S 0.0199999996f" in header


def test_the_policy_id_names_the_weights_and_constants(built):
    import copy

    from datt.export.c_code import policy_id

    spec = built[0]
    header = (built[2] / "src" / "datt_policy.h").read_text()
    assert f"#define DATT_POLICY_ID 0x{policy_id(spec):08x}u" in header
    assert OnboardApp(built[4], controller_id=6).get("policyId") == policy_id(spec)
    other = copy.deepcopy(spec)
    other.head[1][0] += 1e-6  # one bias, one ulp-scale change
    assert policy_id(other) != policy_id(spec)
    other = copy.deepcopy(spec)
    other.l1.alpha *= 0.5
    assert policy_id(other) != policy_id(spec)


IDENTIFYING = [  # (what, how to change it): every value the generated step computes with
    ("horizon", lambda s: setattr(s, "horizon", s.horizon + 1)),
    ("body_frame", lambda s: setattr(s, "body_frame", not s.body_frame)),
    ("feedback", lambda s: setattr(s, "feedback", not s.feedback)),
    ("action_history", lambda s: setattr(s, "action_history", s.action_history + 1)),
    ("use_d_hat", lambda s: setattr(s, "use_d_hat", not s.use_d_hat)),
    ("ref_stride", lambda s: setattr(s, "ref_stride", s.ref_stride + 1)),
    ("dt_s", lambda s: setattr(s, "dt_s", s.dt_s * 1.5)),
    ("action_low", lambda s: s.action_low.__setitem__(3, s.action_low[3] - 0.5)),
    ("action_high", lambda s: s.action_high.__setitem__(0, s.action_high[0] + 0.5)),
    ("conv weight", lambda s: s.convs[-1][0].__setitem__((0, 0, 0), s.convs[-1][0][0, 0, 0] + 1e-3)),
    ("conv bias", lambda s: s.convs[0][1].__setitem__(0, s.convs[0][1][0] + 1e-3)),
    ("proj", lambda s: s.proj[0].__setitem__((0, 0), s.proj[0][0, 0] + 1e-3)),
    ("mlp", lambda s: s.mlp[-1][1].__setitem__(-1, s.mlp[-1][1][-1] + 1e-3)),
    ("head", lambda s: s.head[0].__setitem__((3, 0), s.head[0][3, 0] + 1e-3)),
    ("l1.dt_s", lambda s: setattr(s.l1, "dt_s", s.l1.dt_s * 2)),
    ("l1.gravity_mps2", lambda s: setattr(s.l1, "gravity_mps2", 9.8)),
    ("l1.a_s", lambda s: setattr(s.l1, "a_s", s.l1.a_s * 2)),
    ("l1.law_gain", lambda s: setattr(s.l1, "law_gain", s.l1.law_gain * 2)),
    ("l1.alpha", lambda s: setattr(s.l1, "alpha", s.l1.alpha * 0.5)),
    ("l1.k_thrust", lambda s: setattr(s.l1, "k_thrust", s.l1.k_thrust * 0.5)),
    ("l1.latency_steps", lambda s: setattr(s.l1, "latency_steps", s.l1.latency_steps + 1)),
    (
        "l1.predictor_uses_filtered",
        lambda s: setattr(s.l1, "predictor_uses_filtered", not s.l1.predictor_uses_filtered),
    ),
]


@pytest.mark.parametrize("change", [c for _, c in IDENTIFYING], ids=[name for name, _ in IDENTIFYING])
def test_every_value_the_build_computes_with_changes_its_policy_id(built, change):
    import copy

    from datt.export.c_code import policy_id

    spec = built[0]
    other = copy.deepcopy(spec)
    change(other)
    assert policy_id(other) != policy_id(spec)
    assert policy_id(copy.deepcopy(spec)) == policy_id(spec)  # and nothing else does: a copy is the same build


def test_host_constants_are_the_headers():
    text = (resources.files("datt.export") / "app" / "datt_onboard.h").read_text()
    defines = {m[0]: int(m[1], 0) for m in re.findall(r"#define (DATT_\w+) (0x[0-9a-f]+|\d+)", text)}
    assert defines["DATT_PKT_POINTS"] == onboard.PKT_POINTS and defines["DATT_PKT_ACK"] == onboard.PKT_ACK
    assert defines["DATT_TABLE_MAX"] == onboard.TABLE_MAX and onboard.POINTS_PER_PACKET * 12 + 4 <= 30
    for name in ("IDLE", "TRACK", "LAND", "DONE", "ABORTED", "REFUSED"):
        assert defines[f"DATT_{name}"] == getattr(onboard, name)
    for name in ("OK", "RANGE", "BUSY", "MALFORMED"):
        assert defines[f"DATT_ACK_{name}"] == getattr(onboard, f"ACK_{name}")
    glue = (resources.files("datt.export") / "app" / "app_datt.c").read_text()
    assert [n for n, *_ in onboard.PARAMS] == re.findall(r"PARAM_ADD\([^,]+, (\w+),", glue)
    assert [n for n, _ in onboard.LOGS] == re.findall(r"LOG_ADD\(\w+, (\w+),", glue)


def test_upload_packets_are_acknowledged_or_refused(built):
    app = OnboardApp(built[4], controller_id=6)
    assert app.self_test_ok
    ack = app.receive(onboard.points_packet(7, [(1.0, 2.0, 3.0)]))
    assert onboard.parse_ack(ack) == (7, onboard.ACK_OK) and app.status().n_received == 1
    app.receive(onboard.points_packet(7, [(1.0, 2.0, 3.0)]))  # a resent packet counts once
    assert app.status().n_received == 1
    assert onboard.parse_ack(app.receive(onboard.points_packet(1023, [(0, 0, 0)] * 2))) == (1023, onboard.ACK_RANGE)
    assert onboard.parse_ack(app.receive(b"\x01\x00\x00\x03" + bytes(36))) == (0, onboard.ACK_MALFORMED)
    assert onboard.parse_ack(app.receive(b"\x02")) == (0, onboard.ACK_MALFORMED)
    assert onboard.parse_ack(app.receive(struct.pack("<BHB", 1, 0, 1))) == (0, onboard.ACK_MALFORMED)  # no points


def test_start_is_refused_on_an_incomplete_table_or_bad_parameters(built):
    app = loaded(built, n_points=40)
    app.set("nPoints", 42)  # two points never arrived
    app.run_request = 1
    assert app.tick([0, 0, 1], [0, 0, 0], LEVEL) == (None, False) and app.phase == onboard.REFUSED
    app = loaded(built, track_steps=40)  # the track needs track_steps + 1 points
    app.run_request = 1
    app.tick([0, 0, 1], [0, 0, 0], LEVEL)
    assert app.phase == onboard.REFUSED


def test_one_step_is_the_policy_on_the_table_window_with_the_thrust_map(built):
    spec, controller, _, _, lib, merged = built
    app = loaded(built)
    app.run_request = 1
    pos, vel, quat = [0.3, -0.2, 1.1], [0.5, 0.1, -0.2], [0.9, 0.1, -0.2, 0.3]
    quat = list(np.array(quat) / np.linalg.norm(quat))
    sp, relax = app.tick(pos, vel, quat)
    assert sp is not None and not relax and app.phase == onboard.TRACK
    s = app.status()
    # the window: the table at steps 0, 3, ..., 27 (DATT_REF_STRIDE 3); the policy sees pos - origin
    table = torch.tensor([(0.01 * k, -0.02 * k, 0.005 * k) for k in range(40)])
    window = table[torch.arange(10) * 3].unsqueeze(0)
    rel = torch.tensor([[0.3, -0.2, 0.1]])
    with torch.no_grad():
        d_hat = torch.tensor([list(s.d_hat)])  # one L1 step from the reset (the command sent: hover)
        hover = torch.tensor([[9.81, 0.0, 0.0, 0.0]])
        commands = merged.env.obs.action_history  # the checkpoint's layout (the default export's: 4)
        hist = ((hover - controller.center) / controller.half).repeat(1, commands)  # the history after a start
        from datt.export import reference_action

        want = reference_action(
            controller,
            merged.env.obs,
            {"pos_m": rel, "vel_mps": torch.tensor([vel]), "quat": torch.tensor([quat], dtype=torch.float32),
             "ref_m": window, "d_hat": d_hat, "cmd_hist": hist},
        )[0].numpy()  # fmt: skip
    thrust = ThrustMap()  # the app's defaults are the firmware's map for 34 g
    want[0] = min(want[0], thrust.ceiling_mps2)  # the app keeps the thrust the map can deliver
    assert np.abs(np.array(list(s.action)) - want).max() < 1e-4
    assert list(s.ref_m) == pytest.approx([0.0, 0.0, 0.0])
    assert s.error_m == pytest.approx(math.dist(rel[0].tolist(), (0, 0, 0)), abs=1e-5)
    assert abs(sp.thrust - thrust.command(float(s.action[0]))) <= 1
    # the firmware's setpoint convention: roll = wx, pitch = -wy, yaw = wz, deg/s, within the rate limits
    roll, pitch, yaw = (
        float(np.clip(sign * math.degrees(s.action[k + 1]), -lim, lim))
        for k, (sign, lim) in enumerate(zip((1, -1, 1), thrust.p.max_rate_degps))
    )
    assert (sp.roll_degps, sp.pitch_degps, sp.yaw_degps) == pytest.approx((roll, pitch, yaw), rel=1e-5)


def test_thrust_above_the_maps_ceiling_is_sent_and_remembered_as_the_ceiling(built):
    """The map clips at max_command: the app's action, L1 input and setpoint use the ceiling."""
    app = loaded(built, hoverCmd=55000.0, maxCmd=56000)  # ceiling = g + slope * 1000 ≈ 10.03 m/s²
    app.run_request = 1
    half = math.radians(40) / 2  # tilted and below the reference: the policy asks for far more
    sp, _ = app.tick([0.0, 0.0, 0.0], [0.0, 0.0, -2.0], [math.cos(half), math.sin(half), 0.0, 0.0])
    ceiling = 9.81 + 4 * 0.12 / (65535 * 0.034) * 1000
    assert app.status().action[0] == pytest.approx(ceiling, rel=1e-5) and sp.thrust == 56000


def test_track_then_land_ramp_then_motors_off(built):
    app = loaded(built, n_points=40, track_steps=20, landS=0.2, landHoldS=0.1)  # ramp 10 steps, hold 5
    app.run_request = 1
    phases, refs = [], []
    for _ in range(40):
        sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL)
        phases.append(app.phase)
        refs.append(list(app.status().ref_m))
    assert phases[:19] == [onboard.TRACK] * 19 and phases[19] == onboard.LAND  # after step 19 (the 20th)
    assert phases[34] == onboard.DONE and phases[33] == onboard.LAND  # 15 landing steps
    assert refs[19] == pytest.approx([0.19, -0.38, 0.095], abs=1e-6)  # the table at step 19
    start = (0.2, -0.4, 0.1)  # the table at track_steps: the ramp's start
    assert refs[20] == pytest.approx(start, abs=1e-6)
    assert refs[25][2] == pytest.approx(0.1 + 0.5 * (-0.95 - 0.1), abs=1e-5)  # half way down
    assert refs[31][2] == pytest.approx(-0.95, abs=1e-6)  # held
    assert sp is not None and sp.stop == 1 and sp.thrust == 0  # DONE: stop setpoints until run = 0
    app.run_request = 0
    sp, relax = app.tick([0.0, 0.0, 0.0], [0, 0, 0], LEVEL)
    assert relax and sp is None and app.phase == onboard.IDLE


def test_an_uncertain_position_lands_from_where_the_reference_was(built):
    """Position variance above maxPosStdM² (no measurements arriving): stop tracking, ramp down
    from the current reference point; a variance at the limit flies on."""
    app = loaded(built, n_points=40, track_steps=30, landS=0.2, landHoldS=0.1, maxPosStdM=0.1)
    app.run_request = 1
    for _ in range(5):
        app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL, pos_var_m2=0.01)  # std 0.1 m: on the limit
    assert app.phase == onboard.TRACK and app.status().step == 5
    app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL, pos_var_m2=0.0101)
    s = app.status()
    assert app.phase == onboard.LAND and s.landed_early == 1
    assert list(s.ref_m) == pytest.approx([0.05, -0.10, 0.025], abs=1e-6)  # the table at step 5: the ramp's start
    for _ in range(5):
        app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL, pos_var_m2=0.0)  # measurements back: it keeps landing
    assert app.phase == onboard.LAND
    assert app.status().ref_m[2] == pytest.approx(0.025 + 0.5 * (-0.95 - 0.025), abs=1e-5)


def test_the_uncertainty_limit_is_a_checked_setting():
    from datt.deploy.schema import deploy_params
    from datt.errors import ConfigError

    cfg = compose("deploy", ["deploy.flight.onboard_max_pos_std_m=-1"])
    with pytest.raises(ConfigError, match=r"deploy.flight.onboard_max_pos_std_m: must be a finite number in \[0, 1\]"):
        deploy_params(cfg.deploy)


@pytest.mark.parametrize(
    "pos, quat",
    [
        ([0.0, 0.0, 1.0], [math.cos(math.radians(40)), 0.0, math.sin(math.radians(40)), 0.0]),  # pitched 80 deg
        ([0.0, math.nan, 1.0], LEVEL),
    ],
    ids=["tilt", "nan"],
)
def test_abort_stops_the_motors(built, pos, quat):
    app = loaded(built)
    app.run_request = 1
    sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL)
    assert app.phase == onboard.TRACK and sp.stop == 0
    sp, _ = app.tick(pos, [0, 0, 0], quat)
    assert app.phase == onboard.ABORTED and sp.stop == 1 and sp.thrust == 0


@pytest.mark.parametrize(
    "quat, age_s",
    [([0.0, 0.0, 0.0, 0.0], 0.0), ([0.9, 0.0, 0.0, 0.0], 0.0), ([1.0, 0.0, 0.0, math.nan], 0.0), (LEVEL, 0.011),
     (LEVEL, math.inf)],
    ids=["zero quaternion (never written)", "not unit", "nan", "stale", "hook never ran"],
)  # fmt: skip
def test_the_app_refuses_to_start_on_a_state_it_cannot_trust(built, quat, age_s):
    app = loaded(built)
    app.run_request = 1
    sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], quat, state_age_s=age_s)
    assert app.phase == onboard.REFUSED and sp is None


def test_a_stale_state_in_flight_pushes_no_setpoint(built):
    """The commander's watchdog then levels the vehicle and stops it; the app does not fly blind."""
    app = loaded(built)
    app.run_request = 1
    sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL, state_age_s=0.0)
    assert sp is not None and app.phase == onboard.TRACK
    step = app.status().step
    sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL, state_age_s=0.05)
    assert sp is None and app.status().step == step
    sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], LEVEL, state_age_s=0.0)
    assert sp is not None and app.status().step == step + 1


def test_a_74_degree_tilt_flies_on(built):
    app = loaded(built)
    app.run_request = 1
    half = math.radians(74) / 2
    sp, _ = app.tick([0.0, 0.0, 1.0], [0, 0, 0], [math.cos(half), math.sin(half), 0.0, 0.0])
    assert app.phase == onboard.TRACK and sp.stop == 0


# -- flights with the policy onboard -----------------------------------------------------------


def fly(tmp_path, overrides=()):
    pytest.importorskip("cflib")
    from datt.tasks.deploy import run_deploy

    from . import SHORT_FLIGHT, reference_overrides

    cfg = compose(
        "deploy",
        [f"deploy.uri=udp://127.0.0.1:{next(ports)}", *SHORT_FLIGHT, *reference_overrides(overrides), *overrides],
    )
    seen = {}
    summary = run_deploy(cfg, run_dir=tmp_path, server_hook=lambda server, runner: seen.setdefault("server", server))
    return summary, seen["server"]


@pytest.mark.flight
def test_link_loss_mid_track_the_app_finishes_and_lands(tmp_path):
    """The radio goes silent 1 s into the track: no setpoint, no mocap, no e-stop from the host.
    The app (Lighthouse deck: its own position) flies the rest of the track and lands."""
    summary, server = fly(
        tmp_path,
        ["deploy.onboard=true", "deploy.server.radio_cut_after_start_s=1.0", "deploy.server.decks=[bcLighthouse4]"],
    )
    assert summary["outcome"].startswith("link lost: during the onboard flight")
    assert server.radio_down and server.app.phase == onboard.DONE
    assert server.cmd[3] == 0 and not server.locked and server.true_state()["pos_m"][2] < 0.1
    end = server.app.status()
    landed = np.array(server.true_state()["pos_m"][:2])
    assert np.linalg.norm(landed - (np.array(end.ref_m[:2]))) < 0.15  # where the reference ended
    # the host sent nothing past the cut, and the vehicle got no e-stop watchdog at all
    assert server.estop_watchdog_t is None
    # it said once that the app flies on by itself (not once per tick of the silence)
    flies_on = [
        e for e in summary["events"] if e["text"] == "no fresh state from the vehicle: the onboard app flies on"
    ]
    assert [e["kind"] for e in flies_on] == ["warning"]


@pytest.mark.flight
def test_an_app_whose_log_never_arrives_is_not_started_and_the_pid_lands(tmp_path):
    """The app's log block (phase, step, error) never reaches the host: the host could not see
    the app abort or land, so it does not hand the flight over; the PID, hovering, lands."""
    pytest.importorskip("cflib")
    from datt.tasks.deploy import run_deploy

    from . import SHORT_FLIGHT

    seen = {}

    def deaf_to_the_app(server, runner):
        seen["server"] = server
        runner._on_app_log = lambda values: None  # followed from before arming; no sample arrives

    cfg = compose("deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", "deploy.onboard=true", *SHORT_FLIGHT])
    summary = run_deploy(cfg, run_dir=tmp_path, server_hook=deaf_to_the_app)
    server = seen["server"]
    assert summary["outcome"] == (
        "landed early: the onboard app's log (block datt) has not reached the host since before arming: "
        "the app is not started (the host could not watch it)"
    ), summary["outcome"]
    phases = [e["text"] for e in summary["events"] if e["kind"] == "phase"]
    assert "TRACK" not in phases and phases[-2:] == ["LAND", "DISARM"]
    assert server.app.phase == onboard.IDLE and not server.app.run_request  # never started
    assert server.cmd[3] == 0 and server.true_state()["pos_m"][2] < 0.1


@pytest.mark.flight
def test_the_app_flies_on_the_hover_trims_map(tmp_path):
    """A vehicle 10 % heavier with motors 10 % weaker than the map: the host's trim after the
    takeoff's hover goes to the app with the start (``datt.hoverCmd``, ``datt.slope``, then
    ``datt.run``), so the app flies the rescaled map: while it tracks its parameters are the
    trim's (float32), ~22 % above the nominal map's hover command, and its ceiling is
    ``deploy.thrust.app_max_command`` (65535: its setpoints skip the legacy commander's 60000, and
    this vehicle needs more in the star's first second); after the flight the host restores what
    the vehicle held."""

    pytest.importorskip("cflib")
    from datt.deploy.thrust import ThrustMap
    from datt.tasks.deploy import run_deploy

    from . import SHORT_FLIGHT

    seen = {"tracking": [], "ceiling": [], "thrust": []}

    def watch(server, runner):
        def sample():
            while runner.phase != "DISARM":
                if runner.phase == "TRACK" and server.app is not None and server.app.phase == onboard.TRACK:
                    seen["tracking"].append((server.app.p.hover_command, server.app.p.slope_mps2_per_command))
                    seen["ceiling"].append(server.app.p.max_command)
                    seen["thrust"].append(server.cmd[3])
                runner.clock.sleep(0.05)
            seen["server"] = server

        runner.clock.start_thread(sample, "fault")

    # the training model's rate loop: on a stock vehicle's own loop this vehicle is at its hover trim's limit
    overrides = ["deploy.onboard=true", *HEAVY_WEAK]
    overrides.append("deploy.server.rate_loop=pi_first_order")
    overrides += [f"deploy.uri=udp://127.0.0.1:{next(ports)}", "deploy.flight.hover_s=1.0"]
    cfg = compose("deploy", [*SHORT_FLIGHT, *overrides])
    summary = run_deploy(cfg, run_dir=tmp_path, server_hook=watch)
    assert summary["outcome"] == "landed (onboard)", summary["outcome"]
    assert summary["controller"] == build_controller(cfg)[2]  # the run's labels reach the onboard flight's log
    trims = [e for e in summary["events"] if e["kind"] == "trim"]
    assert [e["phase"] for e in trims] == ["TAKEOFF", "HOVER"]  # the takeoff's hover, refined in HOVER
    f32 = lambda v: struct.unpack("<f", struct.pack("<f", v))[0]  # noqa: E731
    nominal = ThrustMap()
    assert len(seen["tracking"]) > 10
    for hover, slope in seen["tracking"]:
        assert hover == pytest.approx(f32(trims[-1]["hover_command"]), rel=1e-6)
        assert hover / nominal.hover_command > 1.18
        assert slope * hover == pytest.approx(nominal.slope * nominal.hover_command, rel=1e-5)  # through zero
    # its own ceiling, not the legacy commander's: the app's setpoints reach the motors unclamped
    assert set(seen["ceiling"]) == {65535} and max(seen["thrust"]) > 60000, max(seen["thrust"])
    app = seen["server"].app
    assert app.p.hover_command == pytest.approx(f32(nominal.hover_command), rel=1e-6)  # restored at close


@pytest.mark.slow
def test_onboard_star_tracks_within_ten_percent_of_off_board(tmp_path):
    """The full star both ways on the same simulated vehicle (deploy=sim defaults)."""
    full = ["deploy.flight.track_s=null"]
    off, _ = fly(tmp_path / "off", full)
    on, server = fly(tmp_path / "on", [*full, "deploy.onboard=true"])
    assert off["outcome"] == "landed" and on["outcome"] == "landed (onboard)"
    assert on["track_steps"] >= 495
    assert on["track_error_m"] <= 1.1 * off["track_error_m"]


def test_onboard_calibration_is_refused():
    from datt.deploy.schema import deploy_params
    from datt.errors import ConfigError

    cfg = compose("deploy", ["deploy.onboard=true", "deploy.mode=calibrate"])
    with pytest.raises(ConfigError, match="deploy.onboard: only deploy.mode=fly runs onboard"):
        deploy_params(cfg.deploy)


@pytest.mark.flight
def test_a_vehicle_without_the_app_is_refused_before_arming(tmp_path):
    pytest.importorskip("cflib")
    from datt.deploy.sim.server import PARAMS
    from datt.tasks.deploy import run_deploy

    def stock_firmware(server, runner):
        server.app, server.param_toc = None, PARAMS  # as flashed without the app

    cfg = compose("deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", "deploy.onboard=true"])
    summary = run_deploy(cfg, run_dir=tmp_path, server_hook=stock_firmware)
    assert summary["outcome"] == (
        "preflight failed: deploy.onboard: the vehicle's firmware has no DATT app (no parameter datt.run): "
        "build and flash it (datt export format=app; docs/onboard.md), or fly off-board (deploy.onboard=false)"
    )
    assert "ARM" not in [e["text"] for e in summary["events"] if e["kind"] == "phase"]


@pytest.mark.slow
@pytest.mark.flight
def test_link_loss_without_a_positioning_deck_lands_early(tmp_path):
    """Mocap only: the cut also stops the positions, the Kalman variance grows and the app lands
    from where it was instead of tracking on a drifting estimate."""
    summary, server = fly(
        tmp_path,
        ["deploy.onboard=true", "deploy.server.radio_cut_after_start_s=1.0", "deploy.flight.track_s=6.0"],
    )
    assert summary["outcome"].startswith("link lost: during the onboard flight")
    status = server.app.status()
    assert server.app.phase == onboard.DONE and status.landed_early == 1
    assert server.cmd[3] == 0 and server.true_state()["pos_m"][2] < 0.1
    # it landed off its landing point by the estimate's drift (0.2 m/s) over the ~1 s the variance
    # took to pass the limit and the 2 s landing: ~0.6 m; tracking the other 4 s first: ~1.4 m
    off_m = math.dist(server.true_state()["pos_m"][:2], list(status.ref_m[:2]))
    assert 0.3 < off_m < 0.9


@pytest.mark.flight
def test_an_app_with_another_policy_is_refused_before_arming(tmp_path):
    pytest.importorskip("cflib")
    from datt.tasks.deploy import run_deploy

    def other_checkpoint(server, runner):
        runner.onboard_policy_id ^= 1  # the host's checkpoint is not the one the app was built from

    cfg = compose("deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", "deploy.onboard=true"])
    summary = run_deploy(cfg, run_dir=tmp_path, server_hook=other_checkpoint)
    assert re.fullmatch(
        r"preflight failed: deploy.onboard: the vehicle's app carries policy 0x[0-9a-f]{8}, the checkpoint is "
        r"0x[0-9a-f]{8}: flash the app exported from it \(datt export format=app checkpoint=\.\.\.\), or pass the "
        r"checkpoint the app was built from",
        summary["outcome"],
    )
    assert "ARM" not in [e["text"] for e in summary["events"] if e["kind"] == "phase"]


@pytest.mark.flight
def test_a_track_longer_than_the_app_holds_is_refused_before_arming(tmp_path):
    pytest.importorskip("cflib")
    from datt.tasks.deploy import run_deploy

    cfg = compose(
        "deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", "deploy.onboard=true", "deploy.flight.track_s=30"]
    )
    summary = run_deploy(cfg, run_dir=tmp_path)
    assert summary["outcome"] == (
        "preflight failed: deploy.flight.track_s: the app holds 1024 reference points (19.9 s of track at 50 Hz); "
        "this track needs 1501"
    )
    # a setting refused the flight: the user's to change (exit 2), not the vehicle's failure (4)
    assert summary["outcome_kind"] == "refused_setting"


@pytest.mark.flight
def test_the_references_whole_episode_is_checked_against_the_app_too(tmp_path):
    """``deploy.flight.track_s: null`` (the default) flies the reference's episode: 22 s of it
    (1100 steps) do not fit the app's table either, and the refusal says how many points it needs."""
    pytest.importorskip("cflib")
    from datt.tasks.deploy import run_deploy

    overrides = ["deploy.onboard=true", "deploy.flight.track_s=null", "env.episode_steps=1100"]
    cfg = compose("deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", *overrides])
    summary = run_deploy(cfg, run_dir=tmp_path)
    assert summary["outcome"].startswith(
        "preflight failed: deploy.flight.track_s: the app holds 1024 reference points (19.9 s of track at 50 Hz); "
        "this track needs 11"
    ), summary["outcome"]
    assert summary["outcome_kind"] == "refused_setting"


def test_the_onboard_preflight_checks_the_reference_up_to_the_last_tick_flown(tmp_path):
    """A reference that leaves the fence at t = 3.00 s: an onboard track of 3.00 s is refused for
    it, one of 2.98 s is not (the app flies no step past it) and is prepared: the table uploaded,
    stopped there, before arming."""
    pytest.importorskip("cflib")
    from datt.tasks.deploy import run_deploy

    ref = tmp_path / "jump.csv"
    ref.write_text("t,x,y,z\n0,0,0,0\n2.98,0,0,0\n3.0,3.0,0,0\n10,3.0,0,0\n")

    def stop_after_the_upload(server, runner):
        prepare = runner._onboard_prepare

        def then_stop(track):
            prepare(track)
            raise KeyboardInterrupt("after the upload")

        runner._onboard_prepare = then_stop

    outcomes = []
    for track_s in ("3.0", "2.98"):
        run_dir = tmp_path / track_s
        overrides = ["deploy.onboard=true", "traj=csv", f"traj.path={ref}", f"deploy.flight.track_s={track_s}"]
        cfg = compose("deploy", [f"deploy.uri=udp://127.0.0.1:{next(ports)}", *overrides])
        outcomes.append(run_deploy(cfg, run_dir=run_dir, server_hook=stop_after_the_upload)["outcome"])
    assert outcomes == [
        "preflight failed: deploy.safety.geofence_max_m: the reference leaves the geofence at t=3.00 s "
        "(x=3.00 m; fence -2.00..2.00 m)",
        "stopped before arming (after the upload): nothing was armed",
    ]


def test_only_an_acknowledgement_is_read_as_one():
    """parse_ack: type byte PKT_ACK and at least index (2 bytes) and status; an upload packet,
    another type or a short ACK is not an acknowledgement (the host must not drop a pending point)."""
    assert onboard.parse_ack(bytes([onboard.PKT_ACK, 0x34, 0x12, onboard.ACK_BUSY])) == (0x1234, onboard.ACK_BUSY)
    assert onboard.parse_ack(bytes([onboard.PKT_ACK, 5, 0, 0, 99])) == (5, onboard.ACK_OK)  # trailing bytes ignored
    assert onboard.parse_ack(onboard.points_packet(0, [(0.0, 0.0, 0.0)])) is None
    assert onboard.parse_ack(bytes([0x82, 5, 0, 0])) is None
    assert onboard.parse_ack(bytes([onboard.PKT_ACK, 5, 0])) is None
    assert onboard.parse_ack(b"") is None


def test_an_unanswered_upload_sends_each_packet_ten_times_then_fails():
    """Upload's defaults: a packet is sent at most 10 times (waiting 0.1 s for its answer), then
    the upload fails naming the point; a window of packets goes out together."""
    sent, failure = [], []
    upload = onboard.Upload(lambda data: sent.append((0.0, data)), [(0.0, 0.0, 0.0)] * 4)

    def run() -> None:
        try:
            upload.run()
        except RuntimeError as exc:
            failure.append(str(exc))

    uploader = threading.Thread(target=run, daemon=True)  # an upload that never gives up must fail, not hang
    uploader.start()
    uploader.join(timeout=10.0)  # 10 windows of 0.1 s
    assert not uploader.is_alive(), "the upload kept resending: it never gave up"
    assert failure == ["point 0: no acknowledgement after 10 sends"]
    assert upload.timeout_s == 0.1 and upload.attempts == 10
    indices = [struct.unpack("<BHB", data[:4])[1] for _, data in sent]
    assert indices == [0, 2] * 10  # both packets of the table in every window


def test_the_upload_takes_up_to_table_max_points_and_windows_within_the_app_channels_queue():
    acked = []

    def answer(data):  # the app acknowledges every packet at once
        index = struct.unpack("<BHB", data[:4])[1]
        acked.append(index)
        upload.on_packet(bytes([onboard.PKT_ACK, index & 0xFF, index >> 8, onboard.ACK_OK]))

    upload = onboard.Upload(answer, [(0.0, 0.0, 0.0)] * onboard.TABLE_MAX)
    upload.run(window=1)  # one packet at a time is a window too
    assert acked == list(range(0, onboard.TABLE_MAX, onboard.POINTS_PER_PACKET))
    with pytest.raises(ValueError, match=rf"^the reference has {onboard.TABLE_MAX + 1} points; the app holds at most"):
        onboard.Upload(answer, [(0.0, 0.0, 0.0)] * (onboard.TABLE_MAX + 1))
    for window in (0, onboard.APP_CHANNEL_RX_QUEUE + 1):
        with pytest.raises(ValueError, match=rf"^upload window {window}: the app channel queues 1\.\."):
            onboard.Upload(answer, [(0.0, 0.0, 0.0)] * 2).run(window=window)


def test_refused_points_fail_the_upload_naming_each_status():
    def refuse(data):
        index = struct.unpack("<BHB", data[:4])[1]
        upload.on_packet(bytes([onboard.PKT_ACK, index, 0, onboard.ACK_BUSY if index else onboard.ACK_RANGE]))

    upload = onboard.Upload(refuse, [(0.0, 0.0, 0.0)] * 4, timeout_s=0.01)
    busy, out_of_range = onboard.ACK_BUSY, onboard.ACK_RANGE
    message = f"point 0: the app answered status {out_of_range}; point 2: the app answered status {busy}"
    with pytest.raises(RuntimeError, match=f"^{re.escape(message)}$"):
        upload.run()


class _FakeClock:
    """The upload's clock, moving only when the upload waits (to the next acknowledgement due, or
    its deadline); an acknowledgement is delivered ``ack_after_s`` after its packet was sent (as
    the radio answers, but deterministic)."""

    def event(self):
        import threading

        return threading.Event()

    def wait(self, event, timeout_s: float) -> bool:
        due = min((t for t, _ in self.due), default=self.now + timeout_s)
        self.sleep(max(0.0, min(due, self.now + timeout_s) - self.now))
        return event.is_set()

    def __init__(self, ack_after_s: float) -> None:
        self.now, self.ack_after_s, self.due = 0.0, ack_after_s, []
        self.upload = None

    def monotonic(self) -> float:
        return self.now

    def sleep(self, dt: float) -> None:
        self.now += dt
        for t, ack in [d for d in self.due if d[0] <= self.now]:
            self.due.remove((t, ack))
            self.upload.on_packet(ack)

    def send(self, data: bytes) -> None:
        index = struct.unpack("<BHB", data[:4])[1]
        ack = bytes([onboard.PKT_ACK, index & 0xFF, index >> 8, onboard.ACK_OK])
        self.due.append((self.now + self.ack_after_s, ack))


def test_the_next_window_goes_out_as_soon_as_the_last_is_acknowledged(monkeypatch):
    """Answers 5 ms after each send: every packet goes once, and each window waits for its answers
    (woken by each answer), not for the 0.1 s timeout. On the upload's own clock, not the wall's."""
    clock = _FakeClock(ack_after_s=0.005)
    table = [(0.0, 0.0, 0.0)] * (onboard.POINTS_PER_PACKET * 25)  # 25 packets: windows of 10, 10, 5
    sent = []
    upload = onboard.Upload(lambda data: (sent.append(data), clock.send(data)), table, clock=clock)
    clock.upload = upload
    upload.run()
    indices = [struct.unpack("<BHB", data[:4])[1] for data in sent]
    assert indices == list(range(0, len(table), onboard.POINTS_PER_PACKET))  # each packet once
    assert clock.now == pytest.approx(3 * 0.005)  # three windows, each woken by its last answer


def test_a_repeated_acknowledgement_is_harmless():
    """A late answer to a packet already answered (its resend crossed the first answer)."""
    upload = onboard.Upload(lambda data: None, [(0.0, 0.0, 0.0)])
    ack = bytes([onboard.PKT_ACK, 0, 0, onboard.ACK_OK])
    upload.on_packet(ack)
    upload.on_packet(ack)
    assert upload.pending == {} and upload.errors == []


@pytest.mark.flight
def test_the_app_is_not_started_on_a_reference_beyond_its_ceiling(tmp_path):
    """Onboard the same thrust check runs after the trim, at the app's own ceiling: with the app
    capped at 60000 the transfer vehicle (10 % heavy, motors 10 % weak) cannot follow the star;
    the app is never started (``datt.run`` stays 0) and the PID lands from the hover."""
    summary, server = fly(tmp_path, ["deploy.onboard=true", "deploy.thrust.app_max_command=60000", *HEAVY_WEAK])
    assert summary["outcome_kind"] == "refused_reference", summary["outcome"]
    assert summary["track_steps"] == 0 and server.app.phase == onboard.IDLE
    assert "deploy.flight.infeasible=slow" in summary["outcome"]
