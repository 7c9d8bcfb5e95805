"""Typed schema of ``deploy`` (``conf/deploy/{sim,crazyflie}.yaml``). No defaults: the YAML is the
only place a default lives. ``flight``, ``safety`` and ``thrust`` have their own dataclasses
(:mod:`datt.deploy.runner`, :mod:`datt.deploy.safety`, :mod:`datt.deploy.thrust`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from omegaconf import MISSING, DictConfig, OmegaConf

from datt.configuration import structured
from datt.deploy.predictor import PredictorParams
from datt.deploy.runner import FlightParams
from datt.deploy.safety import SafetyParams
from datt.deploy.thrust import ThrustParams
from datt.errors import ConfigError

MOCAP_SOURCES = ("none", "simulated", "motioncapture")
MODES = ("fly", "calibrate")


@dataclass
class MocapParams:
    source: str = MISSING  # none | simulated | motioncapture
    latency_s: float = 0.0  # simulated source only
    dropout_prob: float = 0.0
    dropout_after_s: float | None = None
    noise_std_m: float = 0.0  # simulated source only: Gaussian position noise
    system: str | None = None  # motioncapture source only (e.g. vicon, optitrack)
    host: str | None = None
    body: str | None = None

    def validate(self) -> None:
        if self.source not in MOCAP_SOURCES:
            raise ConfigError(
                f"deploy.mocap.source: unknown source {self.source!r}; allowed: {', '.join(MOCAP_SOURCES)}"
            )
        if self.latency_s < 0 or not 0 <= self.dropout_prob <= 1 or self.noise_std_m < 0:
            raise ConfigError(
                "deploy.mocap: latency_s and noise_std_m must be >= 0 and dropout_prob in [0, 1], "
                f"got {self.latency_s}, {self.noise_std_m}, {self.dropout_prob}"
            )
        if self.source == "motioncapture" and not (self.system and self.host and self.body):
            raise ConfigError("deploy.mocap: source 'motioncapture' needs system, host and body")


@dataclass
class DeployParams:
    """The flight session: link, mocap, mode and timeouts (the nested flight/safety/thrust/server
    nodes are checked by their own schemas)."""

    uri: str = MISSING
    server: Any = MISSING  # simulated Crazyflie (deploy=sim) or null (a real one)
    mocap: MocapParams = MISSING
    mode: str = MISSING  # fly | calibrate
    onboard: bool = MISSING  # TRACK in the vehicle's DATT app (datt export format=app) instead of over the radio
    calibrate_hover_s: float = MISSING
    log_period_ms: int = MISSING
    connect_timeout_s: float = MISSING
    io_timeout_s: float = MISSING
    flight: Any = MISSING
    safety: Any = MISSING
    thrust: Any = MISSING
    predictor: Any = MISSING  # datt.deploy.predictor.PredictorParams (set by deploy_params)

    def validate(self) -> None:
        self.mocap.validate()
        if self.mode not in MODES:
            raise ConfigError(f"deploy.mode: unknown mode {self.mode!r}; allowed: {', '.join(MODES)}")
        if self.onboard and self.mode != "fly":
            raise ConfigError(f"deploy.onboard: only deploy.mode=fly runs onboard, got mode={self.mode!r}")
        if not self.calibrate_hover_s > 0:
            raise ConfigError(f"deploy.calibrate_hover_s: must be > 0, got {self.calibrate_hover_s}")
        if not 10 <= self.log_period_ms <= 2550:
            raise ConfigError(
                f"deploy.log_period_ms: must be in [10, 2550] (firmware log periods), got {self.log_period_ms}"
            )
        if not (self.connect_timeout_s > 0 and self.io_timeout_s > 0):
            raise ConfigError("deploy.connect_timeout_s / io_timeout_s: must be > 0")


def deploy_params(node: DictConfig) -> tuple[DeployParams, FlightParams, SafetyParams, ThrustParams]:
    """``cfg.deploy`` checked against every schema of the flight session."""
    params = structured(DeployParams, OmegaConf.to_container(node, resolve=True), "deploy")
    flight = structured(FlightParams, params.flight, "deploy.flight")
    safety = structured(SafetyParams, params.safety, "deploy.safety")
    thrust = structured(ThrustParams, params.thrust, "deploy.thrust")
    params.predictor = structured(PredictorParams, params.predictor, "deploy.predictor")
    return params, flight, safety, thrust
