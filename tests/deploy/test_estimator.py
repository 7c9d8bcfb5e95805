"""The onboard estimator as the firmware runs it, and the runner that feeds it: the
complementary filter drops external positions, the Kalman filter is selected and read back at
connect, mocap samples are sent once and never stale, and the mocap attitude aligns onboard yaw."""

import math
import struct
import time

import pytest

pytest.importorskip("cflib")

from datt.deploy import crtp  # noqa: E402
from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams  # noqa: E402
from datt.errors import ConfigError  # noqa: E402

from . import fly_sim, ports  # noqa: E402

pytestmark = pytest.mark.flight


def estimate(server):
    x, y, z, vx, vy, vz, qx, qy, qz, qw, *_ = server._estimate()
    return (x, y, z), (qw, qx, qy, qz)


def yaw_deg(q):
    w, x, y, z = q
    return math.degrees(math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)))


def hovering_server(**params):
    server = SimCrazyflie(SimCrazyflieParams(port=next(ports), start_pos_m=(0.4, -0.3, 0.0), **params))
    return server


def test_complementary_estimator_drops_external_positions():
    server = hovering_server()  # estimator 0 (any) and no deck: the firmware runs the complementary filter
    assert server.estimator == 1
    server._on_localization(0, struct.pack("<fff", 0.5, -0.25, 0.0))
    (x, y, z), _ = estimate(server)
    assert (x, y) == (0.0, 0.0)  # not the true (0.4, -0.3), not the sent (0.5, -0.25)
    server.params["stabilizer.estimator"] = 2
    server._on_localization(0, struct.pack("<fff", 0.5, -0.25, 0.0))
    (x, y, z), _ = estimate(server)
    var = 100.0**2  # never measured: the firmware's initial xy variance (stdDevInitialPosition_xy 100 m)
    gain = var / (var + 0.01**2)  # measurement std 0.01 m
    assert (x, y) == pytest.approx((0.4 + gain * 0.1, -0.3 + gain * 0.05), abs=1e-9)


def test_kalman_estimate_drifts_without_measurements():
    server = hovering_server(dead_reckoning_drift_mps=0.2)
    server.params["stabilizer.estimator"] = 2
    server._on_localization(0, struct.pack("<fff", 0.4, -0.3, 0.0))
    for _ in range(50):  # 1 s without a measurement
        server._physics_step()
    (x, y, _), _ = estimate(server)
    assert x == pytest.approx(0.4 + 0.2, abs=1e-6) and y == pytest.approx(-0.3, abs=1e-6)


def test_a_positioning_deck_selects_kalman_and_measures_the_position():
    server = hovering_server(decks=("bcLighthouse4",))
    assert server.estimator == 2
    for _ in range(50):
        server._physics_step()
    (x, y, _), _ = estimate(server)
    assert (x, y) == pytest.approx((0.4, -0.3), abs=1e-6)
    with pytest.raises(ConfigError, match=r"^deploy.server.decks: unknown deck 'bcRadar'; allowed: "):
        hovering_server(decks=("bcRadar",))


def test_extpose_aligns_onboard_yaw():
    server = hovering_server(boot_yaw_deg=25.0)
    server.params["stabilizer.estimator"] = 2
    _, q = estimate(server)
    assert yaw_deg(q) == pytest.approx(-25.0, abs=1e-4)  # true heading 0, onboard relative to boot
    server._on_localization(0, struct.pack("<fff", 0.4, -0.3, 0.0))  # positions alone do not fix it
    assert yaw_deg(estimate(server)[1]) == pytest.approx(-25.0, abs=1e-4)
    server._on_localization(1, struct.pack("<Bfffffff", 8, 0.4, -0.3, 0.0, 0.0, 0.0, 0.0, 1.0))
    assert yaw_deg(estimate(server)[1]) == pytest.approx(0.0, abs=1e-4)


def test_extpose_golden_bytes_reach_the_simulated_filter():
    from cflib.crazyflie.localization import Localization

    from .test_protocol import Capture

    cf = Capture()
    Localization(cf).send_extpose([0.5, -1.0, 1.25], [0.0, 0.0, 0.2588190, 0.9659258])
    port, ch, data = crtp.split(cf.sent[0])
    assert (port, ch, data[0]) == (crtp.PORT_LOCALIZATION, 1, 8)
    server = hovering_server(boot_yaw_deg=10.0)
    server.params["stabilizer.estimator"] = 2
    server._on_localization(ch, data)
    (x, y, z), q = estimate(server)
    # fused with gain 1e4 / (1e4 + 1e-4) (the filter's xy variance is still the initial 100² m²)
    assert (x, y) == pytest.approx((0.5, -1.0), abs=1e-4)
    assert server.yaw_aligned and server.extpos_rx[-1][1] == pytest.approx((0.5, -1.0, 1.25))


def _fly(tmp_path, *overrides):
    return fly_sim(tmp_path, next(ports), overrides)


