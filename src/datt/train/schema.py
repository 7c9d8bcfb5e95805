"""Typed schemas of the training task's config nodes (``train``, ``curriculum``, ``rma`` and the
run-level keys of ``conf/train.yaml``). No defaults here: the YAML is the only place a default
lives, and a key it does not give is an error naming the key."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from omegaconf import MISSING, DictConfig, OmegaConf

from datt.configuration import (
    BATCH,
    COUNT,
    FRACTION,
    HORIZON,
    LEARNING_RATE,
    NON_NEGATIVE_COUNT,
    SEED,
    TIME_S,
    Range,
    hydra_choice,
    load_option,
    ranged,
    structured,
)
from datt.errors import ConfigError

FIXED_REF_MODES = ("steps", "whole_run")
BUDGET = Range(0.0, 1000.0, low_open=True)  # a fraction (or multiple) of the configured steps


@dataclass
class RunParams:
    """Top-level keys of a training run."""

    horizon: int = ranged(MISSING, HORIZON)
    seed: int = ranged(MISSING, SEED)
    budget: float = ranged(MISSING, BUDGET)  # scales train.total_frames, curriculum.fixed_ref_frames
    sweep_name: str | None = MISSING
    resume: Any = MISSING  # false | true | <run dir>
    threads: int | None = ranged(MISSING, Range(1, 1024, integer=True, optional=True))  # null = torch default
    optimized_metric: str | None = None  # what the job returns to a sweeper (datt.tasks.common.headline)

    def validate(self) -> None:
        check_budget(self.budget)
        check_metric_path(self.optimized_metric)


@dataclass
class FitRmaParams:
    """Top-level keys of an RMA fit (``conf/fit_rma.yaml``)."""

    seed: int = ranged(MISSING, SEED)
    budget: float = ranged(MISSING, BUDGET)  # scales rma.iterations
    sweep_name: str | None = MISSING
    base_checkpoint: str = MISSING  # the policy to adapt (frozen)
    threads: int | None = ranged(MISSING, Range(1, 1024, integer=True, optional=True))  # null = torch default
    optimized_metric: str | None = None  # what the job returns to a sweeper (datt.tasks.common.headline)

    def validate(self) -> None:
        check_budget(self.budget)
        check_metric_path(self.optimized_metric)


@dataclass
class TrainParams:
    """``train``: the PPO run's length and bookkeeping."""

    total_frames: int = ranged(MISSING, COUNT)  # frames (env steps summed over the drones)
    checkpoint_every: int = ranged(MISSING, COUNT)  # iterations between last.pt writes
    init_from: str | None = MISSING  # start from this checkpoint's weights (fine-tuning)
    eval_at_end: bool = MISSING
    stagger_episodes: bool = MISSING
    progress: bool = MISSING  # lines of progress (datt.progress); false: none
    progress_every_s: float = ranged(MISSING, TIME_S)  # seconds between two progress lines
    stages: Any = MISSING  # null | [{name, frames, set: {dotted key: value}}] (datt.tasks.stages)

    def validate(self) -> None:
        pass  # every rule is a field's own range


@dataclass
class CurriculumParams:
    """``curriculum``: the first ``fixed_ref_frames`` frames fly the one reference ``fixed``
    (``fixed_ref: steps``, the paper's 2.5 M), or every frame of the run (``fixed_ref: whole_run``,
    what the authors' code did: one zigzag of one seed until an env's 5000th episode,
    ``reset_thresh`` in ``configuration/configuration.py`` line 139 and ``TrajectoryEnv.reset`` in
    ``learning/tasks/trajectory_fbff.py`` lines 47-55, past the end of a 15-25 M-step run of 10
    envs). ``fixed_ref_frames: 0`` skips the fixed reference under both (the no_fixed_ref ablation)."""

    fixed_ref_frames: int = ranged(MISSING, NON_NEGATIVE_COUNT)
    fixed_ref: str = ranged(MISSING, Range(choices=FIXED_REF_MODES))
    fixed: Any = MISSING  # a reference family node with _target_ (datt.refs.Fixed)

    def validate(self) -> None:
        pass  # every rule is a field's own range


@dataclass
class RmaParams:
    """``rma``: fitting an RMA adapter (``fit_rma.py``, :mod:`datt.train.rma`)."""

    iterations: int = ranged(MISSING, COUNT)
    num_envs: int = ranged(MISSING, BATCH)
    lr: float = ranged(MISSING, LEARNING_RATE)
    lr_final_frac: float = ranged(MISSING, FRACTION)  # linear decay of the lr to lr x this (1.0 = constant)
    history_len: int = ranged(MISSING, Range(1, 10_000, integer=True))
    accel_input: bool = MISSING
    inputs: str = ranged(MISSING, Range(choices=("project", "authors")))  # datt.adapt.rma.INPUT_LAYOUTS
    log_every: int = ranged(MISSING, COUNT)

    def validate(self) -> None:
        pass  # every rule is a field's own range


def run_params(cfg: DictConfig) -> RunParams:
    """The run-level keys of a composed training config, validated."""
    return _top_level(RunParams, cfg)


def fit_rma_params(cfg: DictConfig) -> FitRmaParams:
    """The run-level keys of a composed RMA-fit config, validated."""
    return _top_level(FitRmaParams, cfg)


def _top_level(schema: type, cfg: DictConfig):
    return structured(schema, {k: cfg.get(k) for k in schema.__dataclass_fields__ if k in cfg}, "")


def check_metric_path(value: Any) -> None:
    """``optimized_metric``: null, or a dotted path into a run's metrics.json (parts without
    spaces, ``*`` allowed in a part: ``conditions.clean.groups.zigzag.mean_m``)."""
    if value is None:
        return
    text = str(value)
    if not isinstance(value, str) or not text or any(not part or part != part.strip() for part in text.split(".")):
        raise ConfigError(
            f"optimized_metric: must be null or a dotted path into the run's metrics.json "
            f"(e.g. conditions.clean.groups.zigzag.mean_m), got {value!r}"
        )


def check_budget(value: Any) -> float:
    """``budget`` as a float > 0 (it scales every step count of a run; 1 = as configured)."""
    BUDGET.check(value, "budget")
    return float(value)


def budget_factor(cfg: DictConfig) -> float:
    """``cfg.budget``, checked: the factor on train.total_frames and curriculum.fixed_ref_frames
    (train.py) or rma.iterations (fit_rma.py), for sweeps on small machines."""
    return check_budget(cfg.budget)


def check_ablation(cfg: DictConfig) -> None:
    """An ablation option and a command-line value that undoes it (``ablation=h5 horizon=15``)
    would train one thing under the other's label: every key the chosen ablation sets must keep
    its value."""
    name = hydra_choice("ablation", "none")
    sets = OmegaConf.to_container(load_option("ablation", name), resolve=True)  # none: sets nothing

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
