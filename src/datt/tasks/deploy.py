"""``deploy.py``: takeoff -> track -> land through cflib, against the simulated Crazyflie
(``deploy=sim``, started here) or a real one (``deploy=crazyflie``)."""

from __future__ import annotations

import shutil
import signal
from pathlib import Path
from urllib.parse import urlparse

from omegaconf import DictConfig, OmegaConf

from datt.configuration import instantiate_option, with_options
from datt.control.factory import build_controller, require_current_state_timing
from datt.control.pid import PidController
from datt.deploy import mocap
from datt.deploy.calibration import CalibrationFlight
from datt.deploy.clock import WALL
from datt.deploy.link import CrazyflieLink, LinkError
from datt.deploy.onboard_flight import OnboardFlight
from datt.deploy.outcome import Kind, Outcome
from datt.deploy.predictor import StatePredictor
from datt.deploy.runner import FlightRunner
from datt.deploy.schema import DeployParams, deploy_params
from datt.deploy.thrust import ThrustMap, ThrustParams
from datt.envs.factory import make_env
from datt.errors import ConfigError, FlightAborted, FlightStopped
from datt.runs import StopRequest, stop_signals
from datt.tasks.common import console, hydra_run_dir, set_threads

# the policy ``checkpoint: null`` flies, per vehicle preset (deploy.vehicle) and mode
# (src/datt/checkpoints/MANIFEST.md): one policy per preset for both modes, trained on the preset's
# loop and ceiling for a radio that loses setpoints (python train.py experiment=deploy_radio
# vehicle=<preset>); off-board it flies behind the state predictor, onboard in the vehicle's app
DEFAULT_CHECKPOINTS = {
    "cf21": {"off-board": "checkpoints/datt_h10_radio.pt", "onboard": "checkpoints/datt_h10_radio.pt"},
    "cf21_upgrade": {"off-board": "checkpoints/datt_h10_upgrade.pt", "onboard": "checkpoints/datt_h10_upgrade.pt"},
}


def default_checkpoint(vehicle: str, onboard: bool) -> str:
    """The policy :data:`DEFAULT_CHECKPOINTS` flies on preset ``vehicle`` in that mode."""
    return DEFAULT_CHECKPOINTS[vehicle]["onboard" if onboard else "off-board"]


def resolve_checkpoint(cfg: DictConfig) -> None:
    """``checkpoint: null`` (the default) becomes the policy of :data:`DEFAULT_CHECKPOINTS` for the
    vehicle preset (``deploy.vehicle``) and the mode (``deploy.onboard``); a checkpoint given is
    kept. The flight's summary names the one that flew (``controller.checkpoint``)."""
    if cfg.get("checkpoint") is None:
        onboard = OmegaConf.select(cfg, "deploy.onboard", default=False) is True
        vehicle = OmegaConf.select(cfg, "deploy.vehicle", default="cf21")
        cfg.checkpoint = default_checkpoint(vehicle if vehicle in DEFAULT_CHECKPOINTS else "cf21", onboard)


def _onboard_app(cfg: DictConfig, run_dir: Path, simulated: bool) -> tuple[int, str | None]:
    """The DATT app for the flight's checkpoint and adaptation: its policy id (the vehicle's
    app must carry it) and, for the simulated Crazyflie, the app exported into
    ``<run>/onboard_app`` (the sources a real vehicle would be built from) and compiled for this
    machine."""
    from datt.export import export_spec
    from datt.export.app import build_sil_library, write_app
    from datt.export.c_code import policy_id

    spec, _, _ = export_spec(cfg)
    if not simulated:
        return policy_id(spec), None
    app_dir = run_dir / "onboard_app"
    write_app(spec, app_dir)
    return policy_id(spec), str(build_sil_library(app_dir))


def _start_server(cfg: DictConfig, params: DeployParams, thrust: ThrustParams, library: str | None):
    """The simulated Crazyflie of ``deploy.server`` on the ``deploy.uri`` port."""
    from datt.deploy.sim import SimCrazyflie, SimCrazyflieParams
    from datt.deploy.sim.motors import MotorParams

    url = urlparse(params.uri)  # a udp:// one (datt.deploy.schema.check_uri)
    server_cfg = {k: (tuple(v) if isinstance(v, list) else v) for k, v in params.server.items()}
    # the simulated vehicle's own motors and mass (never the controller's map or calibration)
    keys = ("vehicle", "mass_kg", "thrust_max_n", "thrust_gain")
    motor_keys = {k: server_cfg.pop(k) for k in keys if k in server_cfg}
    motor_keys["mass_kg"] = float(motor_keys.get("mass_kg") or thrust.mass_kg)
    server_cfg["onboard_library"] = library  # the vehicle's firmware carries the app (deploy.onboard)
    sim_params = SimCrazyflieParams(host=url.hostname, port=url.port, motors=MotorParams(**motor_keys), **server_cfg)
    return SimCrazyflie(sim_params, disturbance=instantiate_option(cfg, "disturbance")).start()


