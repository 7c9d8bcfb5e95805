"""Golden bytes of every packet the flight sends, built by real cflib, decoded by the simulated
firmware; thrust mapping and rate-sign conventions."""

import struct

import pytest

pytest.importorskip("cflib")

from cflib.crazyflie.commander import Commander  # noqa: E402
from cflib.crazyflie.localization import Localization  # noqa: E402
from cflib.crazyflie.supervisor import Supervisor  # noqa: E402

from datt.deploy import crtp  # noqa: E402
from datt.deploy.thrust import ThrustMap, ThrustParams, fit_hover  # noqa: E402


class Capture:
    """Stands in for cflib's Crazyflie: records packets as the UDP driver would put them on the wire."""

    def __init__(self, protocol=12):
        self.sent = []
        self.platform = type("P", (), {"get_protocol_version": staticmethod(lambda: protocol)})()

    def send_packet(self, pk, expected_reply=(), resend=False, timeout=0.2):
        self.sent.append(bytes([pk.header]) + bytes(pk.data))

    def add_port_callback(self, *a):
        pass


def test_rate_setpoint_golden_bytes():
    cf = Capture()
    Commander(cf).send_setpoint(10.0, -20.0, 30.0, 40000)
    expected = bytes.fromhex("3c") + struct.pack("<fffH", 10.0, 20.0, 30.0, 40000)  # port 3 ch 0; pitch negated
    assert cf.sent == [expected]
    assert crtp.rpyt_setpoint(10.0, 20.0, 30.0, 40000) == expected
    assert expected.hex() == "3c000020410000a0410000f041409c"


def test_zero_thrust_unlock_golden_bytes():
    cf = Capture()
    Commander(cf).send_setpoint(0.0, 0.0, 0.0, 0)
    assert cf.sent == [bytes.fromhex("3c" + "00000000" + "00000080" + "00000000" + "0000")]  # cflib sends -0.0 pitch


def test_extpos_golden_bytes():
    cf = Capture()
    Localization(cf).send_extpos([0.5, -1.0, 1.25])
    assert cf.sent == [bytes.fromhex("6c0000003f000080bf0000a03f")]
    assert crtp.extpos(0.5, -1.0, 1.25) == cf.sent[0]


def test_supervisor_golden_bytes():
    cf = Capture()
    sup = Supervisor(cf)
    sup.send_arming_request(True)
    sup.send_arming_request(False)
    sup.send_emergency_stop()
    assert cf.sent == [bytes.fromhex("9d0101"), bytes.fromhex("9d0100"), bytes.fromhex("9d03")]


def test_log_and_param_packets_golden_bytes():
    assert crtp.toc_info(crtp.PORT_LOG, 12, 0xDEADBEEF) == bytes.fromhex("5c030c00efbeadde1080")
    assert crtp.toc_item(crtp.PORT_PARAM, 1, 0x08, "flightmode", "stabModePitch") == (
        bytes.fromhex("2c02010008") + b"flightmode\0stabModePitch\0"
    )
    assert crtp.log_data(2, 0x123456, b"\x01\x02") == bytes.fromhex("5e0256341201 02".replace(" ", ""))
    assert crtp.split(bytes.fromhex("2e0100")) == (2, 2, b"\x01\x00")  # param write channel


def test_thrust_map_round_trip_and_hover():
    tm = ThrustMap()
    assert tm.thrust_mps2(tm.command(9.81)) == pytest.approx(9.81, abs=0.01)
    for a in (2.0, 9.81, 12.5):
        assert tm.thrust_mps2(tm.command(a)) == pytest.approx(a, rel=2e-3)
    assert tm.command(0.0) == 0 and tm.command(float("nan")) == 0 and tm.command(-3.0) == 0
    # beyond what the motors can do (the policy allows g + 30 m/s²): clipped to max_command
    assert tm.command(25.0) == tm.p.max_command and tm.thrust_mps2(tm.p.max_command) < 25.0
    # a calibrated hover command is exactly the hover point
    cal = ThrustMap(ThrustParams(hover_command=42000.0))
    assert cal.command(9.81) == 42000


def test_rate_conventions_round_trip_through_the_wire():
    tm = ThrustMap()
    wx, wy, wz = 1.0, -0.5, 0.3
    roll, pitch, yaw = tm.rates_deg(wx, wy, wz)
    cf = Capture()
    Commander(cf).send_setpoint(roll, pitch, yaw, 30000)
    _, _, data = crtp.split(cf.sent[0])
    r, p_wire, y, _ = struct.unpack("<fffH", data)
    assert ThrustMap.body_rates_from_wire(r, p_wire, y) == pytest.approx((wx, wy, wz), rel=1e-5)
    assert tm.rates_deg(100.0, 0.0, 0.0)[0] == 720.0  # clipped to deploy.thrust.max_rate_degps


def test_hover_calibration_fit():
    cmds = [38000.0, 40000.0, 42000.0, 44000.0]
    acc = [0.002 * (c - 41000.0) for c in cmds]
    assert fit_hover(cmds, acc) == pytest.approx((41000.0, 0.002))
    with pytest.raises(ValueError):
        fit_hover([40000.0, 40000.0], [0.0, 1.0])


def test_tilt_is_the_angle_of_body_z_from_world_z():
    """Pure yaw does not tilt; pitch and roll tilt by their angle (x² + y² of the quaternion)."""
    import math

    from datt.deploy.safety import tilt_deg

    def q(axis, deg):
        h = math.radians(deg) / 2
        return [math.cos(h), *(math.sin(h) * a for a in axis)]

    assert tilt_deg(q((0, 0, 1), 170)) == pytest.approx(0.0, abs=1e-9)
    assert tilt_deg(q((0, 1, 0), 80)) == pytest.approx(80.0)
    assert tilt_deg(q((1, 0, 0), -30)) == pytest.approx(30.0)


def test_a_packet_without_data_is_its_header_alone():
    assert crtp.packet(crtp.PORT_PARAM, 1) == bytes([crtp.header(crtp.PORT_PARAM, 1)])
    assert crtp.split(crtp.packet(crtp.PORT_LOG, 2)) == (crtp.PORT_LOG, 2, b"")


def test_a_toc_item_packs_its_identifier_and_type_unsigned():
    """TOC items as the firmware sends them (``CMD_TOC_ITEM_V2``: a uint16 identifier, a uint8
    type): an identifier past 32767 and a type past 127 (cflib's group-flag bit) fit as they are."""
    item = crtp.toc_item(crtp.PORT_PARAM, 40000, 0x88, "stabilizer", "controller")
    port, channel, data = crtp.split(item)
    assert (port, channel) == (crtp.PORT_PARAM, 0)
    assert struct.unpack("<BHB", data[:4]) == (2, 40000, 0x88)
    assert data[4:] == b"stabilizer\0controller\0"
