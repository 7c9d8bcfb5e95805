"""Typed schema of ``deploy`` (``conf/deploy/{sim,crazyflie}.yaml``). No defaults: the YAML is the
only place a default lives. ``flight``, ``safety`` and ``thrust`` have their own dataclasses
(:mod:`datt.deploy.runner`, :mod:`datt.deploy.safety`, :mod:`datt.deploy.thrust`)."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING, DictConfig, OmegaConf

from datt.configuration import Range, ranged, structured
from datt.deploy.predictor import PredictorParams
from datt.deploy.runner import FlightParams
from datt.deploy.safety import SafetyParams
from datt.deploy.thrust import ThrustParams
from datt.errors import ConfigError
from datt.sim.vehicles import VEHICLES, vehicle

MOCAP_SOURCES = ("none", "simulated", "motioncapture")
MODES = ("fly", "calibrate")


@dataclass
class MocapParams:
    source: str = ranged(MISSING, Range(choices=MOCAP_SOURCES))
    latency_s: float = ranged(0.0, Range(0.0, 1.0))  # simulated source only
    dropout_prob: float = ranged(0.0, Range(0.0, 1.0))
    dropout_after_s: float | None = ranged(None, Range(0.0, 3600.0, optional=True))
    noise_std_m: float = ranged(0.0, Range(0.0, 1.0))  # simulated source only: Gaussian position noise
    system: str | None = None  # motioncapture source only (e.g. vicon, optitrack)
    host: str | None = None
    body: str | None = None
    options: dict[str, str] = field(default_factory=dict)  # motioncapture: more of its settings (port, ...)
    # motioncapture: the first frame holding the body must come this soon, else the flight is refused
    connect_timeout_s: float = ranged(5.0, Range(0.0, 60.0, low_open=True))
    # each forwarded position led this far along the mocap velocity (datt.deploy.mocap.FrameLead);
    # null: half the radio round trip measured at connect for an onboard flight, 0 off-board
    lead_s: float | None = ranged(MISSING, Range(0.0, 0.2, optional=True))
    lead_window_s: float = ranged(MISSING, Range(0.0, 0.5, low_open=True))  # the velocity's baseline

    def validate(self) -> None:
        if self.source == "motioncapture" and not (self.system and self.host and self.body):
            raise ConfigError("deploy.mocap: source 'motioncapture' needs system, host and body")


@dataclass
class DeployParams:
    """The flight session: link, mocap, mode and timeouts (the nested flight/safety/thrust/server
    nodes are checked by their own schemas)."""

    uri: str = MISSING
    vehicle: str = ranged(MISSING, Range(choices=tuple(VEHICLES)))  # the preset that flies (datt.sim.vehicles)
    server: Any = MISSING  # simulated Crazyflie (deploy=sim) or null (a real one)
    mocap: MocapParams = MISSING
    mode: str = ranged(MISSING, Range(choices=MODES))
    onboard: bool = MISSING  # TRACK in the vehicle's DATT app (datt export format=app) instead of over the radio
    calibrate_hover_s: float = ranged(MISSING, Range(0.0, 600.0, low_open=True))
    log_period_ms: int = ranged(MISSING, Range(10, 2550, integer=True))  # firmware log periods
    connect_timeout_s: float = ranged(MISSING, Range(0.0, 600.0, low_open=True))
    io_timeout_s: float = ranged(MISSING, Range(0.0, 600.0, low_open=True))
    flight: Any = MISSING
    safety: Any = MISSING
    thrust: Any = MISSING
    predictor: Any = MISSING  # datt.deploy.predictor.PredictorParams (set by deploy_params)

    def validate(self) -> None:
        self.mocap.validate()
        if self.onboard and self.mode != "fly":
            raise ConfigError(f"deploy.onboard: only deploy.mode=fly runs onboard, got mode={self.mode!r}")
        if self.server is not None:
            from datt.deploy.sim.server import check_server_settings

            if not isinstance(self.server, dict):
                raise ConfigError(
                    f"deploy.server: must be the simulated vehicle's settings or null, got {self.server!r}"
                )
            check_server_settings(self.server)
        check_uri(self.uri, simulated=self.server is not None)


def deploy_params(node: DictConfig) -> tuple[DeployParams, FlightParams, SafetyParams, ThrustParams]:
    """``cfg.deploy`` checked against every schema of the flight session; the thrust map's and the
    simulated vehicle's nulls become the preset's numbers (``deploy.vehicle``)."""
    params = structured(DeployParams, OmegaConf.to_container(node, resolve=True), "deploy")
    flight = structured(FlightParams, params.flight, "deploy.flight")
    safety = structured(SafetyParams, params.safety, "deploy.safety")
    preset = vehicle(params.vehicle)
    thrust_node = dict(params.thrust)
    for key in ("mass_kg", "thrust_max_n"):  # null: the preset's
        if thrust_node.get(key) is None:
            thrust_node[key] = getattr(preset, key)
    thrust = structured(ThrustParams, thrust_node, "deploy.thrust")
    if params.server is not None:
        params.server = {**params.server, "vehicle": params.vehicle}
    params.predictor = structured(PredictorParams, params.predictor, "deploy.predictor")
    return params, flight, safety, thrust


RADIO_RATES = ("250K", "1M", "2M")


def check_uri(uri: str, simulated: bool) -> None:
    """``deploy.uri`` is one cflib can open: ``radio://<dongle>/<channel 0-125>/<250K|1M|2M>[/<address:
    10 hex digits>]``, ``usb://<n>`` or ``udp://<host>:<port 1-65535>``; the simulated Crazyflie
    (``deploy=sim``) listens on a ``udp://`` one. One line naming the key and the form otherwise."""
    from urllib.parse import urlparse

    def refuse(why: str) -> None:
        raise ConfigError(f"deploy.uri: {why}, got {uri!r}")

    url = urlparse(str(uri))
    if simulated and url.scheme != "udp":
        refuse("the simulated Crazyflie listens on udp://<host>:<port>, e.g. udp://127.0.0.1:19850")
    if url.scheme == "udp":
        try:
            port = url.port
        except ValueError:  # a port out of range or not a number
            port = -1
        if not url.hostname or port is None or not 1 <= port <= 65535:
            refuse("udp:// needs a host and a port 1-65535, e.g. udp://127.0.0.1:19850")
    elif url.scheme == "radio":
        parts = [url.netloc, *[p for p in url.path.split("/") if p]]
        ok = len(parts) in (3, 4) and parts[0].isdigit() and parts[1].isdigit() and 0 <= int(parts[1]) <= 125
        ok = ok and parts[2] in RADIO_RATES and (len(parts) == 3 or re.fullmatch(r"[0-9A-Fa-f]{10}", parts[3]))
        if not ok:
            refuse(
                "radio:// needs <dongle>/<channel 0-125>/<250K|1M|2M>[/<10 hex digits>], e.g. radio://0/80/2M/E7E7E7E7E7"
            )
    elif url.scheme == "usb":
        if not url.netloc.isdigit() or url.path not in ("", "/"):
            refuse("usb:// needs the device number, e.g. usb://0")
    else:
        refuse("must start with radio://, usb:// or udp://")