def _mocap_source(params: DeployParams, server):
    m = params.mocap
    if m.source == "none":
        return mocap.NoMocap()
    if m.source == "simulated":
        if server is None:
            raise ConfigError("deploy.mocap.source: 'simulated' needs the simulated Crazyflie (deploy=sim)")
        return mocap.SimulatedMocap(
            server,
            latency_s=m.latency_s,
            dropout_prob=m.dropout_prob,
            dropout_after_s=m.dropout_after_s,
            noise_std_m=m.noise_std_m,
        )
    return mocap.MotionCaptureMocap(str(m.system), str(m.host), str(m.body), dict(m.options), m.connect_timeout_s)


def _flight_kind(params: DeployParams, policy_id: int | None) -> tuple[type, dict]:
    """The flight class of ``deploy.mode`` / ``deploy.onboard`` and its extra arguments."""
    if params.mode == "calibrate":
        return CalibrationFlight, {"hover_s": params.calibrate_hover_s}
    if params.onboard:
        return OnboardFlight, {"policy_id": policy_id}
    return FlightRunner, {}


def predictor_enabled(params: DeployParams, trained_behind_predictor: bool) -> bool:
    """``deploy.predictor.enabled`` with null resolved: on for a policy trained behind the state
    predictor (``env.obs.predict_latency``) flying off-board, off otherwise."""
    if params.predictor.enabled is not None:
        return params.predictor.enabled
    return trained_behind_predictor and not params.onboard and params.mode != "calibrate"


def _predictor(params: DeployParams, model_cfg: DictConfig) -> StatePredictor | None:
    """The latency predictor of ``deploy.predictor`` (``enabled`` resolved), on the flight model's
    own constants."""
    if not params.predictor.enabled:
        return None
    quad = model_cfg.env.quad
    return StatePredictor(
        params.predictor,
        gravity_mps2=float(quad.gravity_mps2),
        k_rate=float(quad.k_rate),
        dt_s=float(model_cfg.env.dt_s),
        k_thrust=float(quad.k_thrust),
    )


def _flight_model_config(params: DeployParams, merged: DictConfig) -> DictConfig:
    """The config the flight's one-drone envs are built from: no simulated disturbance, no
    random start, eager; the training's latency prediction off (the deployment's own predictor,
    ``deploy.predictor``, in continuous time, replaces it)."""
    model_cfg = with_options(merged, disturbance="none")
    model_cfg.env.init_pos_range_m = 0.0
    model_cfg.env.compile = False
    model_cfg.env.obs.predict_latency = False
    return model_cfg


def resolve_predictor(params: DeployParams, trained_behind: bool) -> None:
    """Set ``params.predictor.enabled`` to what flies (:func:`predictor_enabled`, from
    ``trained_behind``, the policy's ``env.obs.predict_latency``) and print the note if a policy
    trained behind the predictor flies off-board without it."""
    params.predictor.enabled = predictor_enabled(params, trained_behind)
    note = predictor_note(params, trained_behind)
    if note:
        console.print(note)


def predictor_note(params: DeployParams, trained_behind_predictor: bool) -> str | None:
    """The line ``deploy.py`` prints when a policy trained behind the state predictor
    (``env.obs.predict_latency``) flies off-board without it, else None."""
    if trained_behind_predictor and not (params.onboard or params.predictor.enabled or params.mode == "calibrate"):
        return (
            "note: this policy was trained behind the state predictor (env.obs.predict_latency=true); "
            "off-board it is meant to fly with the predictor (deploy.predictor.enabled=true or null)"
        )
    return None


def _print_summary(params: DeployParams, summary: dict, run_dir: Path) -> None:
    """The flight's outcome in one line (and, for a calibration, the fitted thrust map)."""
    if params.mode == "calibrate":
        fit = summary.get("calibration") or {}
        console.print(
            f"calibration: {summary['outcome']}; hover command {fit.get('hover_command')}, slope "
            f"{fit.get('slope_mps2_per_command')} m/s² per unit (set deploy.thrust.hover_command and "
            f"deploy.thrust.slope_mps2_per_command); command-to-response latency "
            f"{fit.get('response_latency_ms')} ms"
        )
    err = summary["track_error_m"]
    jitter = summary["jitter_ms"]
    console.print(
        f"flight: {summary['outcome']}; tracking error {err if err is None else f'{err:.3f} m'} over "
        f"{summary['track_steps']} steps; tick jitter median {jitter['median']:.2f} ms, "
        f"p99 {jitter['p99']:.2f} ms; "
        f"{summary['late_ticks']} late ticks; log in {run_dir}"
    )


