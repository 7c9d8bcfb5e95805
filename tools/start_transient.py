"""Split a policy's bank error into the first second and the rest, under both evaluation protocols.

    python tools/start_transient.py [checkpoint] [--seeds 0 1 2] [--groups zigzag zigzag_fast]
        [--disturbance constant_authors] [--set controller=datt_l1 --set ...]

The authors' protocol (``eval.protocol=authors``) starts within ±0.5 m of the reference at zero
thrust; the project's starts on it at hover thrust (``datt.eval.protocol``). Printing the mean
error over the first ``--split-s`` seconds and over the rest shows how much of a difference
between the two is the start transient (docs/results.md, evaluation protocols). No disturbance
unless ``--disturbance`` names one; ``--set`` passes eval.py overrides (a controller, an
adapter). Without a disturbance the project protocol is deterministic, so it then runs one seed.
"""

from __future__ import annotations

import argparse

from datt.cli import run_tool
from datt.configuration import compose
from datt.control.factory import build_controller
from datt.eval.rollout import evaluate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", nargs="?", default="checkpoints/datt_h10.pt")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--groups", nargs="+", default=["zigzag", "zigzag_fast"])
    parser.add_argument("--split-s", type=float, default=1.0)
    parser.add_argument("--disturbance", default="none")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE")
    args = parser.parse_args()
    print("protocol seed group: all | first split | after split (m)")
    for protocol in ("project", "authors"):
        cfg = compose("eval", [f"checkpoint={args.checkpoint}", f"eval.protocol={protocol}", *args.set])
        controller, merged, _ = build_controller(cfg)
        split = round(args.split_s / float(merged.env.dt_s))
        deterministic = protocol == "project" and args.disturbance == "none"
        for seed in args.seeds[:1] if deterministic else args.seeds:
            res = evaluate(merged, lambda env, c=controller: c, args.disturbance, merged.adaptation, seed=seed)
            start = 0
            for name, count in zip(res["names"], res["counts"]):
                err = res["trace"].err_m[start : start + count]
                start += count
                if name in args.groups:
                    first, rest = err[:, :split].mean().item(), err[:, split:].mean().item()
                    print(f"{protocol} {seed} {name}: {err.mean().item():.4f} | {first:.4f} | {rest:.4f}")


if __name__ == "__main__":
    run_tool(main)
