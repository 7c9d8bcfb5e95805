"""Where one training iteration's time goes, and how far the PPO update is from the machine's
arithmetic peak.

    python benchmarks/profile_iteration.py [--iterations 6] [overrides...]

Runs the default training config for ``--iterations`` iterations (the first two, compilation and
warm-up, are left out) with timers around each part of the loop: collection (simulation and the
policy's actions: the rest of the iteration), GAE, and per gradient step the minibatch's indexing,
the loss's forward pass, the backward pass, the gradient clipping and the optimiser's step. The
update's FLOPs are counted by ``torch.utils.flop_counter.FlopCounterMode`` on one minibatch's
forward and backward; the machine's peak is a matmul microbenchmark of the same layer shapes
(minibatch x in -> out, forward and the two backward products) and of one large square matmul, at
the same torch thread count. Run it alone on the machine. Writes
benchmarks/results/profile_iteration.json.
"""

from __future__ import annotations

import math
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import timed_training_config, write_result  # noqa: E402

from datt.train.loggers import Logger  # noqa: E402
from datt.train.ppo import Trainer  # noqa: E402


class Stamps(Logger):
    """The time of each iteration's log call (the end of the iteration)."""

    def __init__(self) -> None:
        self.t: list[float] = []

    def log(self, metrics, step: int) -> None:
        self.t.append(time.perf_counter())


class Parts:
    """Seconds per named part, per iteration (``begin`` starts a new iteration's row)."""

    def __init__(self) -> None:
        self.rows: list[dict[str, float]] = []

    def begin(self) -> None:
        self.rows.append(defaultdict(float))

    def timed(self, name: str, fn):
        def wrapper(*args, **kwargs):
            start = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                if self.rows:
                    self.rows[-1][name] += time.perf_counter() - start

        return wrapper


def matmul_gflops(m: int, k: int, n: int, repeats: int = 50) -> float:
    """GFLOP/s of ``[m, k] @ [k, n]`` (2 m k n FLOPs each), best of ``repeats`` after a warm-up."""
    a, b = torch.randn(m, k), torch.randn(k, n)
    for _ in range(5):
        a @ b
    best = math.inf
    for _ in range(repeats):
        start = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - start)
    return 2 * m * k * n / best / 1e9


def update_flops(trainer: Trainer, batch) -> float:
    """FLOPs of one gradient step's forward and backward on a minibatch of the configured size: the
    matmul and convolution FLOPs torch's profiler counts (``with_flops``; elementwise work is not
    counted, so the figure is a lower bound of the work done)."""
    from torch.profiler import ProfilerActivity, profile

    data = batch.reshape(-1).select(*trainer._loss_keys, strict=False)[: trainer.algo.minibatch_size]
    with profile(activities=[ProfilerActivity.CPU], with_flops=True) as prof:
        losses = trainer.loss(data)
        (losses["loss_objective"] + losses["loss_critic"]).backward()
    trainer.optim.zero_grad(set_to_none=True)
    return float(sum(event.flops or 0 for event in prof.key_averages()))


def main() -> None:
    probe, cfg, overrides, per_iter = timed_training_config(__doc__.splitlines()[0], 6, "train.eval_at_end=false")
    stamps, parts = Stamps(), Parts()
    captured = {}
    real_backward, real_clip = torch.Tensor.backward, torch.nn.utils.clip_grad_norm_
    with tempfile.TemporaryDirectory() as tmp:
        trainer = Trainer(cfg, tmp, stamps)
        update = trainer.update

        def profiled_update(batch):
            parts.begin()
            out = parts.timed("update", update)(batch)
            captured.setdefault("batch", batch)  # with GAE's advantage and value target in it
            return out

        trainer.update = profiled_update
        trainer.gae = parts.timed("gae", trainer.gae)
        loss = trainer.loss
        trainer.loss = parts.timed("forward", loss)
        trainer.optim.step = parts.timed("optimizer", trainer.optim.step)
        torch.Tensor.backward = parts.timed("backward", real_backward)
        torch.nn.utils.clip_grad_norm_ = parts.timed("clip", real_clip)
        try:
            trainer.train()
        finally:
            torch.Tensor.backward, torch.nn.utils.clip_grad_norm_ = real_backward, real_clip
        trainer.loss = loss
        flops_per_step = update_flops(trainer, captured["batch"])
        nets = (trainer.actor, trainer.critic)
        linears = [m for net in nets for m in net.modules() if isinstance(m, torch.nn.Linear)]
    iters = [(stamps.t[i] - stamps.t[i - 1], parts.rows[i]) for i in range(2, len(stamps.t))]
    n = len(iters)
    iter_s = sum(t for t, _ in iters) / n
    names = ("update", "gae", "forward", "backward", "clip", "optimizer")
    mean = {k: sum(row[k] for _, row in iters) / n for k in names}
    steps = probe.algo.epochs * math.ceil(per_iter / probe.algo.minibatch_size)
    parts_s = {
        "collection": iter_s - mean["update"],
        "gae": mean["gae"],
        "forward": mean["forward"],
        "backward": mean["backward"],
        "clip": mean["clip"],
        "optimizer": mean["optimizer"],
        "indexing and the rest of the update": mean["update"]
        - sum(mean[k] for k in ("gae", "forward", "backward", "clip", "optimizer")),
    }
    achieved = flops_per_step * steps / (mean["forward"] + mean["backward"]) / 1e9
    mb = probe.algo.minibatch_size
    shapes = sorted({(lin.in_features, lin.out_features) for lin in linears})
    layer_peak = {f"{i}x{o}": matmul_gflops(mb, i, o) for i, o in shapes}
    square = matmul_gflops(1024, 1024, 1024, repeats=10)
    result = {
        "overrides": overrides,
        "torch_threads": torch.get_num_threads(),
        "frames_per_iteration": per_iter,
        "iterations_timed": n,
        "iteration_s": iter_s,
        "parts_s": parts_s,
        "parts_share": {k: v / iter_s for k, v in parts_s.items()},
        "gradient_steps_per_iteration": steps,
        "minibatch": mb,
        "update_gflop_per_step": flops_per_step / 1e9,
        "update_gflops_achieved_fwd_bwd": achieved,
        "matmul_gflops_layer_shapes": layer_peak,
        "matmul_gflops_1024_square": square,
    }
    print(f"iteration {iter_s:.2f} s ({per_iter:,} frames, {steps} gradient steps of {mb}):")
    for name, sec in parts_s.items():
        print(f"  {name:<38} {sec:7.3f} s  {sec / iter_s:6.1%}")
    print(f"update: {flops_per_step / 1e9:.3f} GFLOP per gradient step; forward + backward at {achieved:.1f} GFLOP/s")
    shown = ", ".join(f"{k} {v:.1f}" for k, v in layer_peak.items())
    print(f"matmul GFLOP/s at the layers' shapes (minibatch x in -> out): {shown}")
    print(f"matmul 1024^3: {square:.1f} GFLOP/s ({torch.get_num_threads()} threads)")
    print(f"wrote {write_result('profile_iteration', result)}")


if __name__ == "__main__":
    main()
