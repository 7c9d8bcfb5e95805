"""Entry points: ``train.py`` / ``eval.py`` (root shims) and the ``datt`` console script.

Every user error ends in one line on stderr (``error: <key>: <what>``) and exit code 2.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Callable

import torch
from omegaconf import DictConfig, OmegaConf
from rich.console import Console
from rich.table import Table

from datt.config import CONF_DIR, ConfigError, available_options
from datt.train.checkpoint import load_checkpoint

console = Console()


# -- shared helpers ------------------------------------------------------------------------
def _run_dir() -> Path:
    from hydra.core.hydra_config import HydraConfig

    return Path(HydraConfig.get().runtime.output_dir)


def _original_cwd() -> Path:
    try:
        from hydra.utils import get_original_cwd

        return Path(get_original_cwd())
    except ValueError:
        return Path.cwd()


def resolve_path(path: str | Path) -> Path:
    """A user path: absolute, else relative to where the command ran, else to the repository
    (so the shipped ``checkpoints/...`` work from any directory)."""
    p = Path(str(path)).expanduser()
    if p.is_absolute():
        return p
    here = _original_cwd() / p
    repo = CONF_DIR.parent / p
    return here if here.exists() or not repo.exists() else repo


def _set_threads(n) -> None:
    if n:
        torch.set_num_threads(int(n))


def preflight(argv: list[str]) -> None:
    """Reject unknown config-group options before Hydra prints a multi-line error."""
    groups = {p.name for p in CONF_DIR.iterdir() if p.is_dir()}
    for arg in argv:
        if arg.startswith("-") or "=" not in arg:
            continue
        key, value = arg.split("=", 1)
        key = key.lstrip("+~")
        group = key.split("@")[0]
        if group in groups and "," not in value and "(" not in value:
            allowed = available_options(group)
            if value not in allowed and value != "null":
                raise ConfigError(f"{group}: unknown option {value!r}; allowed: {', '.join(allowed)}")


def hydra_main(config_name: str, task: Callable[[DictConfig], object]) -> Callable[[], None]:
    """Wrap ``task`` in ``@hydra.main`` with one-line error reporting."""
    import hydra

    from datt.train.ppo import TrainingDiverged

    @hydra.main(config_path=str(CONF_DIR), config_name=config_name, version_base="1.3")
    def _main(cfg: DictConfig) -> None:
        try:
            task(cfg)
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
        except TrainingDiverged as exc:
            print(f"error: training diverged: {exc}", file=sys.stderr)
            sys.exit(3)

    def entry() -> None:
        try:
            preflight(sys.argv[1:])
        except ConfigError as exc:
            print(f"error: {exc}", file=sys.stderr)
            sys.exit(2)
        _main()

    return entry


def print_metrics(title: str, conditions: dict) -> None:
    from datt.eval.metrics import format_error

    table = Table(title=title)
    table.add_column("condition")
    groups = list(next(iter(conditions.values()))["groups"])
    for g in groups:
        table.add_column(f"{g} error (m)", justify="right")
    for cond, res in conditions.items():
        table.add_row(cond, *(format_error(res["groups"][g]) for g in groups))
    console.print(table)


def evaluate_conditions(cfg: DictConfig, policy, conditions: dict, run_dir: Path, plots: bool, tag: str) -> dict:
    """Fly the bank under each condition with ``policy``: a trained actor, a ready
    :class:`~datt.control.Controller`, or None (hovering, the reference point)."""
    from datt.control import Controller, DattController, HoverController
    from datt.eval.plots import plot_tracks
    from datt.eval.rollout import evaluate

    results = {}
    eval_cfg = OmegaConf.merge(cfg, {"env": {"compile": False}})
    if policy is None:
        factory = lambda env: HoverController()  # noqa: E731
    elif isinstance(policy, Controller):
        factory = lambda env: policy  # noqa: E731
    else:
        factory = lambda env: DattController(policy)  # noqa: E731
    for name, cond in conditions.items():
        res = evaluate(eval_cfg, factory, cond["disturbance"], cond["adaptation"], seed=int(cfg.eval.get("seed", 0)))
        labels = {k: v if isinstance(v, str) else OmegaConf.to_container(v) for k, v in cond.items()}
        results[name] = {**labels, "groups": res["groups"]}
        if plots:
            slug = "".join(c if c.isalnum() else "_" for c in name)
            plot_tracks(res["trace"], res["names"], res["counts"], run_dir / f"tracks_{slug}.png", title=f"{tag}: {name}")
    return results


# -- train ---------------------------------------------------------------------------------
def _resume_dir(resume) -> Path | None:
    if resume in (False, None, "false", "False"):
        return None
    if resume in (True, "true", "True"):
        candidates = sorted((_original_cwd() / "outputs").glob("**/last.pt"), key=lambda p: p.stat().st_mtime)
        if not candidates:
            raise ConfigError("resume: no run with a last.pt under outputs/; pass resume=<run dir>")
        return candidates[-1].parent
    path = resolve_path(resume)
    if not (path / "last.pt").is_file():
        raise ConfigError(f"resume: {str(path)!r} has no last.pt")
    return path


def run_train(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """Train, checkpoint, evaluate; returns the metrics written to ``metrics.json``."""
    from datt.eval.plots import plot_learning_curve
    from datt.train.logging import CsvLogger, MultiLogger, WandbLogger
    from datt.train.ppo import Trainer

    _set_threads(cfg.train.get("threads"))
    if cfg.get("stage", "ppo") == "rma":
        return run_rma(cfg, run_dir or _run_dir())
    if cfg.get("stage", "ppo") != "ppo":
        raise ConfigError(f"stage: unknown value {cfg.stage!r}; allowed: ppo, rma")
    resume_dir = _resume_dir(cfg.get("resume", False))
    run_dir = resume_dir or run_dir or _run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    if resume_dir is None:
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    loggers = [CsvLogger(run_dir)]
    if cfg.logger.get("wandb", False):
        choices = {k: cfg[k] for k in ("horizon", "seed")}
        loggers.append(
            WandbLogger(run_dir, OmegaConf.to_container(cfg, resolve=True), project=cfg.logger.project,
                        group=cfg.logger.get("group"), tags=list(cfg.logger.get("tags") or []),
                        mode=cfg.logger.mode, name=run_dir.name, run_id=f"{run_dir.name}-{choices['seed']}")  # fmt: skip
        )
    logger = MultiLogger(loggers)
    trainer = Trainer(cfg, run_dir, logger, console)
    if resume_dir is not None:
        trainer.load(resume_dir / "last.pt")
        console.print(f"resuming {resume_dir} at {trainer.frames:,} frames")
    console.print(f"run dir: {run_dir}")
    t0 = time.perf_counter()
    try:
        history = trainer.train()
    finally:
        logger.close()
    wall_s = time.perf_counter() - t0
    metrics = {
        "frames": trainer.frames,
        "train_wall_s": wall_s,
        "steps_per_s": (trainer.frames / wall_s) if history else None,
        "horizon": trainer.env.horizon,
        "seed": int(cfg.seed),
    }
    if history and cfg.eval.get("plots", True):
        plot_learning_curve(trainer.history, run_dir / "learning_curve.png")
    if cfg.train.eval_at_end:
        metrics["conditions"] = evaluate_conditions(cfg, trainer.actor, cfg.eval.conditions, run_dir,
                                                    cfg.eval.get("plots", True), tag=run_dir.name)  # fmt: skip
        clean = {"disturbance": "none", "adaptation": "none"}
        metrics["hover_reference"] = evaluate_conditions(cfg, None, {"hover": clean}, run_dir, False, "hover")["hover"]
        print_metrics(f"evaluation ({run_dir.name})", {**metrics["conditions"], "hover (reference)": metrics["hover_reference"]})
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


def run_rma(cfg: DictConfig, run_dir: Path) -> dict:
    """Fit an RMA adapter for ``base_checkpoint`` and evaluate DATT-RMA vs privileged/L1/none."""
    from datt.adapt.rma import train_rma
    from datt.control.datt import DattController
    from datt.eval.rollout import evaluate

    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    result = train_rma(cfg, run_dir, console)
    actor, train_cfg, _ = load_actor(cfg.base_checkpoint)
    eval_cfg = OmegaConf.merge(train_cfg, {"eval": cfg.eval, "env": {"compile": False}})
    conditions = {}
    for name, adaptation in (("d_hat=0", "none"), ("l1", "l1"), ("rma", None), ("privileged", "privileged")):
        choice = adaptation if adaptation else {"_target_": "datt.adapt.RmaAdaptation", "checkpoint": str(run_dir / "rma.pt")}
        res = evaluate(eval_cfg, lambda env: DattController(actor), "brownian", choice, seed=int(cfg.eval.get("seed", 0)))
        conditions[name] = {"disturbance": "brownian", "adaptation": name, "groups": res["groups"]}
    print_metrics("DATT under Brownian disturbance by adaptation", conditions)
    metrics = {"rma_train_wall_s": result["wall_s"], "rma_history": result["history"], "conditions": conditions}
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2) + "\n")
    return metrics


# -- eval ----------------------------------------------------------------------------------
def load_actor(path: str | Path):
    """Actor and its training config from a checkpoint (file or run dir)."""
    from datt.config import env_params_from_cfg, structured
    from datt.envs.tracking import action_bounds
    from datt.policies.networks import PolicyParams, make_actor

    data = load_checkpoint(resolve_path(path))
    train_cfg = OmegaConf.create(data["config_yaml"])
    params = structured(PolicyParams, train_cfg.policy, "policy")
    low, high = action_bounds(env_params_from_cfg(train_cfg.env))
    actor = make_actor(int(data["horizon"]), low, high, params)
    actor.load_state_dict(data["actor"])
    actor.eval()
    return actor, train_cfg, data


def _choice(group: str, default: str = "custom") -> str:
    """The option name Hydra chose for ``group`` (for labels)."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return str(HydraConfig.get().runtime.choices.get(group, default))
    except ValueError:
        return default


