"""Firmware behaviour of the simulated Crazyflie, driven through real cflib: thrust lock, setpoint
watchdog (level after 0.5 s, motors off after 2 s), emergency stop, log block size limit."""

import math
import time

import pytest

pytest.importorskip("cflib")

from datt.deploy.link import CrazyflieLink, LinkError  # noqa: E402
from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams  # noqa: E402
from datt.deploy.thrust import ThrustMap  # noqa: E402

from . import ports  # noqa: E402


@pytest.fixture
def vehicle():
    port = next(ports)
    server = SimCrazyflie(SimCrazyflieParams(port=port)).start()
    link = CrazyflieLink(f"udp://127.0.0.1:{port}").connect()
    yield server, link
    link.close()
    server.stop()


def hold(link, seconds, thrust_cmd, roll=0.0):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        link.send_rates(roll, 0.0, 0.0, thrust_cmd)
        time.sleep(0.02)


def test_thrust_lock_until_a_zero_setpoint(vehicle):
    server, link = vehicle
    link.arm(True)
    climb = ThrustMap().command(12.0)
    hold(link, 0.3, climb)
    assert server.cmd[3] == 0 and server.true_state()["pos_m"][2] == 0.0  # locked: ignored
    hold(link, 0.1, 0)
    hold(link, 0.5, climb)
    assert server.cmd[3] == climb and server.true_state()["pos_m"][2] > 0.05


def test_the_legacy_commander_clamps_the_thrust_and_a_locked_setpoint_still_sets_the_rates(vehicle):
    """``crtp_commander_rpyt.c``: while locked a setpoint flies thrust 0 but its rates; after the
    unlock a thrust under MIN_THRUST (1000) flies 0 and one above MAX_THRUST (60000) flies 60000."""
    server, link = vehicle
    link.arm(True)
    hold(link, 0.1, 50000, roll=30.0)
    assert server.thrust_locked and server.cmd[3] == 0 and server.cmd[0] == pytest.approx(math.radians(30.0))
    hold(link, 0.1, 0)
    hold(link, 0.1, 999)
    assert server.cmd[3] == 0
    hold(link, 0.1, 1000)
    assert server.cmd[3] == 1000
    hold(link, 0.1, 65535)
    assert server.cmd[3] == 60000
    hold(link, 0.1, 60001)
    assert server.cmd[3] == 60000
    hold(link, 0.1, 59999)
    assert server.cmd[3] == 59999


def test_setpoint_watchdog_levels_then_cuts_the_motors(vehicle):
    server, link = vehicle
    link.arm(True)
    hold(link, 0.1, 0)
    hover = ThrustMap().command(9.81)
    hold(link, 0.8, ThrustMap().command(11.0))
    hold(link, 0.3, hover, roll=20.0)  # tilt it, then go silent
    assert abs(server.true_state()["quat"][1]) > 0.02
    time.sleep(1.2)  # > 0.5 s: levelled at the last thrust
    assert abs(server.true_state()["quat"][1]) < 0.02 and server.cmd[3] == hover
    time.sleep(1.2)  # > 2 s: motors off, and the supervisor locks (latched, as in flight)
    assert server.cmd[3] == 0 and server.locked
    assert any("watchdog" in text for _, text in server.events)
    hold(link, 0.3, hover)  # setpoints after the lock are ignored: only a restart unlocks
    assert server.cmd[3] == 0 and server.locked
    assert link.supervisor_bits() >> 6 & 1  # the supervisor reports Locked


def test_estop_watchdog_stops_the_motors_one_second_after_the_last_notification(vehicle):
    server, link = vehicle
    link.arm(True)
    hold(link, 0.1, 0)
    end = time.monotonic() + 0.6
    while time.monotonic() < end:  # setpoints with the watchdog, as the runner sends them
        link.send_rates(0.0, 0.0, 0.0, ThrustMap().command(10.5))
        link.send_estop_watchdog()
        time.sleep(0.02)
    last = server.estop_watchdog_t
    hold(link, 1.5, ThrustMap().command(10.5))  # setpoints keep coming, the watchdog does not
    assert server.emergency_stopped and server.cmd[3] == 0
    stop_t = next(t for t, text in server.events if text.startswith("emergency stop: no e-stop watchdog"))
    assert 1.0 <= stop_t - last <= 1.0 + 2 * server.p.dt_s


def test_arming_is_refused_while_locked_and_the_state_bitfield_says_why(vehicle):
    server, link = vehicle
    assert link.supervisor_bits() & 0b1011011 == 0b0000001  # can be armed; not armed, flying or locked
    link.emergency_stop()
    time.sleep(0.1)
    link.arm(True)
    time.sleep(0.1)
    assert not server.armed and link.supervisor_bits() >> 6 & 1


def test_a_lost_supervisor_request_is_asked_again_and_a_silent_vehicle_refused(vehicle):
    """The state request is sent again after each io_timeout_s without an answer (a lost packet
    costs half a second, not the flight); a vehicle that never answers is refused after
    SUPERVISOR_REQUESTS requests, with one line."""
    from datt.deploy.link import SUPERVISOR_REQUESTS

    server, link = vehicle
    answer, asked = server._on_supervisor, []

    def lose_first(ch, data, lost=1):
        asked.append(ch)
        if len(asked) > lost:
            answer(ch, data)

    server._on_supervisor = lose_first
    assert link.supervisor_bits() & 0b1 and asked == [0, 0]  # the first lost, the second answered
    asked.clear()
    server._on_supervisor = lambda ch, data: lose_first(ch, data, lost=99)
    with pytest.raises(LinkError, match=r"^preflight: the vehicle does not answer the supervisor state request"):
        link.supervisor_bits()
    assert len(asked) == SUPERVISOR_REQUESTS


