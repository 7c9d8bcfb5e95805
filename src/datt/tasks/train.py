"""``train.py``: train a DATT policy with PPO, checkpoint it and evaluate it on the seeded bank
(``stage=rma`` fits an RMA adapter instead, :mod:`datt.tasks.rma`)."""

from __future__ import annotations

import json
import time
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from datt.configuration import structured
from datt.errors import ConfigError, TrainingDiverged
from datt.eval.conditions import evaluate_conditions, print_metrics
from datt.eval.plots import plot_learning_curve
from datt.eval.schema import EndOfRunEvalParams
from datt.paths import original_cwd, resolve_path
from datt.tasks.common import console, hydra_run_dir, set_threads
from datt.train.loggers import CsvLogger, MultiLogger, WandbLogger
from datt.train.ppo import Trainer
from datt.train.schema import TrainParams, run_params


def resume_dir(resume) -> Path | None:
    """The run dir ``resume=`` names: ``true`` = the newest run with a ``last.pt`` under outputs/."""
    if resume in (False, None, "false", "False"):
        return None
    if resume in (True, "true", "True"):
        candidates = sorted((original_cwd() / "outputs").glob("**/last.pt"), key=lambda p: p.stat().st_mtime)
        if not candidates:
            raise ConfigError("resume: no run with a last.pt under outputs/; pass resume=<run dir>")
        return candidates[-1].parent
    path = resolve_path(resume)
    if not (path / "last.pt").is_file():
        raise ConfigError(f"resume: {str(path)!r} has no last.pt")
    return path


def wandb_group_and_tags(cfg: DictConfig, run_dir: Path) -> tuple[str | None, list[str]]:
    """All jobs of one multirun share a wandb group (``<sweep_name or multirun>/<sweep dir>``) and are
    tagged with their swept overrides (``ablation=h5``, ``seed=1``), so dashboards group by them."""
    group, tags = cfg.logger.get("group"), [str(t) for t in (cfg.logger.get("tags") or [])]
    try:
        from hydra.core.hydra_config import HydraConfig
        from hydra.types import RunMode

        hc = HydraConfig.get()
    except (ImportError, ValueError):
        return group, tags
    if hc.mode == RunMode.MULTIRUN:
        group = f"{cfg.sweep_name or 'multirun'}/{run_dir.parent.name}"
        tags += [o.lstrip("+") for o in hc.overrides.task if not o.lstrip("+").startswith(("sweep=", "hydra"))]
    return group, [t[:64] for t in tags]  # wandb caps tag length at 64


def run_train(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """Train, checkpoint, evaluate; returns the metrics written to ``metrics.json``."""
    run = run_params(cfg)
    train = structured(TrainParams, cfg.train, "train")
    set_threads(train.threads)
    if run.stage == "rma":
        from datt.tasks.rma import run_rma

        return run_rma(cfg, run_dir or hydra_run_dir())
    end_eval = structured(EndOfRunEvalParams, cfg.eval, "eval")
    resumed = resume_dir(run.resume)
    run_dir = resumed or run_dir or hydra_run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    if resumed is None:
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    loggers = [CsvLogger(run_dir)]
    if cfg.logger.wandb:
        group, tags = wandb_group_and_tags(cfg, run_dir)
        loggers.append(
            WandbLogger(
                run_dir,
                OmegaConf.to_container(cfg, resolve=True),
                project=cfg.logger.project,
                group=group,
                tags=tags,
                mode=cfg.logger.mode,
                name=run_dir.name,
                run_id=f"{run_dir.parent.name}-{run_dir.name}",
            )
        )
    logger = MultiLogger(loggers)
    trainer = Trainer(cfg, run_dir, logger, console)
    if resumed is not None:
        trainer.load(resumed / "last.pt")
        console.print(f"resuming {resumed} at {trainer.frames:,} frames")
    console.print(f"run dir: {run_dir}")
    t0 = time.perf_counter()
    try:
        history = trainer.train()
    except TrainingDiverged as exc:
        # tables.py reports this run as "failed" (as the paper does for diverged ablations)
        (run_dir / "failed.json").write_text(json.dumps({"message": str(exc), "frames": trainer.frames}) + "\n")
        raise
    finally:
        logger.close()
    wall_s = time.perf_counter() - t0
    metrics = {
        "frames": trainer.frames,
        "train_wall_s": wall_s,
        "steps_per_s": (trainer.frames / wall_s) if history else None,
        "horizon": trainer.env.horizon,
        "seed": run.seed,
    }
    if history and end_eval.plots:
        plot_learning_curve(trainer.history, run_dir / "learning_curve.png")
    if train.eval_at_end:
        seed = end_eval.seed
        metrics["conditions"] = evaluate_conditions(
            cfg, trainer.actor, cfg.eval.conditions, run_dir, end_eval.plots, tag=run_dir.name, seed=seed
        )
        clean = {"disturbance": "none", "adaptation": "none"}
        hover = evaluate_conditions(cfg, None, {"hover": clean}, run_dir, False, "hover", seed=seed)["hover"]
        metrics["hover_reference"] = hover
        print_metrics(console, f"evaluation ({run_dir.name})", {**metrics["conditions"], "hover (reference)": hover})
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics
