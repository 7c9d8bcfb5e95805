"""Sim-to-real transfer test: fly a policy against the strict simulated Crazyflie made worse than
the controller assumes, and compare with ``eval.py`` on the same reference.

Transfer conditions (``CONDITIONS``): 40 ms radio round trip, motors 10 % weaker than the
firmware's fit, the vehicle 10 % heavier than ``deploy.thrust.mass_kg``, 2 % of setpoint, mocap,
log and app-channel packets lost. ``MODES``: off-board on the nominal map (the policy over the
radio at 50 Hz; also with the experimental state predictor), onboard on the nominal map (the
policy in the vehicle's app, ``deploy.onboard``), and onboard after a calibration flight under the
same conditions (:func:`calibrate`: the calibration flight of docs/deploy.md). Used by
``benchmarks/transfer.py`` and ``tests/deploy/test_transfer.py``.
"""

from __future__ import annotations

import random
from pathlib import Path

from datt.configuration import compose
from datt.sim.vehicles import DEFAULT_VEHICLE, VEHICLES
from datt.tasks.deploy import run_deploy
from datt.tasks.eval import run_eval

# what benchmarks/transfer.py flies by default: the shipped policy (python train.py), the deploy-grade one
# (experiment=deploy), the firmware-grade one (experiment=deploy_firmware), the one trained behind the
# state predictor (experiment=deploy_predictor, what deploy.py flies onboard) and that one with the
# cost on its rate command's change (experiment=deploy_smooth), and that one trained on a radio that loses
# setpoints (experiment=deploy_radio, what deploy.py flies off-board)
CHECKPOINTS = [
    "checkpoints/datt_h10.pt",
    "checkpoints/datt_h10_deploy.pt",
    "checkpoints/datt_h10_firmware.pt",
    "checkpoints/datt_h10_predictor.pt",
    "checkpoints/datt_h10_smooth.pt",
    "checkpoints/datt_h10_radio.pt",
]
MASS_KG = VEHICLES[DEFAULT_VEHICLE].mass_kg  # deploy.thrust.mass_kg's default: what the controller believes
CONDITIONS = {
    "deploy.server.radio_latency_s": 0.02,  # each way: 40 ms round trip
    "deploy.server.thrust_gain": 0.9,
    "deploy.server.mass_kg": round(MASS_KG * 1.1, 5),
    "deploy.server.radio_loss": 0.02,
}
MODES = {  # name -> (deploy overrides, calibrate first)
    "off-board": (("deploy.predictor.enabled=false",), False),  # without it, whatever the policy
    "off-board, predictor": (("deploy.predictor.enabled=true",), False),
    "onboard": (("deploy.onboard=true",), False),
    "onboard, calibrated": (("deploy.onboard=true",), True),
}


def _free_port() -> int:
    """A UDP port nothing on this machine holds now, for one flight's simulated Crazyflie: two
    processes flying transfer flights at once (a benchmark and a test, two test workers) never
    share one. Drawn below the kernel's ephemeral range (32768 on), where cflib's own sockets go."""
    from datt.deploy.sim.server import udp_port_free

    rng = random.SystemRandom()
    while True:
        port = rng.randrange(22000, 32000)  # above the test workers' blocks (tests/deploy, 19900 + 500 each)
        if udp_port_free(port):
            return port


# the simulated vehicle's rate loop -> the training simulator's rate model that evaluates the same loop
EVAL_RATE_MODEL = {"pi_first_order": "first_order", "firmware": "firmware"}


def eval_star_error(checkpoint: str, out: Path, rate_loop: str = "firmware", vehicle: str = "cf21") -> float:
    """``eval.py``'s star error of the policy with L1 (the bank's star group: the reference
    ``deploy.py`` flies), no disturbance, nominal simulator fed through ``vehicle``'s thrust
    ceiling (its off-board ``max_command``, as the policies are trained); with
    ``rate_loop="firmware"`` on the simulator's firmware rate model of ``vehicle``, with
    ``pi_first_order`` on the first-order model (the loop the flights then fly)."""
    overrides = [
        f"checkpoint={checkpoint}",
        "controller=datt_l1",
        "eval.plots=false",
        "eval.save_trace=false",
        "eval.timing.steps=0",
    ]
    ceiling = round(VEHICLES[vehicle].ceiling_mps2(), 2)
    overrides += [
        f"env.quad.rate_model={EVAL_RATE_MODEL[rate_loop]}",
        f"env.quad.max_thrust_mps2={ceiling}",
        f"env.quad.vehicle={vehicle}",
    ]
    cfg = compose("eval", overrides)
    metrics = run_eval(cfg, run_dir=out)
    (cond,) = metrics["conditions"].values()
    return float(cond["groups"]["star"]["mean_m"])


