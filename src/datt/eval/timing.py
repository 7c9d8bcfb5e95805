"""Per-step inference time of a controller, as a flight computer would pay it.

Method (the authors published none; this is ours): one drone (batch 1, or ``num_envs``) flies the
first reference of the bank closed-loop in the simulator. Each control step the timer covers
what runs on the controller's side of the loop:

    adaptation update (L1 / RMA / none) -> observation building -> controller.act

A controller that builds its own inputs from the state (``builds_observation``: PID, MPPI, the
frozen DATT path) does that inside ``act``; for the others the env's observation is built in
the timed region.
and not the plant (simulator step, disturbance, reference advance). The first ``warmup_steps``
steps (allocator, torch.compile, caches) are discarded; the rest give median and p95 in ms.
Torch runs on ``threads`` intra-op threads (default 1, as a control loop pinned to one core
would: at batch 1 a thread pool only adds wake-up latency, badly so on a busy machine).
``clock`` is injectable so tests can check the warm-up exclusion without wall-clock timing.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import torch

from datt.control.base import Controller


@torch.no_grad()
def step_times_ms(
    env,
    controller: Controller,
    steps: int = 200,
    warmup_steps: int = 20,
    threads: int | None = 1,
    clock: Callable[[], float] = time.perf_counter,
) -> list[float]:
    """Milliseconds per control step for ``steps`` steps after ``warmup_steps`` untimed ones.
    The env is reset once; drones that finish or crash simply keep flying (no auto-reset)."""
    if steps < 1 or warmup_steps < 0:
        raise ValueError(f"timing: steps must be >= 1 and warmup_steps >= 0, got {steps}, {warmup_steps}")
    previous_threads = torch.get_num_threads()
    if threads:
        torch.set_num_threads(int(threads))
    try:
        return _timed_loop(env, controller, steps, warmup_steps, clock)
    finally:
        torch.set_num_threads(previous_threads)


def _timed_loop(env, controller: Controller, steps: int, warmup_steps: int, clock: Callable[[], float]) -> list[float]:
    td = env.reset()
    controller.reset(env)
    action = controller.act(env, td)
    times = []
    for k in range(warmup_steps + steps):
        s, cmd, d = env.advance_plant(action)
        t0 = clock()
        env.adaptation.update(s, cmd, d)
        if not controller.builds_observation:
            td = env.observe()
        action = controller.act(env, td)
        t1 = clock()
        if k >= warmup_steps:
            times.append(1e3 * (t1 - t0))
    return times


def summarize_ms(times: list[float]) -> dict:
    arr = np.asarray(times, dtype=float)
    return {"median_ms": float(np.median(arr)), "p95_ms": float(np.percentile(arr, 95)), "steps": int(arr.size)}
