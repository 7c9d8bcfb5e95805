"""Evaluation helpers of the tasks: a controller over the seeded bank under named conditions,
results as a table, CSV and the per-step inference time."""

from __future__ import annotations

import csv
from collections.abc import Sequence
from pathlib import Path

from omegaconf import DictConfig, OmegaConf
from rich.table import Table

from datt.checkpoint import write_torch
from datt.control import Controller, DattController, HoverController
from datt.envs.factory import make_env
from datt.eval.metrics import format_error
from datt.eval.plots import plot_disturbance_estimate, plot_group_axes, plot_tracks
from datt.eval.rollout import evaluate
from datt.eval.schema import per_seed_name
from datt.eval.timing import step_times_ms, summarize_ms


def print_metrics(console, title: str, conditions: dict) -> None:
    """One row per condition, one column per bank group (mean ± std, crashes), to ``console``
    (anything with ``print``: :class:`datt.tasks.common.RunOutput`)."""
    table = Table(title=f"{title}: tracking error (m)")
    table.add_column("condition")
    groups = list(next(iter(conditions.values()))["groups"])
    for g in groups:
        table.add_column(g, justify="right")
    for cond, res in conditions.items():
        table.add_row(cond, *(format_error(res["groups"][g]) for g in groups))
    console.print(table)


def evaluate_conditions(
    cfg: DictConfig,
    policy,
    conditions: dict,
    run_dir: Path,
    plots: bool,
    tag: str,
    seed: int = 0,
    trace_path: Path | None = None,
) -> dict:
    """Fly the bank ``cfg.eval.bank`` under each condition (name -> {disturbance, adaptation};
    ``None`` skips it) with ``policy``: a trained actor, a ready
    :class:`~datt.control.Controller`, or None (hovering, the reference point)."""
    results = {}
    eval_cfg = OmegaConf.merge(cfg, {"env": {"compile": False}})
    if policy is None:
        controller = HoverController()
    elif isinstance(policy, Controller):
        controller = policy
    else:
        controller = DattController(policy)
    for name, cond in conditions.items():
        if cond is None:  # a sweep can drop a default condition by setting it to null
            continue
        res = evaluate(eval_cfg, lambda env: controller, cond["disturbance"], cond["adaptation"], seed=seed)
        labels = {k: v if isinstance(v, str) else OmegaConf.to_container(v) for k, v in cond.items()}
        if trace_path is not None:  # for side-by-side plots across controllers (tables.py main)
            tr = res["trace"]
            trace = {"pos_m": tr.pos_m, "ref_m": tr.ref_m, "err_m": tr.err_m, "crashed_at": tr.crashed_at}
            write_torch(trace_path, {**trace, "names": res["names"], "counts": res["counts"]})
        results[name] = {**labels, "groups": res["groups"]}
        if plots:
            slug = "".join(c if c.isalnum() else "_" for c in name)
            names, counts = res["names"], res["counts"]
            plot_tracks(res["trace"], names, counts, run_dir / f"tracks_{slug}.png", title=f"{tag}: {name}")
            dt_s = float(cfg.env.dt_s)
            plot_group_axes(res["trace"], names, counts, dt_s, run_dir / f"axes_{slug}.png", title=f"{tag}: {name}")
            if cond["adaptation"] != "none":  # an estimate to show (d̂ = 0 has none)
                path = run_dir / f"dhat_{slug}.png"
                plot_disturbance_estimate(res["trace"], names, counts, dt_s, path, title=f"{tag}: {name}")
    return results


def end_of_run_plan(cfg: DictConfig, seeds: Sequence[int]) -> list[tuple[str, int, DictConfig]]:
    """The end-of-run evaluation in order: ``(name in metrics.json, seed, condition)`` for each of
    ``seeds`` and each condition of ``cfg.eval.conditions`` that is not switched off (null); the
    name per :func:`~datt.eval.schema.per_seed_name`."""
    return [
        (per_seed_name(name, seed, seeds), int(seed), cond)
        for seed in seeds
        for name, cond in cfg.eval.conditions.items()
        if cond is not None  # a sweep can drop a default condition by setting it to null
    ]


def evaluate_end_of_run(
    cfg: DictConfig, policy, run_dir: Path, plots: bool, tag: str, seeds: Sequence[int], on_part=None
) -> tuple[dict, dict]:
    """A training run's own evaluation: ``cfg.eval.conditions`` with ``policy`` at each of
    ``seeds`` (names per :func:`~datt.eval.schema.per_seed_name`), and a hovering drone on the
    first seed's bank as the reference point. Returns ``(conditions, hover)``. ``on_part``
    (optional) is called with the conditions finished so far after each condition, so a caller
    can keep them on disk as they finish."""
    conditions = {}
    for name, seed, cond in end_of_run_plan(cfg, seeds):
        conditions.update(evaluate_conditions(cfg, policy, {name: cond}, run_dir, plots, tag=tag, seed=seed))
        if on_part is not None:
            on_part(dict(conditions))
    clean = {"disturbance": "none", "adaptation": "none"}
    hover = evaluate_conditions(cfg, None, {"hover": clean}, run_dir, False, "hover", seed=int(seeds[0]))["hover"]
    return conditions, hover


def measure_inference(cfg: DictConfig, controller, timing) -> dict | None:
    """Median/p95 ms per control step at batch 1 (see :mod:`datt.eval.timing`); ``timing`` is
    the ``eval.timing`` node (``steps: 0`` skips)."""
    if timing.steps <= 0:
        return None
    env = make_env(cfg, num_envs=1, seed=int(cfg.seed))
    if timing.compile:
        env.compile_kernels(sim=False)  # the controller side: observation kernel and adaptation update
    times = step_times_ms(env, controller, timing.steps, timing.warmup_steps, threads=timing.threads)
    return {**summarize_ms(times), "batch": 1, "threads": timing.threads}


def write_metrics_csv(path: Path, conditions: dict) -> None:
    """One row per (condition, group): mean_m, std_m, crashes, episodes (written atomically)."""
    from datt.runs import atomic_write

    with atomic_write(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["condition", "group", "mean_m", "std_m", "crashes", "episodes"])
        for cond, res in conditions.items():
            for group, row in res["groups"].items():
                w.writerow([cond, group, row["mean_m"], row["std_m"], row["crashes"], row["episodes"]])
