"""``eval.py``: one controller over the seeded bank, per seed (``eval.seeds``), plus its per-step
inference time at batch 1."""

from __future__ import annotations

import json
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from datt.configuration import command_overrides, structured
from datt.control.factory import build_controller
from datt.eval.conditions import evaluate_conditions, measure_inference, print_metrics, write_metrics_csv
from datt.eval.schema import EvalParams
from datt.tasks.common import console, hydra_run_dir, set_threads
from datt.tasks.validation import validate_config


def bank_of_given_traj(cfg: DictConfig, count: int) -> DictConfig:
    """A ``traj=<option>`` on the command line replaces the bank by one group of that family
    (``count`` references, seed ``seed``; a CSV file is one reference), so
    ``eval.py traj=csv traj.path=my.csv`` flies the user's file. A bank given on the same command
    line (``bank@eval.bank=...``) wins."""
    keys = {o.lstrip("+~").split("=", 1)[0]: o.split("=", 1)[-1] for o in command_overrides() or []}
    name = keys.get("traj")
    if name is None or any(k.startswith(("bank", "eval.bank")) for k in keys):  # a bank given too: it wins
        return cfg
    cfg = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    single = "CsvReference" in str(cfg.traj.get("_target_", ""))
    cfg.eval.bank = {name: [{"traj": cfg.traj, "seed": int(cfg.seed), "count": 1 if single else count}]}
    return cfg


def run_eval(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """Evaluate ``cfg.controller``; writes ``metrics.json``, ``metrics.csv`` (and traces/plots)."""
    validate_config("eval", cfg)
    params = structured(EvalParams, cfg.eval, "eval")
    cfg = bank_of_given_traj(cfg, params.traj_count)
    run_dir = run_dir or hydra_run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    set_threads(cfg.threads)
    controller, merged, labels = build_controller(cfg)
    name = labels["controller"]
    cond = {"disturbance": merged.disturbance, "adaptation": merged.adaptation}
    label = f"{name} {labels['disturbance']}/{labels['adaptation']}"
    results = {}
    for seed in params.seeds:
        trace = run_dir / f"trace_seed{seed}.pt" if params.save_trace else None
        results.update(
            evaluate_conditions(
                merged,
                controller,
                {f"{label} seed {seed}": cond},
                run_dir,
                params.plots,
                name,
                seed=int(seed),
                trace_path=trace,
            )
        )
    metrics = {**labels, "conditions": results}
    print_metrics(console, f"{name} on the seeded bank", results)
    inference = measure_inference(merged, controller, params.timing)
    if inference is not None:
        metrics["inference_ms"] = inference
        console.print(
            f"inference at batch 1: median {inference['median_ms']:.3f} ms, p95 {inference['p95_ms']:.3f} ms "
            f"({inference['steps']} steps after warm-up, {inference['threads']} threads)"
        )
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2, default=str) + "\n")
    write_metrics_csv(run_dir / "metrics.csv", results)
    return metrics
