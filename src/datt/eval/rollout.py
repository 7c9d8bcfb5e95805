"""Run a controller over a seeded bank of references and measure tracking.

A bank is a set of named reference groups, each a family drawn with its own seed (so every
controller, run and machine sees the same references). Default bank (``conf/bank/default.yaml``):
10 zigzags (seed 1000), 10 smooth references (5 poly + 5 chained_poly, seeds 2000/2001) and the
star. Where the drones start and which steps count is the evaluation protocol
(``eval.protocol``, :mod:`datt.eval.protocol`).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import torch
from omegaconf import DictConfig, OmegaConf

from datt.configuration import instantiate_option, load_option, with_options
from datt.control.base import Controller
from datt.envs.factory import make_env
from datt.envs.params import OBS_NOISE_KEYS
from datt.eval.metrics import diverged_episodes, episode_errors, summarize
from datt.eval.protocol import apply_protocol, get_protocol
from datt.refs.base import RefFamily
from datt.refs.composite import Seeded


@dataclass
class Trace:
    """One rollout. Shapes: pos_m/ref_m ``[N, T+1, 3]`` (including the start), err_m ``[N, T]``,
    action ``[N, T, 4]``, d_mps2/d_hat ``[N, T, 3]``, crashed_at ``[N]`` (T if no crash)."""

    pos_m: torch.Tensor
    ref_m: torch.Tensor
    err_m: torch.Tensor
    action: torch.Tensor
    d_mps2: torch.Tensor
    d_hat: torch.Tensor
    crashed_at: torch.Tensor
    step_ms: list[float]


class Concat(RefFamily):
    """Rows from several (seeded) families in order: ``parts`` = [(family, count), ...]."""

    def __init__(self, parts: list[tuple[RefFamily, int]]) -> None:
        self.parts = parts

    def sample(self, n: int, t_s: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        total = sum(c for _, c in self.parts)
        if n != total:
            raise ValueError(f"bank holds {total} references, asked for {n}")
        return torch.cat([fam.sample(c, t_s, generator) for fam, c in self.parts], dim=0)


@torch.no_grad()
def run_controller(env, controller: Controller, steps: int | None = None) -> Trace:
    """Fly every drone of ``env`` for one episode (no auto-reset), recording the trace."""
    steps = steps or env.params.episode_steps
    td = env.reset()
    controller.reset(env)
    n = env.n
    pos = [env.sim.state.pos_m.clone()]
    refs = [env.reference_now_m().clone()]
    errs, acts, ds, dhats, step_ms = [], [], [], [], []
    crashed_at = torch.full((n,), steps, dtype=torch.long, device=env.device)
    for k in range(steps):
        t0 = time.perf_counter()
        action = controller.act(env, td)
        step_ms.append(1e3 * (time.perf_counter() - t0))
        ds.append(env.disturbance.current_mps2.clone())
        dhats.append(td["d_hat"].clone())
        td["action"] = action
        out = env.step(td)["next"]
        pos.append(env.sim.state.pos_m.clone())
        refs.append(env.reference_now_m().clone())
        errs.append(out["tracking_error_m"][:, 0].clone())
        acts.append(action.clone())
        newly = out["terminated"][:, 0] & (crashed_at == steps)
        crashed_at[newly] = k
        td = out.exclude("reward", "done", "terminated", "truncated")
    return Trace(
        pos_m=torch.stack(pos, 1),
        ref_m=torch.stack(refs, 1),
        err_m=torch.stack(errs, 1),
        action=torch.stack(acts, 1),
        d_mps2=torch.stack(ds, 1),
        d_hat=torch.stack(dhats, 1),
        crashed_at=crashed_at,
        step_ms=step_ms,
    )


def build_bank(bank_cfg: DictConfig) -> tuple[list[str], list[int], RefFamily]:
    """``bank_cfg``: group name -> list of {traj: <option or config>, seed, count}."""
    names, counts, parts = [], [], []
    for group, items in bank_cfg.items():
        total = 0
        for item in items:
            traj_cfg = item["traj"]
            if isinstance(traj_cfg, str):  # an option of the traj group, on the run's search path
                traj_cfg = load_option("traj", traj_cfg)
            family = instantiate_option(OmegaConf.create({"traj": traj_cfg}), "traj")
            parts.append((Seeded(family, int(item["seed"])), int(item["count"])))
            total += int(item["count"])
        names.append(str(group))
        counts.append(total)
    return names, counts, Concat(parts)


def evaluate(cfg: DictConfig, controller_factory, disturbance: str, adaptation: str, seed: int = 0) -> dict:
    """Evaluate on ``cfg.eval.bank`` under the named disturbance/adaptation options and the
    protocol ``cfg.eval.protocol``.

    ``controller_factory(env) -> Controller``. Returns per-group summaries and the trace.
    """
    names, counts, bank = build_bank(cfg.eval.bank)
    protocol = get_protocol(str(cfg.eval.protocol))
    env_cfg = with_options(cfg, disturbance=disturbance, adaptation=adaptation)
    apply_protocol(env_cfg, protocol)
    # the bank measures tracking, not the sensor: no observation noise (the vehicle's randomisation,
    # env.quad.*, stays as configured: `randomization=deploy` evaluates on drawn vehicles)
    for key in OBS_NOISE_KEYS:
        env_cfg.env.obs[key] = 0.0
    env = make_env(env_cfg, num_envs=sum(counts), seed=seed, traj=bank)
    env.seed_starts(seed)
    trace = run_controller(env, controller_factory(env))
    crashed = trace.crashed_at < trace.err_m.shape[1]
    diverged = diverged_episodes(trace.err_m, trace.crashed_at, float(cfg.env.dt_s), float(cfg.eval.diverged_error_m))
    if protocol.count_every_step:
        errors = trace.err_m.mean(1)
    else:
        errors = episode_errors(trace.err_m, trace.crashed_at)
    out, start = {}, 0
    for name, count in zip(names, counts):
        sl = slice(start, start + count)
        out[name] = summarize(
            errors[sl], crashed[sl], leave_out_crashed=not protocol.count_every_step, diverged=diverged[sl]
        )
        out[name]["protocol"] = str(cfg.eval.protocol)
        start += count
    return {"groups": out, "trace": trace, "names": names, "counts": counts}
