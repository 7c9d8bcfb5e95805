"""Per-step controller latency: every controller at batch 1, and DATT at batch 4096.

    python benchmarks/controller_latency.py [--steps 300] [--mppi-steps 40] [--rounds 5]

Timing method of :mod:`datt.eval.timing`: per control step, adaptation update + observation
building + controller.act, after warm-up, on one torch thread (batch 1) or all threads (batch
4096), observation kernel and L1 update compiled, DATT's network traced and frozen (as eval.py
times them). DATT and L1-PID/L1-MPPI include their L1 update; MPPI uses the paper's 8192 samples x 40
steps (rollouts compiled with torch.compile). Writes ``benchmarks/results/controller_latency.json``.

On a shared VM the same measurement drifts by 2x between quiet and busy phases of the host
(minutes apart), so batch-1 figures are taken in ``--rounds`` rounds, each measuring every
controller once (interleaved, so a busy phase hits all of them); the summary is the best round's
median per controller (as ``timeit`` reports the minimum) and the range of round medians.
"""

from __future__ import annotations

import argparse

from _common import write_result

from datt.configuration import compose
from datt.control.factory import build_controller
from datt.envs.factory import make_env
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
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args()
    rounds: dict[str, list[dict]] = {option: [] for option in CONTROLLERS}
    for k in range(a.rounds):
        for option in CONTROLLERS:
            steps = a.mppi_steps if "mppi" in option else a.steps
            rounds[option].append(measure(option, steps, warmup=5 if "mppi" in option else 20))
        print(f"round {k + 1}: " + ", ".join(f"{o} {r[-1]['median_ms']:.3f}" for o, r in rounds.items()) + " ms")
    results = {}
    for option, rs in rounds.items():
        medians = [r["median_ms"] for r in rs]
        best = min(rs, key=lambda r: r["median_ms"])
        r = results[f"{option}@1"] = {**best, "round_medians_ms": medians}
        print(
            f"{option:8s} batch 1   : best-round median {r['median_ms']:8.3f} ms   p95 {r['p95_ms']:8.3f} ms   "
            f"(round medians {min(medians):.3f}-{max(medians):.3f})"
        )
    r = results["datt_l1@4096"] = measure("datt_l1", a.steps // 3, batch=4096, threads=None)
    print(
        f"datt_l1  batch 4096: median {r['median_ms']:8.3f} ms   p95 {r['p95_ms']:8.3f} ms "
        f"({r['median_ms'] / 4096 * 1e3:.2f} us per drone)"
    )
    ratio = results["mppi@1"]["median_ms"] / results["datt_l1@1"]["median_ms"]
    per_round = [m["median_ms"] / d["median_ms"] for m, d in zip(rounds["mppi"], rounds["datt_l1"])]
    print(
        f"MPPI / DATT (L1) at batch 1: {ratio:.0f}x (best rounds); "
        f"same round: {min(per_round):.0f}x-{max(per_round):.0f}x"
    )
    path = write_result(
        "controller_latency",
        {
            "results": results,
            "mppi_over_datt_l1": ratio,
            "mppi_over_datt_l1_same_round": per_round,
            "threads_batch1": 1,
            "rounds": a.rounds,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