def test_emergency_stop_locks_the_motors(vehicle):
    server, link = vehicle
    link.arm(True)
    hold(link, 0.1, 0)
    hold(link, 0.3, ThrustMap().command(12.0))
    link.emergency_stop()
    time.sleep(0.1)
    hold(link, 0.3, ThrustMap().command(12.0))
    assert server.emergency_stopped and server.cmd[3] == 0


def test_log_block_over_26_bytes_is_refused():
    import socket
    import struct

    from datt.deploy import crtp

    port = next(ports)
    with SimCrazyflie(SimCrazyflieParams(port=port)):
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.settimeout(1.0)
        items = b"".join(struct.pack("<BH", 0x07, i) for i in range(7))  # 7 floats = 28 bytes
        sock.sendto(crtp.packet(crtp.PORT_LOG, 1, bytes([6, 1]) + items), ("127.0.0.1", port))
        assert sock.recv(64) == crtp.packet(crtp.PORT_LOG, 1, bytes([6, 1, 7]))  # E2BIG, as the firmware
        sock.sendto(crtp.packet(crtp.PORT_LOG, 1, bytes([6, 2]) + items[:18]), ("127.0.0.1", port))
        assert sock.recv(64) == crtp.packet(crtp.PORT_LOG, 1, bytes([6, 2, 0]))  # 6 floats fit
        sock.close()


def test_connect_to_nothing_fails_with_one_line():
    link = CrazyflieLink(f"udp://127.0.0.1:{next(ports)}", connect_timeout_s=1.0)
    with pytest.raises(LinkError, match=r"^connect: udp://127.0.0.1:\d+: ") as info:
        link.connect()
    assert "\n" not in str(info.value)


def test_bad_io_timeout_fails_with_one_line():
    with pytest.raises(LinkError, match=r"^deploy.io_timeout_s: must be > 0, got 0$"):
        CrazyflieLink("udp://127.0.0.1:19999", io_timeout_s=0)


def test_a_stall_of_the_machine_is_measured_and_the_vehicle_catches_up():
    """The physics loop records how far it fell behind its clock while armed (a real vehicle
    never does: the flight tests fly again when the machine stalled the simulation), then runs
    the missed steps so that simulated time keeps up with the host's."""
    with SimCrazyflie(SimCrazyflieParams(port=next(ports))) as server:
        with server._lock:  # unarmed: on the ground, a stall changes nothing the vehicle flies
            time.sleep(0.2)
        time.sleep(0.1)
        assert server.physics_lag_max_s == 0.0
        server.armed = True
        with server._lock:  # the physics thread waits here, as when the machine stalls it
            start_sim_s = server.sim_time_s
            time.sleep(0.3)
        time.sleep(0.1)
        assert server.physics_lag_max_s > 0.25
        assert server.sim_time_s - start_sim_s == pytest.approx(0.4, abs=0.06)
        (stalled_at, lag), *_ = [(t, lag) for t, lag in server.physics_lags if lag > 0.25]
        assert server.physics_lag_max_until(stalled_at - lag + 0.01) == server.physics_lag_max_s
        assert server.physics_lag_max_until(stalled_at - lag - 0.05) < 0.25  # ended before the stall began


def test_the_stall_watch_starts_at_the_hosts_first_supervisor_request():
    """Unarmed, a stall counts once the host's preflight asked the supervisor for its state (from
    there the host's loop meets the vehicle's: a stall then can fail the arming or the flight)."""
    from datt.deploy import firmware

    with SimCrazyflie(SimCrazyflieParams(port=next(ports))) as server:
        with server._lock:
            time.sleep(0.2)
        time.sleep(0.1)
        assert server.physics_lag_max_s == 0.0 and server.physics_lags == []
        server._on_supervisor(0, bytes([firmware.SUPERVISOR_CMD_GET_STATE_BITFIELD]))
        with server._lock:
            time.sleep(0.2)
        time.sleep(0.1)
        assert not server.armed and server.physics_lag_max_s > 0.15


@pytest.mark.parametrize(
    "message, expected",
    [
        (None, "no answer within 3 s (vehicle off, out of range, or another channel/address?)"),
        (
            "Couldn't load link driver: Cannot find a Crazyradio Dongle\n\nTraceback (most recent call last):\n"
            '  File "x.py", line 1\nException: Cannot find a Crazyradio Dongle',
            "Couldn't load link driver: Cannot find a Crazyradio Dongle: plug in a Crazyradio and check its USB "
            "permissions (docs/deploy.md)",
        ),
        ("  first line \n second line\n third line\n", "first line; second line"),
        ("Too many packets lost", "Too many packets lost"),
        ("\n  \nTraceback (most recent call last):\n  only a traceback", "connection failed"),
    ],
    ids=["silence", "no-radio", "three-lines", "one-line", "traceback-only"],
)
def test_a_connect_failure_is_one_line_without_cflibs_traceback(message, expected):
    """What cflib hands the failure callback (its message, often with a traceback appended)
    becomes one line: the first two lines of the message before any traceback, joined by "; ";
    a missing radio says what to do; no message at all is the connect timeout's silence."""
    from datt.deploy.link import _connect_failure

    assert _connect_failure(message, 3.0) == expected
