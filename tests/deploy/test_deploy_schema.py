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
