"""``train.py``: train a DATT policy with PPO, checkpoint it and evaluate it on the seeded bank
(an RMA adapter for a trained policy is ``fit_rma.py``, :mod:`datt.tasks.rma`)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from datt.configuration import config_groups, search_roots, structured
from datt.errors import TrainingDiverged
from datt.eval.conditions import end_of_run_plan, evaluate_end_of_run, print_metrics
from datt.eval.plots import plot_learning_curve
from datt.eval.schema import EndOfRunEvalParams
from datt.runs import OWN_RUN, RunLock, finite_json, record_failure, scheduler_signal, write_json
from datt.tasks.common import console, hydra_run_dir, set_threads, wandb_run_id
from datt.tasks.resume import finished_frames, holds_a_run, resume_config, resume_dir
from datt.tasks.stages import in_stages, run_stages, stage_plan
from datt.tasks.validation import validate_config
from datt.train.loggers import (
    RESULT_COLUMNS,
    CsvLogger,
    MultiLogger,
    WandbLogger,
    condition_key,
    eval_summary,
    result_rows,
)
from datt.train.ppo import Trainer
from datt.train.schema import TrainParams, budget_factor, check_ablation, run_params


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
    """Train, checkpoint, evaluate; returns the metrics written to ``metrics.json``.

    ``resume=<run>`` carries on that run with its own saved config (:mod:`datt.tasks.resume`);
    the run dir is locked while this process writes it."""
    validate_config("train", cfg)
    run = run_params(cfg)
    structured(TrainParams, cfg.train, "train")  # checked before anything is written
    check_ablation(cfg)
    if in_stages(cfg):
        stage_plan(cfg)  # a bad schedule is refused before anything is written
    set_threads(run.threads)
    resumed = resume_dir(run.resume) or _requeued_attempt(run_dir, own=run.resume == OWN_RUN)
    if resumed is not None:
        cfg = resume_config(cfg, resumed, config_groups(search_roots()))
        validate_config("train", cfg)  # the run's saved config is a file: checked like a command line
        _drop_own_hydra_dir(resumed, run_dir)
        done = finished_frames(resumed, int(int(cfg.train.total_frames) * budget_factor(cfg)))
        metrics_path = resumed / "metrics.json"
        if done is not None and _complete(metrics_path):  # report, write nothing
            console.print(
                f"run {resumed} is finished ({done:,} frames); nothing to do. To train on, resume with a larger "
                f"train.total_frames (> {done:,})"
            )
            return json.loads(metrics_path.read_text())
        # trained to its end but stopped before metrics.json: the resume only evaluates
        run_dir = resumed
    run_dir = run_dir or hydra_run_dir()
    with RunLock(run_dir):
        if in_stages(cfg):
            return run_stages(cfg, run_dir, _train_locked)
        return _train_locked(cfg, run_dir, resumed is not None)


def _complete(metrics_path: Path) -> bool:
    """Whether ``metrics.json`` holds a whole end-of-run evaluation (one stopped part-way says
    ``complete: false``: the resume evaluates again)."""
    if not metrics_path.is_file():
        return False
    return json.loads(metrics_path.read_text()).get("complete") is not False


def _requeued_attempt(given: Path | None, own: bool = False) -> Path | None:
    """In a scheduler's job (:func:`datt.runs.scheduler_signal`: submitit, locally or on Slurm), a
    run dir that already holds a checkpoint is this job's own earlier attempt, stopped by a time
    limit or a preemption and requeued with the same overrides: it resumes there; so does every
    job of a sweep carried on with ``resume=<sweep dir>`` (``own``: ``resume=own``). Elsewhere a
    run dir is new (``${uid:}``), so nothing is resumed without ``resume=``."""
    if scheduler_signal() is None and not own:
        return None
    try:
        run_dir = given or hydra_run_dir()
    except ValueError:  # not inside a Hydra job
        return None
    if holds_a_run(run_dir):
        console.print(f"{'carried-on' if own else 'requeued'} job: resuming its own run {run_dir}")
        return run_dir
    return None


def _drop_own_hydra_dir(resumed: Path, given: Path | None) -> None:
    """A resume trains in the resumed run's dir: the fresh dir Hydra made for this command holds
    only its own config copy and log, so it goes (no empty run for tables/resume=true to find)."""
    if given is not None:
        return
    try:
        own = hydra_run_dir()
    except ValueError:  # not inside a Hydra job
        return
    if own.resolve() == resumed.resolve() or not own.is_dir():
        return
    if all(p.name == ".hydra" or p.suffix == ".log" for p in own.iterdir()):
        shutil.rmtree(own, ignore_errors=True)


def _train_locked(cfg: DictConfig, run_dir: Path, resumed: bool) -> dict:
    run = run_params(cfg)
    train = structured(TrainParams, cfg.train, "train")
    end_eval = structured(EndOfRunEvalParams, cfg.eval, "eval")
    loggers = [CsvLogger(run_dir)]
    trainer = Trainer(cfg, run_dir, MultiLogger(loggers))
    if resumed:
        trainer.load(run_dir / "last.pt")
        loggers[0].keep_until(trainer.frames)  # rows logged after the checkpoint are trained again
        console.print(f"resuming {run_dir} at {trainer.frames:,} of {trainer.total_frames:,} frames")
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
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
                run_id=wandb_run_id(run_dir),
            )
        )
    logger = trainer.logger
    console.print(f"run dir: {run_dir}")
    try:
        return _train_and_evaluate(cfg, run_dir, trainer, run, train, end_eval)
    finally:  # the wandb run holds the evaluation too: it closes after it (or on any error)
        logger.close()


def _train_and_evaluate(cfg, run_dir: Path, trainer, run, train, end_eval) -> dict:
    """Train, then the end-of-run evaluation; every result goes to metrics.json and the loggers
    (wandb's summary gets ``eval/<condition>/<group>/<stat>``, the plots and the table)."""
    try:
        history = trainer.train()
    except TrainingDiverged as exc:
        # tables.py reports this run as "failed" (as the paper does for diverged ablations)
        record_failure(run_dir, "diverged", f"training diverged: {exc}", frames=trainer.frames)
        raise
    metrics = {
        "frames": trainer.frames,
        "train_wall_s": trainer.train_wall_s,  # summed over every segment of a resumed run
        "steps_per_s": (trainer.frames / trainer.train_wall_s) if history and trainer.train_wall_s > 0 else None,
        "horizon": trainer.env.horizon,
        "seed": run.seed,
    }
    if history and end_eval.plots:
        plot_learning_curve(trainer.history, run_dir / "learning_curve.png")
    if train.eval_at_end:

        def keep(done: dict) -> None:  # each finished condition on disk (a signal keeps them), not yet complete
            write_json(run_dir / "metrics.json", {**metrics, "conditions": done, "complete": False})

        try:
            metrics["conditions"], hover = evaluate_end_of_run(
                cfg, trainer.actor, run_dir, end_eval.plots, run_dir.name, end_eval.seeds, on_part=keep
            )
        except KeyboardInterrupt as exc:  # SIGINT, or SIGTERM through the entry point: say what is kept
            signal_name = exc.args[0] if exc.args else "SIGINT"
            raise KeyboardInterrupt(
                f"{signal_name}: training finished ({run_dir / 'last.pt'}); the conditions evaluated so far are in "
                f"{run_dir / 'metrics.json'} (complete: false); resume={run_dir} evaluates again"
            ) from None
        metrics["hover_reference"] = hover
        print_metrics(console, f"evaluation ({run_dir.name})", {**metrics["conditions"], "hover (reference)": hover})
    write_json(run_dir / "metrics.json", metrics)
    names = end_of_run_names(cfg, end_eval.seeds)
    summary = {"time/frames": trainer.frames, "time/train_wall_s": trainer.train_wall_s}
    summary.update(eval_summary(metrics.get("conditions") or {}, names))
    rows = result_rows(metrics.get("conditions") or {}, names)
    trainer.logger.results(
        summary,
        images={p.stem: p for p in sorted(run_dir.glob("*.png"))},
        tables={"eval/table": (RESULT_COLUMNS, rows)} if rows else {},
    )
    trainer.logger.checkpoints(
        f"policy-{wandb_run_id(run_dir)}",
        [run_dir / name for name in ("best.pt", "last.pt", "config.yaml", "metrics.json")],
        {k: v for k, v in summary.items() if v is not None},
    )
    return finite_json(metrics)


def end_of_run_names(cfg, seeds) -> dict[str, str]:
    """metrics.json's name of each end-of-run condition (``clean``, ``brownian seed 1``) -> its
    wandb name (:func:`~datt.train.loggers.condition_key`: ``none-none``, ``brownian-privileged-
    seed1``), the name eval.py gives the same condition."""
    return {
        name: condition_key(cond.disturbance, cond.adaptation, seed, seeds)
        for name, seed, cond in end_of_run_plan(cfg, seeds)
    }
