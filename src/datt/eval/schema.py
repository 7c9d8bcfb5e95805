"""Typed schemas of the evaluation config nodes: the ``eval`` node of ``eval.py``, ``train.py``'s
end-of-run evaluation and ``fit_rma.py``, whose shared keys have one home
(``conf/evaluation/common.yaml``). No defaults: the YAML is the only place a default lives."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from datt.configuration import SEED, THREADS, Range, check_option, ranged
from datt.errors import ConfigError
from datt.eval.protocol import PROTOCOLS

STEPS = Range(0, 10**7, integer=True)
BANK_COUNT = Range(1, 100_000, integer=True)  # references of one bank entry


def check_bank(bank: Any, key: str) -> None:
    """``eval.bank``: group name -> non-empty list of ``{traj: <traj option or node>, seed, count}``."""
    if not isinstance(bank, Mapping) or not bank:
        raise ConfigError(f"{key}: must map group names to lists of {{traj, seed, count}}, got {bank!r}")
    for group, items in bank.items():
        where = f"{key}.{group}"
        if not isinstance(items, Sequence) or isinstance(items, str) or not items:
            raise ConfigError(f"{where}: must be a non-empty list of {{traj, seed, count}}, got {items!r}")
        for i, item in enumerate(items):
            if not isinstance(item, Mapping) or set(item) != {"traj", "seed", "count"}:
                raise ConfigError(f"{where}[{i}]: must be {{traj, seed, count}}, got {item!r}")
            traj = item["traj"]
            if isinstance(traj, str):
                check_option("traj", traj, f"{where}[{i}].traj")
            elif not isinstance(traj, Mapping) or "_target_" not in traj:
                raise ConfigError(f"{where}[{i}].traj: must name a traj option or be a _target_ node, got {traj!r}")
            SEED.check(item["seed"], f"{where}[{i}].seed")
            BANK_COUNT.check(item["count"], f"{where}[{i}].count")


def check_conditions(conditions: Any, key: str) -> None:
    """``eval.conditions`` of a training run: name -> ``{disturbance, adaptation}`` option names
    (null drops a condition)."""
    if not isinstance(conditions, Mapping):
        raise ConfigError(f"{key}: must map condition names to {{disturbance, adaptation}}, got {conditions!r}")
    for name, cond in conditions.items():
        if cond is None:
            continue
        if not isinstance(cond, Mapping) or set(cond) != {"disturbance", "adaptation"}:
            raise ConfigError(f"{key}.{name}: needs disturbance and adaptation, got {cond!r}")
        for group in ("disturbance", "adaptation"):
            check_option(group, cond[group], f"{key}.{name}.{group}")


@dataclass
class TimingParams:
    """``eval.timing``: per-step inference time at batch 1 (``steps: 0`` skips)."""

    steps: int = ranged(MISSING, STEPS)
    warmup_steps: int = ranged(MISSING, STEPS)
    threads: int = ranged(MISSING, THREADS)  # torch threads while timing (a control loop on one core)
    compile: bool = MISSING  # torch.compile the observation kernel and adaptation update

    def validate(self) -> None:
        pass  # every rule is a field's own range


@dataclass
class SharedEvalParams:
    """The ``eval`` keys every job shares (``conf/evaluation/common.yaml``): ``train.py``'s
    end-of-run evaluation, ``eval.py`` and ``fit_rma.py`` fly the same bank the same way."""

    protocol: str = ranged(MISSING, Range(choices=tuple(PROTOCOLS)))
    # The paper's "failed: the drone diverges from the reference" as a rule (datt.eval.metrics):
    # the authors' evaluation has no termination, so a diverging drone ends far from its
    # reference; 1 m is the half-width of the zigzags' waypoint box, more than twice the error of
    # a drone that holds its start point (the hover reference row). Up to 20 m: the room.
    diverged_error_m: float = ranged(MISSING, Range(0.0, 20.0, low_open=True))
    seeds: list[int] = ranged(MISSING, SEED)  # the bank at each seed; one seed = condition names without a suffix
    plots: bool = MISSING
    bank: Any = MISSING

    def validate(self) -> None:
        check_bank(self.bank, "eval.bank")


@dataclass
class EvalParams(SharedEvalParams):
    """``eval`` of ``eval.py``: one controller over the seeded bank, per seed."""

    save_trace: bool = MISSING
    timing: TimingParams = field(default_factory=TimingParams)
    traj_count: int = ranged(
        MISSING, Range(1, 100_000, integer=True)
    )  # references drawn when the command gives traj= (a bank of one group)

    def validate(self) -> None:
        super().validate()
        self.timing.validate()


@dataclass
class AdapterEvalParams(SharedEvalParams):
    """``eval`` of ``fit_rma.py``: the evaluation after the fit (its four d̂ sources are fixed)."""


@dataclass
class EndOfRunEvalParams(SharedEvalParams):
    """``eval`` of ``train.py``: conditions evaluated at the end of training."""

    conditions: Any = MISSING  # name -> {disturbance, adaptation} (null drops a condition)

    def validate(self) -> None:
        super().validate()
        check_conditions(self.conditions, "eval.conditions")


def per_seed_name(name: str, seed: int, seeds: Sequence[int]) -> str:
    """A condition's name in a job evaluated at ``seeds``: ``name`` alone for one seed (the
    names tables.py and the wandb summary read), ``"<name> seed <k>"`` for several."""
    return name if len(seeds) == 1 else f"{name} seed {seed}"
