"""Wall time and steps a training config needs to reach a zigzag tracking error.

    python benchmarks/time_to_accuracy.py --label defaults [--eval-every 1000000]
        [--max-minutes 30] [--thresholds 0.2 0.1 0.07 0.055] [--protocol authors]
        [--seeds 0 1 2] [train overrides...]

Trains with ``conf/train.yaml`` plus the overrides (``train.total_frames`` bounds the run) and,
every ``--eval-every`` frames, flies the policy deterministically on the evaluation bank's
zigzags (``conf/bank/default.yaml``: the authors' generator, 10 references; no disturbance,
d̂ = 0) under ``--protocol`` (default ``authors``: the protocol of the paper's figures,
:mod:`datt.eval.protocol`) at each of ``--seeds``, pooled (the mean over seeds of the
per-seed means: every seed flies the same 10 references). The training clock excludes those
evaluations. Stops when every threshold
is reached, at ``--max-minutes`` of training, or at the total. Prints the table and writes
``benchmarks/results/time_to_accuracy_<label>.json`` (every evaluation with the last training
iteration's lr, KL estimate, training error and policy std, and per threshold the first frames
and training minutes at which the error was at or below it; null = not reached).

Run it alone on the machine: the wall times are the figures.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402
from omegaconf import OmegaConf  # noqa: E402

from datt.configuration import compose  # noqa: E402
from datt.eval.conditions import evaluate_conditions  # noqa: E402
from datt.tasks.common import set_threads  # noqa: E402
from datt.train.loggers import Logger  # noqa: E402
from datt.train.ppo import Trainer  # noqa: E402

CLEAN = {"clean": {"disturbance": "none", "adaptation": "none"}}


class Done(Exception):
    """Every threshold reached, or out of time: stop training."""


class AccuracyClock(Logger):
    """Evaluates the trainer's policy on the bank's zigzags every ``every`` frames, on a training
    clock that leaves the evaluations out."""

    def __init__(self, cfg, every: int, thresholds: list[float], max_s: float, run_dir: Path, seeds: list[int]) -> None:
        self.cfg = OmegaConf.merge(cfg, {"eval": {"bank": {"zigzag": cfg.eval.bank.zigzag}}})
        self.seeds = seeds
        self.every, self.thresholds, self.max_s, self.run_dir = every, sorted(thresholds, reverse=True), max_s, run_dir
        self.trainer: Trainer | None = None
        self.start = time.perf_counter()
        self.eval_s = 0.0
        self.next_eval = every
        self.points: list[dict] = []
        self.reached: dict[str, dict | None] = {f"{t:g}": None for t in self.thresholds}

    def train_s(self) -> float:
        return time.perf_counter() - self.start - self.eval_s

    def pooled_zigzag(self) -> dict:
        """The zigzag group's mean error (m) over ``self.seeds`` and its crashes, summed."""
        per_seed = [
            evaluate_conditions(self.cfg, self.trainer.actor, CLEAN, self.run_dir, False, "tta", seed=seed)["clean"][
                "groups"
            ]["zigzag"]
            for seed in self.seeds
        ]
        mean_m = sum(g["mean_m"] for g in per_seed) / len(per_seed)
        return {"mean_m": mean_m, "crashes": sum(g["crashes"] for g in per_seed)}

    def evaluate(self, frames: int) -> None:
        t0 = time.perf_counter()
        train_s = self.train_s()
        zig = self.pooled_zigzag()
        error_m = zig["mean_m"] if math.isfinite(zig["mean_m"]) else None  # None: every episode crashed
        point = {"frames": frames, "train_min": train_s / 60, "zigzag_m": error_m, "crashes": zig["crashes"]}
        if self.trainer.history:  # the training iteration just done: its lr, KL estimate, training error
            last = self.trainer.history[-1]
            keep = ("lr", "kl_approx", "tracking_error_m")
            point |= {k: v for k, v in last.items() if k in keep or k.startswith("policy_std")}
        self.points.append(point)
        print(
            f"{frames / 1e6:7.2f} M steps  {point['train_min']:6.1f} min  zigzag {zig['mean_m']:.4f} m"
            f"  crashes {zig['crashes']}  lr {point.get('lr', math.nan):.2e}"
            f"  kl {point.get('kl_approx', math.nan):.4f}",
            flush=True,
        )
        for t in self.thresholds:
            key = f"{t:g}"
            if self.reached[key] is None and zig["crashes"] == 0 and error_m is not None and error_m <= t:
                self.reached[key] = {"frames": frames, "train_min": point["train_min"]}
        self.eval_s += time.perf_counter() - t0

    def log(self, metrics, step: int) -> None:
        if step >= self.next_eval:
            self.next_eval += self.every
            self.evaluate(step)
            if all(v is not None for v in self.reached.values()):
                raise Done("every threshold reached")
        if self.train_s() > self.max_s:
            self.evaluate(step)
            raise Done("out of time")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--label", required=True, help="names the result file")
    parser.add_argument("--eval-every", type=int, default=1_000_000, help="frames between evaluations")
    parser.add_argument("--max-minutes", type=float, default=30.0, help="training time limit")
    parser.add_argument("--thresholds", type=float, nargs="+", default=[0.2, 0.1, 0.07, 0.055])
    parser.add_argument("--protocol", default="authors", help="eval.protocol of the evaluations")
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2], help="evaluation seeds, pooled")
    parser.add_argument("overrides", nargs="*", default=[])
    args = parser.parse_args()

    quiet = ["logger=csv", "train.progress=false", "train.eval_at_end=false", f"eval.protocol={args.protocol}"]
    cfg = compose("train", [*quiet, *args.overrides])
    set_threads(cfg.threads)
    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp)
        clock = AccuracyClock(cfg, args.eval_every, args.thresholds, args.max_minutes * 60, run_dir, args.seeds)
        trainer = Trainer(cfg, run_dir, clock)
        clock.trainer = trainer
        clock.start = time.perf_counter()  # construction (env, compile) is not training
        try:
            trainer.train()
            stop = "total steps reached"
            if not clock.points or clock.points[-1]["frames"] != trainer.frames:
                clock.evaluate(trainer.frames)
        except Done as exc:
            stop = str(exc)
    print(f"stopped: {stop}")
    for key, hit in clock.reached.items():
        where = "not reached" if hit is None else f"{hit['frames'] / 1e6:.1f} M steps, {hit['train_min']:.1f} min"
        print(f"  <= {key} m: {where}")
    path = write_result(
        f"time_to_accuracy_{args.label}",
        {
            "label": args.label,
            "overrides": args.overrides,
            "protocol": args.protocol,
            "seeds": args.seeds,
            "eval_every": args.eval_every,
            "max_minutes": args.max_minutes,
            "stopped": stop,
            "reached": clock.reached,
            "evaluations": clock.points,
        },
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