# What a flight's log needs on its disk before anything is armed: flight.csv at 50 Hz for a
# battery's flight (~7 min, ~2 MB), events.json and the plots (~1 MB), with room to spare.
LOG_HEADROOM_BYTES = 50 * 1024 * 1024


def check_log_headroom(run_dir: Path, free_bytes: int | None = None) -> None:
    """Refuse a flight, in one line and before arming, whose log could not be written whole."""
    free = shutil.disk_usage(run_dir).free if free_bytes is None else free_bytes
    if free < LOG_HEADROOM_BYTES:
        raise ConfigError(
            f"hydra.run.dir: {run_dir} has {free / 2**20:.1f} MB free; a flight's log needs "
            f"{LOG_HEADROOM_BYTES // 2**20} MB before arming: free some space or set hydra.run.dir=<another disk>"
        )


def _flight_dir(run_dir: Path) -> Path:
    """The flight's run dir, made, with room for its log (:func:`check_log_headroom`)."""
    run_dir.mkdir(parents=True, exist_ok=True)
    check_log_headroom(run_dir)
    return run_dir


def run_deploy(cfg: DictConfig, run_dir: Path | None = None, estop=None, server_hook=None) -> dict:
    """Fly (or calibrate) once; returns the flight summary written to ``events.json``.
    ``server_hook(server, runner)`` lets tests inject faults once the flight objects exist."""
    from datt.tasks.validation import validate_config

    resolve_checkpoint(cfg)
    validate_config("deploy", cfg)
    params, flight, safety, thrust = deploy_params(cfg.deploy)
    run_dir = _flight_dir(run_dir or hydra_run_dir())
    set_threads(cfg.threads)
    controller, merged, labels = build_controller(cfg)
    require_current_state_timing(merged, "deploy")
    resolve_predictor(params, bool(labels.get("predict_latency", False)))
    model_cfg = _flight_model_config(params, merged)

    def make_flight_env(family):
        return make_env(model_cfg, num_envs=1, seed=int(cfg.seed), traj=family)

    # While the flight is prepared (the app exported and built, the simulated vehicle started) a stop
    # signal is remembered, and the runner ends the flight there, before anything is armed; from
    # CONNECT on the runner takes the signals over (after arming a stop KILLs).
    with StopRequest() as stop:
        policy_id, library = _onboard_app(cfg, run_dir, params.server is not None) if params.onboard else (None, None)
        server = _start_server(cfg, params, thrust, library) if params.server is not None else None
        try:
            source = _mocap_source(params, server).with_lead(params.mocap.lead_s, params.mocap.lead_window_s)
            clock = WALL if server is None else server.clock  # a real vehicle flies in real time
            link = CrazyflieLink(params.uri, params.log_period_ms, params.connect_timeout_s, params.io_timeout_s, clock)
            track_family = instantiate_option(cfg, "traj")
            kind, extra = _flight_kind(params, policy_id)
            runner = kind(
                link,
                source,
                make_flight_env,
                controller,
                PidController,
                track_family,
                flight,
                safety,
                ThrustMap(thrust),
                run_dir,
                estop=estop,
                console=console,
                stop_request=stop,
                summary_extra={"controller": labels},
                predictor=_predictor(params, model_cfg),
                **extra,
            )
            if server_hook is not None:
                server_hook(server, runner)
            try:
                summary = runner.fly()
            except LinkError as exc:
                raise ConfigError(str(exc)) from None
        finally:
            if server is not None:
                server.stop()
    with stop_signals(signal.SIG_IGN):  # the flight is over: a late signal must not cut the log short
        _print_summary(params, summary, run_dir)
    return summary


def run_deploy_command(cfg: DictConfig) -> dict:
    """``deploy.py``: :func:`run_deploy`, and a flight that did not land is a failing command
    (a refused setting: one line naming it, exit 2; KILLed, not armed or lost: exit 4; stopped
    before arming: exit 130)."""
    summary = run_deploy(cfg)
    outcome = Outcome(Kind(summary["outcome_kind"]), "")
    text = str(summary["outcome"])
    if outcome.exit_code == 2:  # a setting refused the flight before arming
        raise ConfigError(text.removeprefix("preflight failed: "))
    if outcome.exit_code == 130:
        raise FlightStopped(text)
    if outcome.exit_code != 0:
        raise FlightAborted(text)
    return summary