def test_connect_selects_kalman_and_rate_mode_and_close_restores_angle_mode(tmp_path):
    summary, server, _ = _fly(tmp_path)
    assert summary["outcome"] == "landed"
    estimators = [text for _, text in server.events if text.startswith("param stabilizer.estimator")]
    assert estimators == ["param stabilizer.estimator = 2", "param stabilizer.estimator = 1"]  # set, then restored
    assert server.params["stabilizer.estimator"] == 1  # as it booted (no positioning deck: complementary)
    modes = [text for _, text in server.events if text.startswith("param flightmode.stabMode")]
    # rate mode for the flight, angle mode restored on close (for whoever flies it next)
    assert modes[:2] == ["param flightmode.stabModeRoll = 0", "param flightmode.stabModePitch = 0"]
    assert modes[-2:] == ["param flightmode.stabModePitch = 1", "param flightmode.stabModeRoll = 1"]
    assert server.yaw_aligned  # the default simulated vehicle booted 25 deg off the mocap x axis


def test_stale_mocap_is_never_sent(tmp_path):
    """After the mocap stream stops, the runner sends nothing more (it used to resend the last
    sample every tick, pinning the Kalman estimate where the vehicle had been)."""
    summary, server, runner = _fly(tmp_path, "deploy.mocap.dropout_after_s=3.5")
    assert summary["outcome"].startswith("landed early: mocap stale"), summary["outcome"]
    cut = runner.mocap._t0 + 3.5
    latest_fresh = cut + runner.mocap.latency_s + runner.safety.max_mocap_age_s + 0.1
    late = [t for t, _ in server.extpos_rx if t > latest_fresh]
    assert server.extpos_rx and not late, f"{len(late)} stale samples sent"
    sent = [p for _, p in server.extpos_rx]
    assert len(sent) > 100


def test_without_mocap_the_preflight_passes_once_the_filter_settles_not_at_its_timeout(tmp_path):
    """A positioning deck and no mocap source: the estimate has nothing to agree with, so the
    preflight passes as soon as the Kalman filter has settled (well within a second here), not
    after waiting out ``deploy.flight.preflight_timeout_s``. Stopped there, before arming."""
    took = {}

    def stop_after_the_preflight(server, runner):
        preflight = runner._preflight

        def timed():
            t0 = time.monotonic()
            preflight()
            took["s"] = time.monotonic() - t0
            raise KeyboardInterrupt("after the preflight")

        runner._preflight = timed

    overrides = [
        "deploy.mocap.source=none",
        "deploy.server.decks=[bcLighthouse4]",
        "deploy.flight.preflight_timeout_s=30",
    ]
    summary, server, _ = fly_sim(tmp_path, next(ports), overrides, hook=stop_after_the_preflight)
    assert summary["outcome"] == "stopped before arming (after the preflight): nothing was armed"
    assert [e["text"] for e in summary["events"] if e["kind"] == "preflight ok"] == ["battery 4.10 V"]
    assert took["s"] < 15, took  # half the timeout: the filter settled long before it
    assert not server.armed


@pytest.mark.slow  # a real-time flight that 4 test workers on 2 cores can starve into a tilt KILL; alone it lands
def test_no_mocap_needs_a_positioning_deck(tmp_path):
    with pytest.raises(ConfigError, match=r"^deploy.mocap.source: none, and the vehicle has no positioning deck"):
        _fly(tmp_path, "deploy.mocap.source=none")
    summary, server, _ = _fly(tmp_path / "lh", "deploy.mocap.source=none", "deploy.server.decks=[bcLighthouse4]")
    assert summary["outcome"] == "landed" and server.estimator == 2


def test_kalman_variance_shrinks_with_measurements_and_grows_without():
    """The logged position variance: reset as the firmware does (kalman_core_params_defaults.h:
    100² m² in x and y, 1 m² in z), the scalar Kalman update v r / (v + r) per measurement
    (r = locSrv.extPosStdDev²), growth of 0.01 m²/s between them."""
    server = hovering_server()
    server.params["stabilizer.estimator"] = 2
    server._on_param(2, struct.pack("<H", _param_id("kalman.resetEstimation")) + b"\x01")
    assert server.kalman_var_m2 == [1e4, 1e4, 1.0] and server.params["kalman.resetEstimation"] == 0
    r = 0.01**2
    server._on_localization(0, struct.pack("<fff", 0.4, -0.3, 0.0))
    assert server.kalman_var_m2[0] == pytest.approx(1e4 * r / (1e4 + r))
    assert server.kalman_var_m2[2] == pytest.approx(1.0 * r / (1.0 + r))
    before = server.kalman_var_m2[0]
    for _ in range(50):
        server._physics_step()
    assert server.kalman_var_m2[0] == pytest.approx(before + 0.01 * 50 * server.p.dt_s)
    # the reset put the estimate at the origin; one measurement (gain ~1) moved it back
    assert estimate(server)[0][:2] == pytest.approx((0.4 + 0.2, -0.3), abs=1e-4)


def _param_id(name):
    from datt.deploy.sim.server import PARAMS

    return next(i for i, (g, n, _, _) in enumerate(PARAMS) if f"{g}.{n}" == name)
