"""Fitting an RMA adapter for a frozen DATT policy (paper §5.1; the network and its inputs are in
:mod:`datt.adapt.rma`).

The frozen policy flies with the adapter's *own* predictions as d̂ (so the adapter sees the state
distribution it will face), and every step one Adam step regresses the adapter's output to the
true d over all N drones (``rma.iterations`` steps, lr decayed linearly to
``rma.lr * rma.lr_final_frac``; paper: 10000 iterations of one 500-step rollout).
"""

from __future__ import annotations

import time
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf

from datt.adapt.rma import RmaAdaptation, RmaNet
from datt.checkpoint import save_checkpoint
from datt.configuration import instantiate_option, structured, with_options
from datt.control.datt import DattController
from datt.envs.factory import make_env
from datt.errors import ConfigError
from datt.policies.loading import load_actor
from datt.progress import ProgressReport
from datt.train.loggers import CsvLogger
from datt.train.schema import RmaParams, budget_factor


def _setup(cfg: DictConfig, rma: RmaParams) -> tuple:
    """The frozen base policy (``base_checkpoint``) flying ``rma.num_envs`` drones under the
    run's disturbance and references, an untrained adapter as their adaptation, episodes
    staggered. Returns (env, adapter, controller, the base checkpoint's payload)."""
    if cfg.base_checkpoint in (None, ""):
        raise ConfigError("base_checkpoint: fit_rma.py needs the policy checkpoint to adapt (base_checkpoint=...)")
    actor, train_cfg, base = load_actor(cfg.base_checkpoint, key="base_checkpoint")
    for p in actor.parameters():
        p.requires_grad_(False)
    torch.manual_seed(int(cfg.seed))
    env_cfg = with_options(train_cfg, disturbance=OmegaConf.to_container(cfg.disturbance))
    env_cfg.env.compile = False
    env = make_env(env_cfg, num_envs=int(rma.num_envs), seed=int(cfg.seed), traj=instantiate_option(cfg, "traj"))
    net = RmaNet(int(rma.history_len), accel_dt_s=env.dt_s if bool(rma.accel_input) else None, inputs=rma.inputs)
    adapter = RmaAdaptation(net=net)
    env.adaptation = adapter
    adapter.bind(env.n, env.dt_s, env.params.quad.gravity_mps2, env.device, env.dtype)
    env.stagger_episodes()  # spread resets: otherwise every 500th step is all fresh histories
    return env, adapter, DattController(actor), base


def adapter_loss(pred_mps2: torch.Tensor, true_mps2: torch.Tensor) -> torch.Tensor:
    """The fit's loss: the squared error of the predicted disturbance (``[N, 3]``, world frame),
    summed over the axes and averaged over the drones, in (m/s²)²."""
    return (pred_mps2 - true_mps2).pow(2).sum(-1).mean()


def train_rma(cfg: DictConfig, run_dir: Path, progress: bool = False) -> dict:
    """``fit_rma.py base_checkpoint=<policy>``: fit an adapter for a frozen policy; ``progress``:
    lines of its progress (:class:`datt.progress.ProgressReport`)."""
    rma = structured(RmaParams, cfg.rma, "rma")
    env, adapter, controller, base = _setup(cfg, rma)
    net = adapter.net
    optim = torch.optim.Adam(net.parameters(), lr=float(rma.lr))
    logger = CsvLogger(run_dir, "rma_metrics.csv")
    td = env.reset()
    history = []
    t0 = time.perf_counter()
    iterations = max(1, int(int(rma.iterations) * budget_factor(cfg)))
    final_frac = float(rma.lr_final_frac)
    report = ProgressReport("fit_rma", iterations, "iterations", enabled=progress)
    # linear decay to lr * final_frac: at a constant lr the per-step loss over 1024 drones stays noisy
    sched = torch.optim.lr_scheduler.LambdaLR(optim, lambda i: 1.0 - (1.0 - final_frac) * min(i / iterations, 1.0))
    for it in range(1, iterations + 1):
        td["action"] = controller.act(env, td)
        step, td = env.step_and_maybe_reset(td)
        net.train()
        pred = net(adapter.history.float())
        loss = adapter_loss(pred, env.disturbance.current_mps2.float())
        optim.zero_grad(set_to_none=True)
        loss.backward()
        optim.step()
        sched.step()
        net.eval()
        if it % rma.log_every == 0 or it == iterations:
            row = {
                "iteration": it,
                "loss": loss.item(),
                "lr": optim.param_groups[0]["lr"],  # for the next step
                "tracking_error_m": step["next", "tracking_error_m"].mean().item(),
            }
            history.append(row)
            logger.log(row, step=it)
            report.update(it, loss=f"{row['loss']:.4f} (m/s²)²", err=f"{row['tracking_error_m']:.3f} m")
    payload = {
        "rma": net.state_dict(),
        "history_len": int(rma.history_len),
        "accel_dt_s": net.accel_dt_s,
        "inputs": net.inputs,
        "base_checkpoint": str(cfg.base_checkpoint),
        "frames": int(base["frames"]),
        "config_yaml": OmegaConf.to_yaml(cfg, resolve=True),
    }
    save_checkpoint(run_dir / "rma.pt", payload)
    return {"history": history, "wall_s": time.perf_counter() - t0}
