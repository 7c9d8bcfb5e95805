"""A training schedule in stages, from one command: ``train.stages`` lists the stages of one run,
each a number of frames and the values it changes; stage k starts from stage k-1's weights.

A stage is a whole PPO run in ``<run>/stage<k>_<name>/`` (its own config, learning curve, lr
schedule from ``algo.lr`` down to ``algo.lr x algo.lr_final_frac`` over its frames, a fresh
optimiser) started with ``train.init_from`` = the previous stage's ``last.pt``, exactly what a
chain of ``train.init_from`` commands does; the first stage starts from the run's own
``train.init_from`` (null = fresh weights), so a schedule can fine-tune a checkpoint
(``experiment=deploy``). The curriculum's fixed reference flies only in the first stage (later
stages start with ``curriculum.fixed_ref_frames: 0`` unless they set it). The end-of-run
evaluation runs once, on the last stage; the run's own ``last.pt`` and ``metrics.json`` are the
last stage's, so ``eval.py checkpoint=<run>/last.pt`` and ``tables.py`` see one run.

``resume=<run>`` (or ``true``) carries a run in stages on: finished stages (their ``metrics.json``)
are kept, the interrupted one resumes from its ``last.pt``, the rest run.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from datt.configuration import upgrade_saved_config
from datt.errors import ConfigError, TrainingInterrupted
from datt.runs import atomic_write, finite_json, read_failure, write_json

# Keys a stage may not set: they say which run this is, or the schedule itself.
FORBIDDEN_PREFIXES = ("train.stages", "train.init_from", "train.total_frames", "resume", "seed", "horizon")
STAGE_NAME = re.compile(r"^[A-Za-z0-9_-]+$")


def in_stages(cfg: DictConfig) -> bool:
    return OmegaConf.select(cfg, "train.stages", default=None) is not None


def stage_plan(cfg: DictConfig) -> list[tuple[str, int, dict[str, Any]]]:
    """``train.stages`` checked: ``[(dir name, frames, {dotted key: value})]``. Every key must exist
    in the config (a typo would silently train the wrong schedule), and the stages' frames must add
    up to ``train.total_frames`` (the run's total, which budget, resume and tables read)."""
    node = cfg.train.stages
    stages = OmegaConf.to_container(node, resolve=True) if isinstance(node, ListConfig | DictConfig) else node
    if not isinstance(stages, list):
        raise ConfigError(f"train.stages: must be a list of {{name, frames, set}} or null, got {stages!r}")
    plan, names = [], set()
    for k, stage in enumerate(stages, start=1):
        where = f"train.stages[{k - 1}]"
        if isinstance(stage, dict) and "steps" in stage:
            raise ConfigError(f"{where}.steps: no longer a setting; use frames (the same number: frames)")
        if not isinstance(stage, dict) or set(stage) - {"name", "frames", "set"} or "frames" not in stage:
            raise ConfigError(f"{where}: must be a mapping with keys name, frames and set (only), got {stage!r}")
        name = str(stage.get("name") or f"stage{k}")
        if not STAGE_NAME.match(name) or name in names:
            raise ConfigError(f"{where}.name: {name!r} must be unique and use only letters, digits, _ and -")
        names.add(name)
        frames = stage["frames"]
        if not isinstance(frames, int) or isinstance(frames, bool) or frames < 1:
            raise ConfigError(f"{where}.frames: must be an integer >= 1, got {frames!r}")
        values = stage.get("set") or {}
        if not isinstance(values, dict):
            raise ConfigError(f"{where}.set: must map dotted config keys to values, got {values!r}")
        for key in values:
            if any(key == p or key.startswith(p + ".") for p in FORBIDDEN_PREFIXES):
                raise ConfigError(
                    f"{where}.set: {key} cannot change between stages (the stages set: everything but "
                    f"{', '.join(FORBIDDEN_PREFIXES)})"
                )
            if OmegaConf.select(cfg, key, default="\0missing") == "\0missing":
                raise ConfigError(f"{where}.set: unknown config key {key!r}")
        plan.append((f"stage{k}_{name}", frames, values))
    if not plan:
        raise ConfigError("train.stages: empty list; use null for a run without stages")
    total = sum(frames for _, frames, _ in plan)
    if total != int(cfg.train.total_frames):
        raise ConfigError(
            f"train.stages: the stages add up to {total:,} frames but train.total_frames is "
            f"{int(cfg.train.total_frames):,}; set train.total_frames={total}"
        )
    return plan


def stage_config(cfg: DictConfig, k: int, plan, init_from: Path | None) -> DictConfig:
    """The whole config of stage ``k`` (0-based): ``cfg`` with the stage's values, its frames and the
    previous stage's weights (the first stage: the run's ``train.init_from``); no stages of its own."""
    _, frames, values = plan[k]
    out = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    OmegaConf.update(out, "train.stages", None)
    OmegaConf.update(out, "train.total_frames", frames)
    if k > 0:
        OmegaConf.update(out, "train.init_from", str(init_from))
        OmegaConf.update(out, "curriculum.fixed_ref_frames", 0)
    last = k == len(plan) - 1
    OmegaConf.update(out, "train.eval_at_end", last and bool(cfg.train.eval_at_end))
    for key, value in values.items():
        OmegaConf.update(out, key, value, merge=False)
    return out


def holds_run_in_stages(path: Path) -> bool:
    """Whether ``path`` is the dir of a run in stages (its saved config schedules stages)."""
    saved = path / "config.yaml"
    return saved.is_file() and in_stages(upgrade_saved_config(OmegaConf.load(saved)))


def stages_parent(run_dir: Path) -> Path | None:
    """The run in stages a stage dir belongs to (``<run>/stage<k>_<name>``), else None."""
    parent = run_dir.parent
    return parent if re.match(r"^stage\d+_", run_dir.name) and holds_run_in_stages(parent) else None


def run_stages(cfg: DictConfig, run_dir: Path, train_one) -> dict:
    """Train every stage of ``cfg.train.stages`` under ``run_dir`` (locked by the caller).
    ``train_one(cfg, stage_dir, resumed) -> metrics`` trains one stage."""
    plan = stage_plan(cfg)
    run_dir.mkdir(parents=True, exist_ok=True)
    with atomic_write(run_dir / "config.yaml") as f:
        f.write(OmegaConf.to_yaml(cfg, resolve=True))
    previous: Path | None = None
    done: list[dict] = []
    metrics: dict = {}
    for k, (name, planned, _) in enumerate(plan):
        stage_dir = run_dir / name
        old_dir = run_dir / re.sub(r"^stage", "phase", name)  # a run begun when stages were named phases
        if not stage_dir.exists() and old_dir.is_dir():
            old_dir.rename(stage_dir)
        stage_dir.mkdir(exist_ok=True)
        if (stage_dir / "metrics.json").is_file() and read_failure(stage_dir) is None:
            metrics = OmegaConf.to_container(OmegaConf.load(stage_dir / "metrics.json"))
        else:
            resumed = (stage_dir / "last.pt").is_file()
            try:
                metrics = train_one(stage_config(cfg, k, plan, previous), stage_dir, resumed)
            except TrainingInterrupted as exc:
                where = f"stage {k + 1} of {len(plan)}; resume the whole run with resume={run_dir}"
                raise TrainingInterrupted(f"{exc} ({where})", signal=exc.signal) from None
        frames, wall = metrics.get("frames"), metrics.get("train_wall_s")
        done.append({"stage": name, "planned_frames": planned, "frames": frames, "train_wall_s": wall})
        previous = stage_dir / "last.pt"
    shutil.copyfile(previous, run_dir / ".last.pt.tmp")
    (run_dir / ".last.pt.tmp").replace(run_dir / "last.pt")
    wall = sum(p["train_wall_s"] or 0.0 for p in done)
    frames = sum(p["frames"] or 0 for p in done)
    out = {
        **metrics,
        "frames": frames,
        "train_wall_s": wall,
        "steps_per_s": frames / wall if wall > 0 else None,
        "stages": done,
    }
    write_json(run_dir / "metrics.json", out)
    return finite_json(out)
