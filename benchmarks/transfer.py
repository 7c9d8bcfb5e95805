"""Sim-to-real transfer test: fly policies against the strict simulated Crazyflie made worse than
the controller assumes, and compare with ``eval.py`` on the same reference.

    python benchmarks/transfer.py [--flights 3] [--checkpoints checkpoints/datt_h10_iid.pt ...]

Per checkpoint: ``eval.py``'s star error (DATT + L1, nominal simulator), then ``--flights``
flights of ``deploy.py`` (takeoff, the star, land; DATT + L1 as deployed) under the transfer
conditions: 40 ms radio round trip, motors 10 % weaker than the firmware's fit, the
vehicle 10 % heavier than ``deploy.thrust.mass_kg``, 2 % of setpoint, mocap and log packets
lost; in each mode of ``datt.tasks.transfer.MODES`` (off-board / onboard on the nominal map /
onboard after a calibration flight under the same conditions), on the simulated vehicle's timing
(it logs the estimate of now before its 20 ms step; ``--log-after-step``: the former timing, a step
early); below the commander the simulated vehicle flies the default preset's loop (``cf21``: the
firmware's rate loop), ``--rate-loop pi_first_order`` the training simulator's first-order model.
The grid over round trip, mass, motors and loss per preset: ``benchmarks/transfer_grid.py``.
Reports per flight the outcome, star error (each estimate against the reference when it was
measured, as ``eval.py``; off-board also against the reference of the tick it arrived in, the
figure before 2026-12-05), its ratio to the eval error, tick jitter and per-tick compute, and writes
``benchmarks/results/transfer.json`` (``--out``). Real time: ~20 s per flight; run it alone.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from _common import write_result

from datt.paths import resolve_path
from datt.sim.vehicles import DEFAULT_VEHICLE, VEHICLES
from datt.tasks.transfer import CHECKPOINTS, CONDITIONS, EVAL_RATE_MODEL, MODES, calibrate, eval_star_error, fly


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=3)
    ap.add_argument("--out", default="transfer", help="result name: benchmarks/results/<out>.json")
    ap.add_argument("--checkpoints", nargs="+", default=CHECKPOINTS)
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument(
        "--rate-loop",
        default=None,
        choices=list(EVAL_RATE_MODEL),
        help="the simulated vehicle below its commander (deploy.server.rate_loop; default: the cf21 preset's, "
        "firmware); firmware also "
        "evaluates on the simulator's firmware rate model",
    )
    ap.add_argument(
        "--log-after-step",
        action="store_true",
        help="the simulated vehicle's former timing: it logs after its step, a step early "
        "(deploy.server.log_before_step=false), and the predictor does not model its 20 ms loop tick "
        "(deploy.predictor.vehicle_tick_s=0); to reproduce earlier results",
    )
    args = ap.parse_args()
    conditions = dict(CONDITIONS)
    if args.log_after_step:
        conditions["deploy.server.log_before_step"] = False
        conditions["deploy.predictor.vehicle_tick_s"] = 0.0
    rate_loop = args.rate_loop or VEHICLES[DEFAULT_VEHICLE].rate_loop  # deploy.vehicle's default preset
    conditions["deploy.server.rate_loop"] = rate_loop
    results = {}
    missing = [c for c in args.checkpoints if not resolve_path(c).exists()]
    for ckpt in missing:
        print(f"{ckpt}: not found, skipped")
    calibration = None
    with tempfile.TemporaryDirectory() as tmp:
        if any(MODES[m][1] for m in args.modes):  # one calibration flight serves every policy
            calibration = calibrate(conditions, Path(tmp) / "calibration")
            print(f"calibration flight: {' '.join(calibration)}")
        for k, ckpt in enumerate(c for c in args.checkpoints if c not in missing):
            base = Path(tmp) / f"policy{k}"
            eval_err = eval_star_error(ckpt, base / "eval", rate_loop)
            results[ckpt] = {"eval_star_error_m": eval_err, "modes": {}}
            print(f"{ckpt}: eval.py star {eval_err:.3f} m")
            for mode in args.modes:
                extra, calibrated = MODES[mode]
                extra = extra + (calibration if calibrated else ())
                flights = [
                    fly(ckpt, conditions, base / f"{mode}{i}".replace(" ", "_"), seed=i, extra=extra)
                    for i in range(args.flights)
                ]
                for f in flights:
                    err = f["track_error_m"]
                    f["ratio_to_eval"] = None if err is None else err / eval_err
                landed = [f for f in flights if f["outcome"].startswith("landed")]
                results[ckpt]["modes"][mode] = {"landed": len(landed), "flights": flights}
                print(f"  {mode}: landed {len(landed)} of {len(flights)}")
                for f in flights:
                    err = f["track_error_m"]
                    shown = "-" if err is None else f"{err:.3f} m ({f['ratio_to_eval']:.2f}x eval)"
                    if f.get("track_error_received_m") is not None:
                        shown += f" [against the tick it arrived in: {f['track_error_received_m']:.3f} m]"
                    print(
                        f"    {f['outcome']}: star {shown}; jitter median {f['jitter_ms']['median']:.2f} ms, "
                        f"p99 {f['jitter_ms']['p99']:.2f} ms; compute median {f['compute_ms']['median']:.2f} ms"
                    )
    path = write_result(
        args.out,
        {"conditions": conditions, "calibration": calibration, "policies": results},
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
