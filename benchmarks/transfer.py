"""Sim-to-real transfer test: fly policies against the strict simulated Crazyflie made worse than
the controller assumes, and compare with ``eval.py`` on the same reference.

    python benchmarks/transfer.py [--flights 3] [--checkpoints checkpoints/datt_h10.pt ...]

Per checkpoint: ``eval.py``'s star error (DATT + L1, nominal simulator), then ``--flights``
flights of ``deploy.py`` (takeoff, the star, land; DATT + L1 as deployed) under the transfer
conditions (default, issue 18): 40 ms radio round trip, motors 10 % weaker than the firmware's
fit, the vehicle 10 % heavier than ``deploy.thrust.mass_kg``, 2 % of setpoint, mocap and log
packets lost; no calibration flight (the controller flies the nominal map). Reports per flight
the outcome, star error, its ratio to the eval error, tick jitter and per-tick compute, and
writes ``benchmarks/results/transfer.json``. Real time: ~20 s per flight; run it alone.
"""

from __future__ import annotations

import argparse
import itertools
import tempfile
from pathlib import Path

from _common import write_result

from datt.configuration import compose
from datt.tasks.deploy import run_deploy
from datt.tasks.eval import run_eval

CHECKPOINTS = ["checkpoints/datt_h10.pt", "checkpoints/datt_h10_deploy.pt"]
MASS_KG = 0.034  # deploy.thrust.mass_kg's default: what the controller believes
CONDITIONS = {
    "deploy.server.radio_latency_s": 0.02,  # each way: 40 ms round trip
    "deploy.server.thrust_gain": 0.9,
    "deploy.server.mass_kg": round(MASS_KG * 1.1, 5),
    "deploy.server.radio_loss": 0.02,
}
_ports = itertools.count(19950)


def eval_star_error(checkpoint: str, out: Path) -> float:
    cfg = compose(
        "eval",
        [
            f"checkpoint={checkpoint}",
            "controller=datt_l1",
            "traj=star",
            "eval.traj_count=1",
            "eval.plots=false",
            "eval.save_trace=false",
            "eval.timing.steps=0",
        ],
    )
    metrics = run_eval(cfg, run_dir=out)
    (cond,) = metrics["conditions"].values()
    (group,) = cond["groups"].values()  # the one reference family flown
    return float(group["mean_m"])


def fly(checkpoint: str, conditions: dict, out: Path, seed: int) -> dict:
    overrides = [f"checkpoint={checkpoint}", f"deploy.uri=udp://127.0.0.1:{next(_ports)}", f"seed={seed}"]
    overrides += [f"{k}={v}" for k, v in conditions.items()]
    overrides.append(f"deploy.server.radio_seed={seed}")
    summary = run_deploy(compose("deploy", overrides), run_dir=out)
    return {
        "outcome": summary["outcome"],
        "track_error_m": summary["track_error_m"],
        "jitter_ms": summary["jitter_ms"],
        "late_ticks": summary["late_ticks"],
        "compute_ms": summary["compute_ms"],
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--flights", type=int, default=3)
    ap.add_argument("--checkpoints", nargs="+", default=CHECKPOINTS)
    args = ap.parse_args()
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for k, ckpt in enumerate(args.checkpoints):
            base = Path(tmp) / f"policy{k}"
            eval_err = eval_star_error(ckpt, base / "eval")
            flights = [fly(ckpt, CONDITIONS, base / f"flight{i}", seed=i) for i in range(args.flights)]
            for f in flights:
                err = f["track_error_m"]
                f["ratio_to_eval"] = None if err is None else err / eval_err
            landed = [f for f in flights if f["outcome"].startswith("landed")]
            results[ckpt] = {"eval_star_error_m": eval_err, "landed": len(landed), "flights": flights}
            print(f"{ckpt}: eval.py star {eval_err:.3f} m; landed {len(landed)} of {len(flights)}")
            for f in flights:
                err = f["track_error_m"]
                shown = "-" if err is None else f"{err:.3f} m ({f['ratio_to_eval']:.2f}x eval)"
                print(
                    f"  {f['outcome']}: star {shown}; jitter median {f['jitter_ms']['median']:.2f} ms, "
                    f"p99 {f['jitter_ms']['p99']:.2f} ms; compute median {f['compute_ms']['median']:.2f} ms"
                )
    path = write_result("transfer", {"conditions": CONDITIONS, "policies": results})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
