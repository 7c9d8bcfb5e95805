"""The transfer grid: one policy flown by ``deploy.py`` against the simulated Crazyflie of a vehicle
preset, over every combination of radio round trip (20 / 40 / 60 ms), a vehicle heavier than the
host believes (+0 / +10 / +15 %), motors weaker than the firmware's fit (-0 / -10 %) and packet loss
(0 / 2 / 5 %), ``--flights`` flights per cell (radio seeds 0..n-1).

    python benchmarks/transfer_grid.py [--vehicle cf21] [--mode off-board|onboard] [--flights 5]
        [--controller datt_l1|pid] [--workers 3] [--rtt-ms 20 40 60] [--mass-pct 0 10 15] ...

Per cell: landed (the whole track) / landed early (a LAND decision in TRACK, e.g. sinking) /
refused (landed without tracking: the thrust check or the hover trim's limit, docs/deploy.md) /
killed; the mean error of the flights that landed after the whole track, and its ratio to the
policy's ``eval.py`` star error on the preset's own loop. The vehicle's loop is the preset's
(``deploy.vehicle``); the policy the mode's default (``checkpoint: null``) unless ``--checkpoint``.
Flights are real time (~12-30 s each); ``--workers`` fly at once, each in its own process on its
own UDP port (each flight's late ticks and jitter are recorded, so a machine too busy for it
shows). Writes ``benchmarks/results/transfer_grid_<vehicle>_<mode>[_<controller>].json``.
"""

from __future__ import annotations

import argparse
import itertools
import statistics
import tempfile
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from _common import write_result

from datt.sim.vehicles import VEHICLES
from datt.tasks.deploy import DEFAULT_CHECKPOINTS
from datt.tasks.transfer import GRID, cell_conditions, eval_star_error, fly, verdict

MODE_OVERRIDES = {"off-board": (), "onboard": ("deploy.onboard=true",)}


def _fly_one(job: tuple) -> tuple:
    cell, seed, checkpoint, conditions, extra, out = job
    flight = fly(checkpoint, conditions, Path(out), seed=seed, extra=extra)
    return cell, flight


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vehicle", default="cf21", choices=list(VEHICLES))
    ap.add_argument("--mode", default="off-board", choices=list(MODE_OVERRIDES))
    ap.add_argument("--controller", default="datt_l1", help="datt_l1 (the policy + L1) or pid (the baseline)")
    ap.add_argument("--checkpoint", default=None, help="default: the mode's policy (deploy.py's checkpoint: null)")
    ap.add_argument("--flights", type=int, default=5)
    ap.add_argument("--workers", type=int, default=3)
    for key, values in GRID.items():
        ap.add_argument("--" + key.replace("_", "-"), nargs="+", type=float, default=list(values))
    ap.add_argument("--out", default=None)
    args = ap.parse_args()
    checkpoint = args.checkpoint or DEFAULT_CHECKPOINTS["onboard" if args.mode == "onboard" else "off-board"]
    vehicle = VEHICLES[args.vehicle]
    extra = (*MODE_OVERRIDES[args.mode], f"controller={args.controller}")
    axes = [getattr(args, key) for key in GRID]
    cells = list(itertools.product(*axes))
    with tempfile.TemporaryDirectory() as tmp:
        eval_err = None
        if args.controller == "datt_l1":
            eval_err = eval_star_error(checkpoint, Path(tmp) / "eval", vehicle.rate_loop, args.vehicle)
            print(f"{checkpoint}: eval.py star {eval_err:.3f} m ({args.vehicle}'s {vehicle.rate_loop} loop)")
        jobs = [
            (cell, seed, checkpoint, cell_conditions(args.vehicle, *cell), extra, f"{tmp}/{i}_{seed}")
            for i, cell in enumerate(cells)
            for seed in range(args.flights)
        ]
        flights: dict[tuple, list] = {cell: [] for cell in cells}
        with ProcessPoolExecutor(max_workers=args.workers) as pool:
            for done, (cell, flight) in enumerate(pool.map(_fly_one, jobs), start=1):
                flights[cell].append(flight)
                if done % args.flights == 0:
                    print(f"  {done}/{len(jobs)} flights", flush=True)
    rows = []
    print("rtt_ms mass% motor% loss% | landed early refused killed other | error_m ratio | late ticks")
    for cell in cells:
        found = flights[cell]
        kinds = [verdict(f["outcome_kind"], f["track_steps"]) for f in found]
        errors = [f["track_error_m"] for f, k in zip(found, kinds) if k == "landed" and f["track_error_m"] is not None]
        mean = statistics.fmean(errors) if errors else None
        row = {
            **dict(zip(GRID, cell)),
            "landed": kinds.count("landed"),
            "refused": kinds.count("refused"),
            "killed": kinds.count("killed"),
            "landed_early": kinds.count("landed early"),
            "other": len(kinds) - sum(kinds.count(k) for k in ("landed", "landed early", "refused", "killed")),
            "error_m": mean,
            "error_max_m": max(errors) if errors else None,
            "ratio_to_eval": None if (mean is None or eval_err is None) else mean / eval_err,
            "late_ticks": sum(f["late_ticks"] for f in found),
            "flights": found,
        }
        rows.append(row)
        shown = "-" if mean is None else f"{mean:.3f}"
        ratio = "-" if row["ratio_to_eval"] is None else f"{row['ratio_to_eval']:.2f}x"
        print(
            f"{cell[0]:>5g} {cell[1]:>+5g} {cell[2]:>+5g} {cell[3]:>4g} | {row['landed']:>6} {row['landed_early']:>5} "
            f"{row['refused']:>7} "
            f"{row['killed']:>6} {row['other']:>5} | {shown:>7} {ratio:>6} | {row['late_ticks']}"
        )
    totals = {k: sum(r[k] for r in rows) for k in ("landed", "landed_early", "refused", "killed", "other")}
    print(f"total: {totals}")
    name = args.out or f"transfer_grid_{args.vehicle}_{args.mode.replace('-', '')}" + (
        "" if args.controller == "datt_l1" else f"_{args.controller}"
    )
    path = write_result(
        name,
        {
            "vehicle": args.vehicle,
            "mode": args.mode,
            "controller": args.controller,
            "checkpoint": checkpoint,
            "flights_per_cell": args.flights,
            "workers": args.workers,
            "eval_star_error_m": eval_err,
            "totals": totals,
            "cells": rows,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
