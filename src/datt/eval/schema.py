"""Typed schemas of the evaluation config nodes (``eval`` in ``conf/eval.yaml`` and the end-of-run
``eval`` of ``conf/train.yaml``). No defaults: the YAML is the only place a default lives."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from omegaconf import MISSING

from datt.errors import ConfigError
from datt.eval.protocol import get_protocol


@dataclass
class TimingParams:
    """``eval.timing``: per-step inference time at batch 1 (``steps: 0`` skips)."""

    steps: int = MISSING
    warmup_steps: int = MISSING
    threads: int = MISSING  # torch threads while timing (a control loop on one core)
    compile: bool = MISSING  # torch.compile the observation kernel and adaptation update

    def validate(self) -> None:
        if self.steps < 0 or self.warmup_steps < 0 or self.threads < 1:
            raise ConfigError(
                f"eval.timing: steps and warmup_steps must be >= 0 and threads >= 1, got "
                f"{self.steps}, {self.warmup_steps}, {self.threads}"
            )


@dataclass
class EvalParams:
    """``eval`` of ``eval.py``: one controller over the seeded bank, per seed."""

    protocol: str = MISSING  # datt.eval.protocol.PROTOCOLS
    seeds: list[int] = MISSING
    plots: bool = MISSING
    save_trace: bool = MISSING
    timing: TimingParams = field(default_factory=TimingParams)
    bank: Any = MISSING
    traj_count: int = MISSING  # references drawn when the command gives traj= (a bank of one group)

    def validate(self) -> None:
        get_protocol(self.protocol)
        if not self.seeds:
            raise ConfigError("eval.seeds: must list at least one seed, e.g. [0] or [0,1,2]")
        if self.traj_count < 1:
            raise ConfigError(f"eval.traj_count: must be >= 1, got {self.traj_count}")
        self.timing.validate()


@dataclass
class EndOfRunEvalParams:
    """``eval`` of ``train.py``: conditions evaluated at the end of training."""

    protocol: str = MISSING  # datt.eval.protocol.PROTOCOLS
    conditions: Any = MISSING  # name -> {disturbance, adaptation} (null drops a condition)
    seed: int = MISSING
    plots: bool = MISSING
    bank: Any = MISSING

    def validate(self) -> None:
        get_protocol(self.protocol)
        for name, cond in (self.conditions or {}).items():
            if cond is not None and not {"disturbance", "adaptation"} <= set(cond):
                raise ConfigError(f"eval.conditions.{name}: needs disturbance and adaptation, got {dict(cond)}")
