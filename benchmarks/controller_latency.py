"""Per-step controller latency: every controller at batch 1, and DATT at batch 4096.

    python benchmarks/controller_latency.py [--steps 300] [--mppi-steps 40]

Timing method of :mod:`datt.eval.timing`: per control step, adaptation update + observation
building + controller.act, after warm-up, on one torch thread (batch 1) or all threads (batch
4096), observation kernel and L1 update compiled, DATT's network traced and frozen (as eval.py
times them). DATT and L1-PID/L1-MPPI include their L1 update; MPPI uses the paper's 8192 samples x 40
steps (rollouts compiled with torch.compile). Writes ``benchmarks/results/controller_latency.json``.
"""

from __future__ import annotations

import argparse

from _common import write_result

from datt.cli import build_controller
from datt.config import compose, make_env
from datt.eval.timing import step_times_ms, summarize_ms

CONTROLLERS = ["datt", "datt_l1", "pid", "l1_pid", "mppi", "l1_mppi"]


def measure(option: str, steps: int, batch: int = 1, threads: int | None = 1, warmup: int = 20) -> dict:
    ctrl, cfg, _ = build_controller(compose("eval", [f"controller={option}"]))
    env = make_env(cfg, num_envs=batch, seed=0).compile_kernels(sim=False)  # as eval.py times it
    return summarize_ms(step_times_ms(env, ctrl, steps=steps, warmup_steps=warmup, threads=threads))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--mppi-steps", type=int, default=40)
    a = ap.parse_args()
    results = {}
    for option in CONTROLLERS:
        steps = a.mppi_steps if "mppi" in option else a.steps
        results[f"{option}@1"] = measure(option, steps, warmup=5 if "mppi" in option else 20)
        r = results[f"{option}@1"]
        print(f"{option:8s} batch 1   : median {r['median_ms']:8.3f} ms   p95 {r['p95_ms']:8.3f} ms")
    r = results["datt_l1@4096"] = measure("datt_l1", a.steps // 3, batch=4096, threads=None)
    print(f"datt_l1  batch 4096: median {r['median_ms']:8.3f} ms   p95 {r['p95_ms']:8.3f} ms "
          f"({r['median_ms'] / 4096 * 1e3:.2f} us per drone)")  # fmt: skip
    ratio = results["mppi@1"]["median_ms"] / results["datt_l1@1"]["median_ms"]
    print(f"MPPI / DATT (L1) at batch 1: {ratio:.0f}x")
    path = write_result("controller_latency", {"results": results, "mppi_over_datt_l1": ratio, "threads_batch1": 1})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
