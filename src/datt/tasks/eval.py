"""``eval.py``: one controller over the seeded bank, per seed (``eval.seeds``), plus its per-step
inference time at batch 1."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from datt.configuration import command_overrides, structured
from datt.control.factory import build_controller
from datt.eval.conditions import evaluate_conditions, measure_inference, print_metrics, write_metrics_csv
from datt.eval.metrics import format_error
from datt.eval.schema import EvalParams
from datt.paths import resolve_path
from datt.progress import ProgressReport
from datt.runs import write_json
from datt.tasks.common import console, hydra_run_dir, set_threads, sweep_group, wandb_run_id
from datt.tasks.validation import validate_config
from datt.train.loggers import RESULT_COLUMNS, condition_key, eval_summary, log_results_run, result_rows


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
    results, wandb_names = {}, {}
    metrics = {**labels, "conditions": results, "complete": False, "seeds_done": []}
    progress = ProgressReport("eval", len(params.seeds), "seeds", every_s=0.0)  # a seed is one whole bank
    try:
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
            wandb_names[f"{label} seed {seed}"] = condition_key(
                labels["disturbance"], labels["adaptation"], int(seed), params.seeds
            )
            metrics["seeds_done"].append(int(seed))
            _write_records(run_dir, metrics, results)  # each finished seed is on disk as it finishes
            finished = len(metrics["seeds_done"])
            progress.update(finished, seed=str(seed), error=_group_errors(results[f"{label} seed {seed}"]))
        print_metrics(console, f"{name} on the seeded bank", results)
        inference = measure_inference(merged, controller, params.timing)
    except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM through the entry point: what is done stays
        signal_name = exc.args[0] if exc.args else "SIGINT"
        done = metrics["seeds_done"]
        kept = f"seeds {done} of {list(params.seeds)} are in {run_dir / 'metrics.json'}" if done else "no seed finished"
        raise KeyboardInterrupt(f"{signal_name}: {kept} (complete: false)") from None
    if inference is not None:
        metrics["inference_ms"] = inference
        console.print(
            f"inference at batch 1: median {inference['median_ms']:.3f} ms, p95 {inference['p95_ms']:.3f} ms "
            f"({inference['steps']} steps after warm-up, {inference['threads']} threads)"
        )
    metrics["complete"] = True
    _write_records(run_dir, metrics, results)
    _log_to_wandb(cfg, run_dir, metrics, {wandb_names[k]: v for k, v in results.items()})
    return metrics


def _group_errors(result: dict) -> str:
    """One condition's error per bank group, as the table prints it (``zigzag 0.021 ± 0.004``)."""
    return "; ".join(f"{group} {format_error(row)}" for group, row in result["groups"].items())


def _write_records(run_dir: Path, metrics: dict, results: dict) -> None:
    """``metrics.json`` (strict JSON: a NaN is null) and ``metrics.csv``, each written atomically."""
    write_json(run_dir / "metrics.json", metrics)
    write_metrics_csv(run_dir / "metrics.csv", results)


def training_run(checkpoint: str) -> tuple[str | None, str | None]:
    """The wandb run id and group of the training run whose run dir holds ``checkpoint``, as
    ``train.py`` named them (id ``<parent dir>-<run dir>``; a multirun job's group
    ``<sweep_name or multirun>/<sweep dir>``); (None, None) for a checkpoint outside a run dir."""
    run_dir = resolve_path(checkpoint)
    run_dir = run_dir if run_dir.is_dir() else run_dir.parent
    if not (run_dir / "config.yaml").is_file():
        return None, None
    return wandb_run_id(run_dir), sweep_group(run_dir)


def _log_to_wandb(cfg: DictConfig, run_dir: Path, metrics: dict, conditions: dict) -> None:
    """``logger=wandb``: a wandb run (job type ``eval``) in the checkpoint's training run's group,
    its id in the config (``train_run_id``), the summary ``eval/<condition>/<group>/<stat>`` (the
    condition named as train.py names the same one: :func:`~datt.train.loggers.condition_key`) and
    ``inference/<stat>``, the plots and the evaluation as a Table."""
    if not cfg.logger.wandb:
        return
    train_run_id, group = training_run(str(cfg.checkpoint)) if cfg.get("checkpoint") else (None, None)
    summary = eval_summary(conditions)
    summary.update({f"inference/{k}": v for k, v in (metrics.get("inference_ms") or {}).items()})
    rows = result_rows(conditions)
    config = {**OmegaConf.to_container(cfg, resolve=True), "train_run_id": train_run_id}
    log_results_run(
        cfg.logger,
        run_dir,
        config,
        name=f"eval-{run_dir.name}",
        group=group,
        job_type="eval",
        summary=summary,
        images={p.stem: p for p in sorted(run_dir.glob("*.png"))},
        tables={"eval/table": (RESULT_COLUMNS, rows)} if rows else {},
    )
