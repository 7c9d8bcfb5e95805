"""Throughput of the full training loop (collection + GAE + PPO updates) with the default
training config, and the projected wall time of the paper's 20M steps.

    python benchmarks/train_throughput.py [--iterations 12] [overrides...]
    python benchmarks/train_throughput.py --iterations 6 algo=sb3    # the authors' PPO

The first two iterations (compilation, warm-up) are excluded. Also reports the share of the
loop spent in the PPO update (GAE + gradient steps). Writes
benchmarks/results/train_throughput.json (with overrides: train_throughput_<overrides>.json).
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import timed_training_config, write_result  # noqa: E402

from datt.train.loggers import Logger  # noqa: E402
from datt.train.ppo import Trainer  # noqa: E402


class Timer(Logger):
    def __init__(self) -> None:
        self.stamps: list[tuple[float, int]] = []

    def log(self, metrics, step: int) -> None:
        self.stamps.append((time.perf_counter(), step))


def main() -> None:
    probe, cfg, overrides, per_iter = timed_training_config(__doc__.splitlines()[0], 12)
    timer = Timer()
    t0 = time.perf_counter()
    update_s: list[float] = []
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, tmp, timer)
        update = trainer.update

        def timed_update(batch):
            start = time.perf_counter()
            out = update(batch)
            update_s.append(time.perf_counter() - start)
            return out

        trainer.update = timed_update
        trainer.train()
    total_s = time.perf_counter() - t0
    (t_a, f_a), (t_b, f_b) = timer.stamps[1], timer.stamps[-1]
    steps_per_s = (f_b - f_a) / (t_b - t_a)
    # share of the loop spent in GAE + PPO epochs (the rest: collection = simulation + policy)
    update_share = sum(update_s[2:]) / (t_b - t_a)
    result = {
        "overrides": overrides,
        "frames_per_iteration": per_iter,
        "iterations_timed": len(timer.stamps) - 2,
        "steps_per_s": steps_per_s,
        "projected_20M_wall_min": 20e6 / steps_per_s / 60,
        "projected_15M_wall_min": 15e6 / steps_per_s / 60,  # Table 3's budget per run
        "ppo_update_share": update_share,
        "grad_steps_per_iteration": probe.algo.epochs * math.ceil(per_iter / probe.algo.minibatch_size),
        "run_wall_s": total_s,
    }
    print(
        f"{steps_per_s:,.0f} env steps/s (collection + PPO update); "
        f"20M steps ≈ {result['projected_20M_wall_min']:.1f} min, 15M ≈ {result['projected_15M_wall_min']:.1f} min"
    )
    print(f"PPO update (GAE + {result['grad_steps_per_iteration']} gradient steps) {update_share:.0%} of the loop")
    # one result per configuration: the default's, and one per set of overrides (algo=sb3 ...)
    given = [a for a in sys.argv[1:] if "=" in a and not a.startswith("--")]
    name = "_".join(["train_throughput", *(a.replace("=", "-").replace("/", "-") for a in given)])
    print(f"wrote {write_result(name, result)}")


if __name__ == "__main__":
    main()
