"""L1 estimator figures: per-step cost at batch 1 and 4096, and d̂ tracking error against the
low-pass cutoff (to choose ``adaptation.cutoff_tau_s``).

    python benchmarks/l1.py

Tracking runs N drones hovering with random command wiggles under ``brownian`` and ``wind``,
with the measured velocity exact or with Gaussian noise (mocap-differentiated velocity on a real
drone is noisy, and the law amplifies velocity noise by ~1/dt). Writes benchmarks/results/l1.json.
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import torch
from rich.console import Console
from rich.table import Table

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from datt.adapt import L1Adaptation  # noqa: E402
from datt.adapt.l1 import l1_step  # noqa: E402
from datt.sim import Brownian, Quadrotor, Wind  # noqa: E402

TAUS = [0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0]


def step_cost_ms(n: int, repeats: int = 2000, compiled: bool = True) -> dict:
    """``compiled=True``: as the env runs it after ``compile_kernels`` (compiled kernel from
    ``COMPILE_MIN_BATCH`` drones on, eager below)."""
    est = L1Adaptation()
    est.bind(n, 0.02, 9.81, "cpu", torch.float32)
    if compiled:
        est.compile()
    state = SimpleNamespace(vel_mps=torch.randn(n, 3), quat=torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4).contiguous())
    cmd = torch.tensor([[9.81, 0.0, 0.0, 0.0]]).expand(n, 4).contiguous()
    for _ in range(100):
        est.update(state, cmd)
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        est.update(state, cmd)
        times.append(1e3 * (time.perf_counter() - t0))
    times.sort()
    kernel = "compiled" if est._step is not l1_step else "eager"
    return {
        "batch": n,
        "kernel": kernel,
        "median_ms": statistics.median(times),
        "p95_ms": times[int(0.95 * len(times))],
    }


def tracking_rmse(tau: float, disturbance: str, vel_noise: float, n: int = 256, steps: int = 1000) -> float:
    gen = torch.Generator().manual_seed(0)
    quad = Quadrotor(n)
    dist = Brownian() if disturbance == "brownian" else Wind()
    dist.bind(n, 0.02, gen, "cpu", torch.float32)
    idx = torch.arange(n)
    dist.reset(idx, quad.state)
    est = L1Adaptation(cutoff_tau_s=tau)
    est.bind(n, 0.02, 9.81, "cpu", torch.float32)
    est.reset(idx, None, quad.state)
    sq, count = 0.0, 0
    for k in range(steps):
        cmd = torch.zeros(n, 4)
        cmd[:, 0] = 9.81 + 2.0 * torch.randn(n, generator=gen)
        cmd[:, 1:3] = 0.5 * torch.randn(n, 2, generator=gen) - 0.5 * quad.state.quat[:, 1:3]  # stay near level
        quad.step(cmd, dist.current_mps2)
        dist.update(quad.state)
        measured = SimpleNamespace(
            vel_mps=quad.state.vel_mps + vel_noise * torch.randn(n, 3, generator=gen), quat=quad.state.quat
        )
        d_hat = est.update(measured, cmd)
        if k >= 100:
            sq += (d_hat - dist.current_mps2).pow(2).sum().item()
            count += d_hat.numel()
    return (sq / count) ** 0.5


def main() -> None:
    torch.set_num_threads(1)
    # batch 1 runs the eager kernel either way; at 4096 compare the compiled one with eager
    cost = [step_cost_ms(1), step_cost_ms(4096, repeats=500), step_cost_ms(4096, repeats=500, compiled=False)]
    rows = []
    for disturbance in ("brownian", "wind"):
        for noise in (0.0, 0.02):
            rmse = {tau: tracking_rmse(tau, disturbance, noise) for tau in TAUS}
            rows.append(
                {
                    "disturbance": disturbance,
                    "vel_noise_std_mps": noise,
                    "rmse_mps2_by_tau_s": rmse,
                    "best_tau_s": min(rmse, key=rmse.get),
                }
            )
    table = Table(title="L1: RMSE of d̂ − d (m/s²) vs low-pass time constant τ")
    table.add_column("disturbance")
    table.add_column("vel noise")
    for tau in TAUS:
        table.add_column(f"τ={tau}", justify="right")
    for r in rows:
        table.add_row(
            r["disturbance"], f"{r['vel_noise_std_mps']}", *(f"{r['rmse_mps2_by_tau_s'][t]:.3f}" for t in TAUS)
        )
    console = Console()
    console.print(table)
    for c in cost:
        console.print(
            f"L1 update, batch {c['batch']} ({c['kernel']}): median {c['median_ms']:.4f} ms, p95 {c['p95_ms']:.4f} ms"
        )
    print(f"wrote {write_result('l1', {'step_cost': cost, 'tracking': rows})}")


if __name__ == "__main__":
    main()