def _flight_overrides(conditions: dict, seed: int) -> list[str]:
    """A fresh port, ``conditions`` (``deploy.*`` overrides), ``seed`` for the run and the radio's losses."""
    overrides = [f"deploy.uri=udp://127.0.0.1:{_free_port()}", f"seed={seed}"]
    return overrides + [f"{k}={v}" for k, v in conditions.items()] + [f"deploy.server.radio_seed={seed}"]


def fly(checkpoint: str, conditions: dict, out: Path, seed: int, extra: tuple = ()) -> dict:
    """One ``deploy.py`` flight (DATT + L1, the star) of ``checkpoint`` under ``conditions``
    (``deploy.*`` overrides); ``seed`` also seeds the radio's losses. Returns the summary's figures."""
    overrides = [f"checkpoint={checkpoint}", *_flight_overrides(conditions, seed), *extra]
    summary = run_deploy(compose("deploy", overrides), run_dir=out)
    return {
        "outcome": summary["outcome"],
        "outcome_kind": summary["outcome_kind"],
        "thrust_check": summary.get("thrust_check"),
        "track_error_m": summary["track_error_m"],
        "track_steps": summary["track_steps"],
        # the estimate against the reference of the tick it arrived in (the former pairing)
        "track_error_received_m": summary.get("track_error_received_m"),
        "jitter_ms": summary["jitter_ms"],
        "late_ticks": summary["late_ticks"],
        "compute_ms": summary["compute_ms"],
    }


def calibrate(conditions: dict, out: Path, seed: int = 0) -> tuple[str, ...]:
    """A calibration flight (``deploy.mode=calibrate``: PID hover with a thrust square wave) under
    ``conditions``; returns the ``deploy.thrust`` overrides it fitted (hover command and slope).
    Raises RuntimeError when the calibration flight does not land."""
    overrides = ["deploy.mode=calibrate", *_flight_overrides(conditions, seed)]
    summary = run_deploy(compose("deploy", overrides), run_dir=out)
    fit = summary.get("calibration") or {}
    if not summary["outcome"].startswith("landed") or fit.get("hover_command") is None:
        raise RuntimeError(f"the calibration flight failed: {summary['outcome']}")
    return (
        f"deploy.thrust.hover_command={fit['hover_command']:.2f}",
        f"deploy.thrust.slope_mps2_per_command={fit['slope_mps2_per_command']:.8g}",
    )


# the transfer grid (benchmarks/transfer_grid.py): radio round trip, vehicle heavier than the map
# believes, motors weaker than the firmware's fit, packet loss
GRID = {"rtt_ms": (20, 40, 60), "mass_pct": (0, 10, 15), "motor_pct": (0, -10), "loss_pct": (0, 2, 5)}


def cell_conditions(vehicle: str, rtt_ms: float, mass_pct: float, motor_pct: float, loss_pct: float) -> dict:
    """``deploy.*`` overrides of one grid cell for the preset ``vehicle``: the simulated vehicle
    ``mass_pct`` heavier than the preset's flying mass (what the host's map believes), its motors
    ``motor_pct`` from the firmware's fit, ``rtt_ms`` of radio round trip, ``loss_pct`` of packets lost."""
    mass = VEHICLES[vehicle].mass_kg
    return {
        "deploy.vehicle": vehicle,
        "deploy.server.radio_latency_s": round(rtt_ms / 2000.0, 6),
        "deploy.server.mass_kg": round(mass * (1.0 + mass_pct / 100.0), 6),
        "deploy.server.thrust_gain": round(1.0 + motor_pct / 100.0, 6),
        "deploy.server.radio_loss": round(loss_pct / 100.0, 6),
    }


def verdict(outcome_kind: str, track_steps: int = 1) -> str:
    """A flight's outcome as the grid counts it: landed (the whole track), landed early (a LAND
    decision during TRACK), refused (the thrust check, the hover trim's limit or any refusal before
    TRACK: ``track_steps`` 0), killed, or the outcome kind itself."""
    if outcome_kind in ("landed", "landed_onboard"):
        return "landed"
    if outcome_kind == "landed_early":
        return "landed early" if track_steps else "refused"
    if outcome_kind in ("refused_reference", "refused", "refused_setting"):
        return "refused"
    return outcome_kind
