"""A training schedule in phases, from one command: ``train.phases`` lists the phases of one run,
each a number of frames and the values it changes; phase k starts from phase k-1's weights.

A phase is a whole PPO run in ``<run>/phase<k>_<name>/`` (its own config, learning curve, lr
schedule from ``algo.lr`` down to ``algo.lr x algo.lr_final_frac`` over its frames, a fresh
optimiser) started with ``train.init_from`` = the previous phase's ``last.pt``, exactly what a
chain of ``train.init_from`` commands does; the first phase starts from the run's own
``train.init_from`` (null = fresh weights), so a schedule can fine-tune a checkpoint
(``experiment=deploy``). The curriculum's fixed reference flies only in the first phase (later
phases start with ``curriculum.fixed_ref_frames: 0`` unless they set it). The end-of-run
evaluation runs once, on the last phase; the run's own ``last.pt`` and ``metrics.json`` are the
last phase's, so ``eval.py checkpoint=<run>/last.pt`` and ``tables.py`` see one run.

``resume=<run>`` (or ``true``) carries a phased run on: finished phases (their ``metrics.json``)
are kept, the interrupted one resumes from its ``last.pt``, the rest run.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from datt.errors import ConfigError, TrainingInterrupted
from datt.runs import atomic_write, finite_json, read_failure, write_json

# Keys a phase may not set: they say which run this is, or the schedule itself.
FORBIDDEN_PREFIXES = ("train.phases", "train.init_from", "train.total_frames", "resume", "seed", "horizon")
PHASE_NAME = re.compile(r"^[A-Za-z0-9_-]+$")


def is_phased(cfg: DictConfig) -> bool:
    return OmegaConf.select(cfg, "train.phases", default=None) is not None


def phase_plan(cfg: DictConfig) -> list[tuple[str, int, dict[str, Any]]]:
    """``train.phases`` checked: ``[(dir name, frames, {dotted key: value})]``. Every key must exist
    in the config (a typo would silently train the wrong schedule), and the phases' frames must add
    up to ``train.total_frames`` (the run's total, which budget, resume and tables read)."""
    node = cfg.train.phases
    phases = OmegaConf.to_container(node, resolve=True) if isinstance(node, ListConfig | DictConfig) else node
    if not isinstance(phases, list):
        raise ConfigError(f"train.phases: must be a list of {{name, frames, set}} or null, got {phases!r}")
    plan, names = [], set()
    for k, phase in enumerate(phases, start=1):
        where = f"train.phases[{k - 1}]"
        if isinstance(phase, dict) and "steps" in phase:
            raise ConfigError(f"{where}.steps: no longer a setting; use frames (the same number: frames)")
        if not isinstance(phase, dict) or set(phase) - {"name", "frames", "set"} or "frames" not in phase:
            raise ConfigError(f"{where}: must be a mapping with keys name, frames and set (only), got {phase!r}")
        name = str(phase.get("name") or f"phase{k}")
        if not PHASE_NAME.match(name) or name in names:
            raise ConfigError(f"{where}.name: {name!r} must be unique and use only letters, digits, _ and -")
        names.add(name)
        frames = phase["frames"]
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise ConfigError(f"{where}.frames: must be an integer >= 1, got {frames!r}")
        values = phase.get("set") or {}
        if not isinstance(values, dict):
            raise ConfigError(f"{where}.set: must map dotted config keys to values, got {values!r}")
        for key in values:
            if any(key == p or key.startswith(p + ".") for p in FORBIDDEN_PREFIXES):
                raise ConfigError(
                    f"{where}.set: {key} cannot change between phases (the phases set: everything but "
                    f"{', '.join(FORBIDDEN_PREFIXES)})"
                )
            if OmegaConf.select(cfg, key, default="\0missing") == "\0missing":
                raise ConfigError(f"{where}.set: unknown config key {key!r}")
        plan.append((f"phase{k}_{name}", frames, values))
    if not plan:
        raise ConfigError("train.phases: empty list; use null for a run without phases")
    total = sum(frames for _, frames, _ in plan)
    if total != int(cfg.train.total_frames):
        raise ConfigError(
            f"train.phases: the phases add up to {total:,} frames but train.total_frames is "
            f"{int(cfg.train.total_frames):,}; set train.total_frames={total}"
        )
    return plan


def phase_config(cfg: DictConfig, k: int, plan, init_from: Path | None) -> DictConfig:
    """The whole config of phase ``k`` (0-based): ``cfg`` with the phase's values, its frames and the
    previous phase's weights (the first phase: the run's ``train.init_from``); no phases of its own."""
    _, frames, values = plan[k]
    out = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    OmegaConf.update(out, "train.phases", None)
    OmegaConf.update(out, "train.total_frames", frames)
    if k > 0:
        OmegaConf.update(out, "train.init_from", str(init_from))
        OmegaConf.update(out, "curriculum.fixed_ref_frames", 0)
    last = k == len(plan) - 1
    OmegaConf.update(out, "train.eval_at_end", last and bool(cfg.train.eval_at_end))
    for key, value in values.items():
        OmegaConf.update(out, key, value, merge=False)
    return out


def phased_parent(run_dir: Path) -> Path | None:
    """The phased run a phase dir belongs to (``<run>/phase<k>_<name>``), else None."""
    parent = run_dir.parent
    if not re.match(r"^phase\d+_", run_dir.name) or not (parent / "config.yaml").is_file():
        return None
    return parent if is_phased(OmegaConf.load(parent / "config.yaml")) else None


def run_phases(cfg: DictConfig, run_dir: Path, train_one) -> dict:
    """Train every phase of ``cfg.train.phases`` under ``run_dir`` (locked by the caller).
    ``train_one(cfg, phase_dir, resumed) -> metrics`` trains one phase."""
    plan = phase_plan(cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(run_dir / "config.yaml") as f:
        f.write(OmegaConf.to_yaml(cfg, resolve=True))
    previous: Path | None = None
    done: list[dict] = []
    metrics: dict = {}
    for k, (name, planned, _) in enumerate(plan):
        phase_dir = run_dir / name
        phase_dir.mkdir(exist_ok=True)
        if (phase_dir / "metrics.json").is_file() and read_failure(phase_dir) is None:
            metrics = OmegaConf.to_container(OmegaConf.load(phase_dir / "metrics.json"))
        else:
            resumed = (phase_dir / "last.pt").is_file()
            try:
                metrics = train_one(phase_config(cfg, k, plan, previous), phase_dir, resumed)
            except TrainingInterrupted as exc:
                where = f"phase {k + 1} of {len(plan)}; resume the whole run with resume={run_dir}"
                raise TrainingInterrupted(f"{exc} ({where})", signal=exc.signal) from None
        frames, wall = metrics.get("frames"), metrics.get("train_wall_s")
        done.append({"phase": name, "planned_frames": planned, "frames": frames, "train_wall_s": wall})
        previous = phase_dir / "last.pt"
    shutil.copyfile(previous, run_dir / ".last.pt.tmp")
    (run_dir / ".last.pt.tmp").replace(run_dir / "last.pt")
    wall = sum(p["train_wall_s"] or 0.0 for p in done)
    frames = sum(p["frames"] or 0 for p in done)
    out = {
        **metrics,
        "frames": frames,
        "train_wall_s": wall,
        "steps_per_s": frames / wall if wall > 0 else None,
        "phases": done,
    }
    write_json(run_dir / "metrics.json", out)
    return finite_json(out)
