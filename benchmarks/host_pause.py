"""How long a full garbage collection pauses the flying host, with and without the frozen heap.

    python benchmarks/host_pause.py [--rounds 5]

Loads what ``deploy.py`` loads before it arms (the deploy config, the shipped policy traced as
the flight model traces it, cflib, the simulated Crazyflie's modules), then times ``gc.collect()``
(a generation-2 collection: it holds the interpreter lock, so every thread of the host, the
control loop included, waits) as the heap is, and inside :func:`datt.deploy.runner.frozen_heap`,
which the runner enters before arming. Writes ``benchmarks/results/host_pause.json``.
"""

from __future__ import annotations

import argparse
import gc
import statistics
import time

from _common import write_result

from datt.configuration import compose
from datt.deploy.runner import frozen_heap


def load_the_host() -> int:
    """Import and build what deploy.py holds at arming time; the number of tracked objects."""
    import cflib.crtp  # noqa: F401

    from datt.control.factory import build_controller
    from datt.deploy.sim import SimCrazyflie  # noqa: F401
    from datt.envs.factory import make_env
    from datt.tasks import deploy  # noqa: F401

    cfg = compose("deploy", [])
    ctrl, ctrl_cfg, _ = build_controller(cfg)
    env = make_env(ctrl_cfg, num_envs=1, seed=0)
    ctrl.reset(env)
    ctrl.act(env, env.reset())  # traces the policy, as the flight model's warm-up
    return len(gc.get_objects())


def pauses_ms(rounds: int) -> list[float]:
    out = []
    for _ in range(rounds):
        start = time.perf_counter()
        gc.collect()
        out.append((time.perf_counter() - start) * 1e3)
    return out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--rounds", type=int, default=5)
    a = ap.parse_args()
    objects = load_the_host()
    as_is = pauses_ms(a.rounds)
    with frozen_heap():
        frozen = pauses_ms(a.rounds)
    print(f"tracked objects at arming: {objects:,}")
    print(f"full collection, heap as is : median {statistics.median(as_is):7.2f} ms (max {max(as_is):.2f})")
    print(f"full collection, heap frozen: median {statistics.median(frozen):7.2f} ms (max {max(frozen):.2f})")
    path = write_result(
        "host_pause",
        {"tracked_objects": objects, "gc_pause_ms": as_is, "gc_pause_frozen_ms": frozen, "rounds": a.rounds},
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
