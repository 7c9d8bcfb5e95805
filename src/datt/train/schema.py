"""Typed schemas of the training task's config nodes (``train``, ``curriculum``, ``rma`` and the
run-level keys of ``conf/train.yaml``). No defaults here: the YAML is the only place a default
lives, and a key it does not give is an error naming the key."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from omegaconf import MISSING, DictConfig, OmegaConf

from datt.configuration import check_horizon, hydra_choice, load_option, structured
from datt.errors import ConfigError


def _need(ok: bool, key: str, msg: str) -> None:
    if not ok:
        raise ConfigError(f"{key}: {msg}")


def _is_int(x: Any) -> bool:
    return isinstance(x, int) and not isinstance(x, bool)


@dataclass
class RunParams:
    """Top-level keys of a training run."""

    horizon: int = MISSING
    seed: int = MISSING
    stage: str = MISSING  # ppo | rma
    budget: float = MISSING  # scales train.total_steps, curriculum.fixed_ref_steps and rma.iterations
    sweep_name: str | None = MISSING
    base_checkpoint: str | None = MISSING
    resume: Any = MISSING  # false | true | <run dir>

    def validate(self) -> None:
        check_horizon(self.horizon)
        _need(self.stage in ("ppo", "rma"), "stage", f"unknown value {self.stage!r}; allowed: ppo, rma")
        check_budget(self.budget)


@dataclass
class TrainParams:
    """``train``: the PPO run's length and bookkeeping."""

    total_steps: int = MISSING
    checkpoint_every: int = MISSING  # iterations between last.pt writes
    init_from: str | None = MISSING  # start from this checkpoint's weights (fine-tuning)
    eval_at_end: bool = MISSING
    stagger_episodes: bool = MISSING
    progress: bool = MISSING
    threads: int | None = MISSING  # null = torch default (cores / parallel jobs under joblib)
    phases: Any = MISSING  # null | [{name, steps, set: {dotted key: value}}] (datt.tasks.phases)

    def validate(self) -> None:
        _need(self.total_steps >= 1, "train.total_steps", f"must be >= 1, got {self.total_steps}")
        _need(self.checkpoint_every >= 1, "train.checkpoint_every", f"must be >= 1, got {self.checkpoint_every}")
        _need(self.threads is None or self.threads >= 1, "train.threads", f"must be null or >= 1, got {self.threads}")


FIXED_REF_MODES = ("steps", "whole_run")


@dataclass
class CurriculumParams:
    """``curriculum``: the first ``fixed_ref_steps`` frames fly the one reference ``fixed``
    (``fixed_ref: steps``, the paper's 2.5 M), or every frame of the run (``fixed_ref: whole_run``,
    what the authors' code did: one zigzag of one seed until an env's 5000th episode,
    ``reset_thresh`` in ``configuration/configuration.py`` line 139 and ``TrajectoryEnv.reset`` in
    ``learning/tasks/trajectory_fbff.py`` lines 47-55, past the end of a 15-25 M-step run of 10
    envs). ``fixed_ref_steps: 0`` skips the fixed reference under both (the no_fixed_ref ablation)."""

    fixed_ref_steps: int = MISSING
    fixed_ref: str = MISSING  # steps | whole_run
    fixed: Any = MISSING  # a reference family node with _target_ (datt.refs.Fixed)

    def validate(self) -> None:
        _need(self.fixed_ref_steps >= 0, "curriculum.fixed_ref_steps", f"must be >= 0, got {self.fixed_ref_steps}")
        _need(
            self.fixed_ref in FIXED_REF_MODES,
            "curriculum.fixed_ref",
            f"unknown value {self.fixed_ref!r}; allowed: {', '.join(FIXED_REF_MODES)}",
        )


@dataclass
class RmaParams:
    """``rma``: fitting an RMA adapter (``stage=rma``, :mod:`datt.train.rma`)."""

    iterations: int = MISSING
    num_envs: int = MISSING
    lr: float = MISSING
    lr_final_frac: float = MISSING  # linear decay of the lr to lr x this (1.0 = constant)
    history_len: int = MISSING
    accel_input: bool = MISSING
    inputs: str = MISSING  # project | authors (datt.adapt.rma)
    log_every: int = MISSING

    def validate(self) -> None:
        _need(self.iterations >= 1, "rma.iterations", f"must be >= 1, got {self.iterations}")
        _need(self.num_envs >= 1, "rma.num_envs", f"must be >= 1, got {self.num_envs}")
        _need(self.lr > 0, "rma.lr", f"must be > 0, got {self.lr}")
        _need(0 < self.lr_final_frac <= 1, "rma.lr_final_frac", f"must be in (0, 1], got {self.lr_final_frac}")
        _need(self.log_every >= 1, "rma.log_every", f"must be >= 1, got {self.log_every}")
        _need(  # the layouts of datt.adapt.rma.INPUT_LAYOUTS (not imported here: no torch in the schema)
            self.inputs in ("project", "authors"),
            "rma.inputs",
            f"unknown value {self.inputs!r}; allowed: project, authors",
        )


def run_params(cfg: DictConfig) -> RunParams:
    """The run-level keys of a composed training config, validated."""
    keys = RunParams.__dataclass_fields__
    return structured(RunParams, {k: cfg.get(k) for k in keys if k in cfg}, "")


def check_budget(value: Any) -> float:
    """``budget`` as a float > 0 (it scales every step count of a run; 1 = as configured)."""
    try:
        budget = float(value)
    except (TypeError, ValueError):
        budget = float("nan")
    _need(budget > 0, "budget", f"must be a number > 0 (fraction of the configured steps), got {value!r}")
    return budget


def budget_factor(cfg: DictConfig) -> float:
    """``cfg.budget``, checked: the factor on train.total_steps, curriculum.fixed_ref_steps and
    rma.iterations (sweeps on small machines)."""
    return check_budget(cfg.budget)


def check_ablation(cfg: DictConfig) -> None:
    """An ablation option and a command-line value that undoes it (``ablation=h5 horizon=15``)
    would train one thing under the other's label: every key the chosen ablation sets must keep
    its value."""
    name = hydra_choice("ablation", "none")
    if name in ("none", "custom"):
        return
    sets = OmegaConf.to_container(load_option("ablation", name), resolve=True)

    def walk(node, prefix):
        for key, value in node.items():
            path = f"{prefix}{key}"
            if isinstance(value, dict):
                walk(value, path + ".")
            elif OmegaConf.select(cfg, path) != value:
                raise ConfigError(
                    f"{path}: {OmegaConf.select(cfg, path)} contradicts ablation={name} (which sets {path}={value}); "
                    "drop one of the two"
                )

    walk(sets, "")
