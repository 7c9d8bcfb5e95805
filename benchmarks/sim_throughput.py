"""Env steps per second through the TorchRL API (``step_and_maybe_reset``, what collectors
call), next to the bare dynamics kernel, eager and ``torch.compile``-d, for two action streams:

* ``hover``: the hover command, no disturbance (``disturbance=none`` is appended); drones stay
  in the box, so this is the steady-state cost of a step (episodes end only by truncation);
* ``random``: uniform random actions over the full bounds; most drones crash within ~20 steps,
  so every step also resets hundreds of drones (reference sampling dominates). This is the
  worst case, like the first iterations of training.

    python benchmarks/sim_throughput.py [--sizes 1024 4096 16384] [--steps 200] [--no-compile]

    python benchmarks/sim_throughput.py --out sim_throughput_firmware traj=zigzag disturbance=brownian \
        env.quad.rate_model=firmware

Writes benchmarks/results/sim_throughput.json (``--out``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from datt.configuration import compose  # noqa: E402
from datt.envs.factory import make_env  # noqa: E402


def make_actions(env, count: int, kind: str) -> list[torch.Tensor]:
    g = torch.Generator().manual_seed(0)
    lo, hi = env.action_low, env.action_high
    if kind == "random":
        return [lo + (hi - lo) * torch.rand(env.n, 4, generator=g) for _ in range(count)]
    return [env.hover_action for _ in range(count)]


def time_env(n: int, steps: int, compiled: bool, kind: str, overrides: list[str]) -> dict:
    if kind == "hover":
        overrides = [*overrides, "disturbance=none"]
    env = make_env(compose("sim", overrides), num_envs=n)
    if compiled:
        env.compile_kernels()
    actions = make_actions(env, 16, kind)
    td = env.reset()
    t0 = time.perf_counter()
    for k in range(10):  # warm-up (and compilation)
        td["action"] = actions[k % 16]
        _, td = env.step_and_maybe_reset(td)
    warmup_s = time.perf_counter() - t0
    resets = 0
    t0 = time.perf_counter()
    for k in range(steps):
        td["action"] = actions[k % 16]
        step, td = env.step_and_maybe_reset(td)
        resets += int(step["next", "done"].sum())
    elapsed = time.perf_counter() - t0
    sim = env.sim
    cmd = env.hover_action
    d = torch.zeros(n, 3)
    for _ in range(5):
        sim.step(cmd, d)
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.step(cmd, d)
    kernel_s = time.perf_counter() - t0
    return {
        "num_envs": n,
        "actions": kind,
        "compiled": compiled,
        "env_steps_per_s": n * steps / elapsed,
        "ms_per_batched_step": 1e3 * elapsed / steps,
        "kernel_steps_per_s": n * steps / kernel_s,
        "kernel_ms_per_batched_step": 1e3 * kernel_s / steps,
        "episodes_reset": resets,
        "warmup_s": warmup_s,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1024, 4096, 16384])
    parser.add_argument("--steps", type=int, default=200)
    parser.add_argument("--no-compile", action="store_true")
    parser.add_argument("--actions", nargs="+", default=["hover", "random"], choices=["hover", "random"])
    parser.add_argument("--out", default="sim_throughput", help="result name: benchmarks/results/<out>.json")
    parser.add_argument("overrides", nargs="*", default=["traj=zigzag", "disturbance=brownian"])
    args = parser.parse_args()
    rows = []
    for kind in args.actions:
        for compiled in [False] + ([] if args.no_compile else [True]):
            for n in args.sizes:
                rows.append(time_env(n, args.steps, compiled, kind, args.overrides))
    table = Table(title="TrackingEnv throughput (step_and_maybe_reset)")
    for col in ("N", "actions", "compiled", "resets", "env steps/s", "ms/step", "kernel steps/s", "kernel ms/step"):
        table.add_column(col, justify="right")
    for r in rows:
        table.add_row(
            str(r["num_envs"]),
            r["actions"],
            str(r["compiled"]),
            str(r["episodes_reset"]),
            f"{r['env_steps_per_s'] / 1e6:.2f} M",
            f"{r['ms_per_batched_step']:.2f}",
            f"{r['kernel_steps_per_s'] / 1e6:.2f} M",
            f"{r['kernel_ms_per_batched_step']:.2f}",
        )
    Console().print(table)
    path = write_result(args.out, {"overrides": args.overrides, "steps": args.steps, "rows": rows})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
