"""``deploy`` checked as a whole (``datt.deploy.schema.deploy_params``): what each refusal names and
what a motion-capture source needs."""

from __future__ import annotations

import pytest

from datt.configuration import compose
from datt.deploy.schema import deploy_params
from datt.errors import ConfigError

NEEDS = "^deploy.mocap: source 'motioncapture' needs system, host and body$"


def params(*overrides: str, deploy: str = "crazyflie"):
    return deploy_params(compose("deploy", [f"deploy={deploy}", *overrides]).deploy)


@pytest.mark.parametrize("missing", ["system", "host", "body"])
def test_a_motion_capture_source_without_its_system_host_or_body_is_refused(missing):
    with pytest.raises(ConfigError, match=NEEDS):
        params("deploy.mocap.source=motioncapture", f"deploy.mocap.{missing}=null")
    with pytest.raises(ConfigError, match=NEEDS):
        params("deploy.mocap.source=motioncapture", f"deploy.mocap.{missing}=''")


def test_a_motion_capture_source_with_all_three_is_accepted_and_other_sources_need_none():
    deploy, *_ = params("deploy.mocap.source=motioncapture")
    assert (deploy.mocap.system, deploy.mocap.host, deploy.mocap.body) == ("vicon", "192.168.1.10", "cf1")
    for source in ("none", "simulated"):
        off, *_ = params(f"deploy.mocap.source={source}", "deploy.mocap.system=null", "deploy.mocap.host=null")
        assert off.mocap.source == source


def test_a_server_that_is_not_a_settings_node_is_refused_naming_it():
    with pytest.raises(ConfigError, match=r"^deploy.server: must be the simulated vehicle's settings or null, got 5$"):
        params("deploy.server=5")


@pytest.mark.parametrize(
    "override, key",
    [
        ("deploy.log_period_ms=often", "deploy.log_period_ms"),
        ("deploy.thrust.max_command=lots", "deploy.thrust.max_command"),
        ("deploy.flight.track_s=long", "deploy.flight.track_s"),
        ("deploy.safety.max_tilt_deg=steep", "deploy.safety.max_tilt_deg"),
        ("deploy.predictor.latency_s=soon", "deploy.predictor.latency_s"),
    ],
    ids=["session", "thrust", "flight", "safety", "predictor"],
)
def test_a_value_of_the_wrong_type_is_refused_under_its_full_key(override, key):
    with pytest.raises(ConfigError, match=f"^{key}: "):
        params(override, deploy="sim")


def test_interpolations_are_resolved_before_the_schemas_read_them():
    """A value given as another key's (``${...}``) is the other key's value, not the text."""
    _, flight, _, thrust = params(
        "deploy.flight.track_s=${deploy.flight.takeoff_s}", "deploy.thrust.max_command=${deploy.log_period_ms}"
    )
    base, base_flight, *_ = params()
    assert flight.track_s == base_flight.takeoff_s and thrust.max_command == base.log_period_ms


@pytest.mark.parametrize(
    "uri, simulated, message",
    [
        ("udp://127.0.0.1:99999", True, "udp:// needs a host and a port 1-65535"),
        ("udp://127.0.0.1:abc", True, "udp:// needs a host and a port 1-65535"),
        ("udp://127.0.0.1", True, "udp:// needs a host and a port 1-65535"),
        ("udp://:19850", True, "udp:// needs a host and a port 1-65535"),
        ("radio://0/80/2M/E7E7E7E7E7", True, "the simulated Crazyflie listens on udp://"),
        ("radio://0/126/2M", False, "radio:// needs <dongle>/<channel 0-125>"),
        ("radio://0/80/3M", False, "radio:// needs <dongle>/<channel 0-125>"),
        ("radio://0/80/2M/E7E7", False, "radio:// needs <dongle>/<channel 0-125>"),
        ("usb://x", False, "usb:// needs the device number"),
        ("tcp://127.0.0.1:1", False, "must start with radio://, usb:// or udp://"),
        ("", False, "must start with radio://, usb:// or udp://"),
    ],
)
def test_a_uri_cflib_cannot_open_is_one_line(uri, simulated, message):
    from datt.deploy.schema import check_uri

    with pytest.raises(ConfigError) as info:
        check_uri(uri, simulated)
    assert str(info.value).startswith(f"deploy.uri: {message}") and str(info.value).endswith(f", got {uri!r}")


@pytest.mark.parametrize("uri", ["radio://0/80/2M/E7E7E7E7E7", "radio://1/0/250K", "usb://0", "udp://127.0.0.1:1"])
def test_the_uris_cflib_opens_are_accepted(uri):
    from datt.deploy.schema import check_uri

    check_uri(uri, simulated=uri.startswith("udp"))


@pytest.mark.parametrize(
    "uri, hint",
    [
        ("udp://nohost.invalid:19850", "the host must be an address of this machine"),
        ("udp://127.0.0.1:{busy}", "another simulated Crazyflie may be running"),
    ],
)
def test_a_simulated_vehicle_that_cannot_bind_says_why(uri, hint):
    """A name that does not resolve is not "another simulated Crazyflie may be running"."""
    import socket

    from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams
    from datt.deploy.sim.motors import MotorParams

    holder = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    holder.bind(("127.0.0.1", 0))
    try:
        uri = uri.format(busy=holder.getsockname()[1])
        host, port = uri.removeprefix("udp://").rsplit(":", 1)
        server = SimCrazyflie(SimCrazyflieParams(host=host, port=int(port), motors=MotorParams()))
        with pytest.raises(ConfigError) as info:
            server.start()
        assert str(info.value).startswith(f"deploy.uri: {uri} cannot be bound (") and hint in str(info.value)
    finally:
        holder.close()