def run_eval(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """``eval.py``: one controller over the seeded bank, per seed (``eval.seeds``)."""
    from datt.config import instantiate_option

    run_dir = run_dir or _run_dir()
    run_dir.mkdir(parents=True, exist_ok=True)
    name = str(cfg.controller.name)
    merged = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    OmegaConf.set_struct(merged, False)
    if name == "datt":
        actor, train_cfg, data = load_actor(cfg.checkpoint)
        # The policy's observation layout (horizon, ablations) comes from its training config.
        merged = OmegaConf.merge(merged, {"horizon": train_cfg.horizon, "env": {"obs": train_cfg.env.obs}})
        OmegaConf.set_struct(merged, False)
        policy, extra = actor, {"checkpoint": str(cfg.checkpoint), "frames": int(data["frames"])}
    else:
        node = OmegaConf.create({k: v for k, v in OmegaConf.to_container(cfg.controller).items() if k != "name"})
        policy, extra = instantiate_option(OmegaConf.create({"controller": node}), "controller"), {}
    cond = {"disturbance": cfg.disturbance, "adaptation": cfg.adaptation}
    label = f"{name} {_choice('disturbance')}/{_choice('adaptation')}"
    results = {}
    for seed in cfg.eval.seeds:
        merged.eval.seed = int(seed)
        results.update(evaluate_conditions(merged, policy, {f"{label} seed {seed}": cond}, run_dir, cfg.eval.plots, name))
    metrics = {"controller": name, **extra, "conditions": results}
    print_metrics(f"{name} on the seeded bank", results)
    (run_dir / "metrics.json").write_text(json.dumps(metrics, indent=2, default=str) + "\n")
    return metrics


# -- console script ------------------------------------------------------------------------
train_main = hydra_main("train", run_train)
eval_main = hydra_main("eval", run_eval)
COMMANDS = {"train": train_main, "eval": eval_main}


def main() -> None:
    """``datt <command> [hydra overrides]``."""
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS:
        print(f"usage: datt {{{','.join(COMMANDS)}}} [overrides...]", file=sys.stderr)
        sys.exit(2)
    command = sys.argv.pop(1)
    sys.argv[0] = f"datt {command}"
    COMMANDS[command]()


__all__ = ["main", "run_train", "run_eval", "load_actor"]
