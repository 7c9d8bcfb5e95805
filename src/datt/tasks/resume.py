"""Resuming a training run: the run's own saved config, and which overrides may change it.

A resumed run trains on with ``<run>/config.yaml``. An override on the resume command may only
change how the run is carried on (``RESUMABLE``: extend ``train.total_frames``, logging,
checkpoint cadence, threads, end-of-run evaluation); anything that changes what is trained
(env, policy, algo, references, seed ...) is refused in one line.
"""

from __future__ import annotations

from pathlib import Path

import yaml
from omegaconf import DictConfig, OmegaConf

from datt.checkpoint import load_checkpoint
from datt.configuration import check_targets, command_overrides, flat_leaves, upgrade_saved_config
from datt.errors import ConfigError
from datt.paths import original_cwd, resolve_path
from datt.runs import OWN_RUN, is_locked
from datt.tasks.stages import holds_run_in_stages, stages_parent

# Dotted keys (or prefixes ending in ".") an override may change on resume.
RESUMABLE = (
    "resume",
    "train.total_frames",
    "train.checkpoint_every",
    "train.progress",
    "train.progress_every_s",
    "threads",
    "train.eval_at_end",
    "logger.",
    "eval.",
)
RESUMABLE_GROUPS = ("logger", "bank@eval.bank")


def resume_dir(resume) -> Path | None:
    """The run dir ``resume=`` names: ``true`` = the newest run with a ``last.pt`` under outputs/
    that no other process holds. A stage of a run in stages (:mod:`datt.tasks.stages`) stands for its
    whole run."""
    if resume in (False, None, "false", "False", OWN_RUN):  # own: the job's own dir, if it holds a run
        return None
    if resume in (True, "true", "True"):
        candidates = sorted((original_cwd() / "outputs").glob("**/last.pt"), key=lambda p: p.stat().st_mtime)
        runs = [stages_parent(c.parent) or c.parent for c in candidates]
        free = [r for r in runs if not is_locked(r)]
        if not free:
            held = " (the newest is in use by another process)" if candidates else ""
            raise ConfigError(f"resume: no run with a last.pt under outputs/{held}; pass resume=<run dir>")
        return free[-1]
    path = resolve_path(resume)
    path = stages_parent(path) or path
    if not holds_a_run(path):
        raise ConfigError(f"resume: {str(path)!r} has no last.pt")
    return path


def holds_a_run(path: Path) -> bool:
    """Whether ``path`` holds a run to carry on: a ``last.pt``, or the config of a run in stages."""
    return (path / "last.pt").is_file() or holds_run_in_stages(path)


# Config keys added after runs may have been written, with the value that keeps what the code did
# before the key existed: a resume of such a run fills them in (and its config.yaml then records them).
KEYS_ADDED_SINCE: dict[str, object] = {
    "eval.protocol": "project",
    "curriculum.fixed_ref": "steps",
    "env.obs.timing": "project",
    "env.obs.predict_latency": False,
    "env.obs.predict_latency_error_steps": 0,
    "env.quad.command_loss_max": 0.0,
}


def _resumable(key: str) -> bool:
    return any(key == k or (k.endswith(".") and key.startswith(k)) for k in RESUMABLE)


def _saved_choices(run_dir: Path) -> dict[str, str] | None:
    path = run_dir / ".hydra" / "hydra.yaml"
    if not path.is_file():
        return None
    data = yaml.safe_load(path.read_text()) or {}
    return {str(k): str(v) for k, v in ((data.get("hydra") or {}).get("runtime") or {}).get("choices", {}).items()}


def resume_config(cfg: DictConfig, run_dir: Path, groups: set[str]) -> DictConfig:
    """The config a resume of ``run_dir`` trains with: the run's saved config plus the allowed
    overrides of this command. ``cfg``: this command's composed config; ``groups``: the config
    group names (an override of one is a group choice, compared with the run's own choice)."""
    path = run_dir / "config.yaml"
    if path.is_file():
        saved = OmegaConf.load(path)
    else:  # a run trained through the library API: the checkpoint holds the config it trained with
        path = run_dir / "last.pt"
        saved = OmegaConf.create(load_checkpoint(path, key="resume")["config_yaml"])
    upgrade_saved_config(saved)
    check_targets(saved, "resume", source=str(path))  # a file's config only selects registered options
    for key, value in KEYS_ADDED_SINCE.items():
        if OmegaConf.select(saved, key, default="absent") == "absent":
            OmegaConf.update(saved, key, value, force_add=True)
    now = OmegaConf.to_container(cfg, resolve=True)
    before = OmegaConf.to_container(saved, resolve=True)
    now_leaves, before_leaves = flat_leaves(now), flat_leaves(before)
    overrides = command_overrides()
    changed: list[str] = []
    if overrides is None:  # called as a library: every key that differs was asked for
        changed = [k for k in sorted(set(now_leaves) | set(before_leaves)) if now_leaves.get(k) != before_leaves.get(k)]
    else:
        choices = _saved_choices(run_dir)
        for text in overrides:
            key, _, value = text.lstrip("+~").partition("=")
            if key in groups or "/" in key or "@" in key:
                if key in RESUMABLE_GROUPS:
                    changed += [k for k in now_leaves if k.startswith(key.split("@")[-1] + ".")]
                    continue
                was = (choices or {}).get(key)
                if was != value:
                    raise ConfigError(
                        f"resume: {key}={value} changes what the run trains (it used {key}={was}); "
                        "start a new run instead"
                    )
                continue
            changed += [k for k in now_leaves if k == key or k.startswith(key + ".")]
    merged = OmegaConf.create(before)
    for key in changed:
        if now_leaves.get(key) == before_leaves.get(key):
            continue
        if not _resumable(key):
            raise ConfigError(
                f"resume: {key}={now_leaves.get(key)} changes what the run trains (it used "
                f"{before_leaves.get(key)}); on resume only {', '.join(k.rstrip('.') for k in RESUMABLE[1:])} "
                "may change; start a new run instead"
            )
        OmegaConf.update(merged, key, now_leaves.get(key), force_add=True)
    OmegaConf.update(merged, "resume", str(run_dir), force_add=True)
    return merged


def finished_frames(run_dir: Path, total_frames: int) -> int | None:
    """The frames of ``run_dir``'s last checkpoint if they already reach ``total_frames`` (a staged
    run: the frames of all its stages once its last stage is done)."""
    if holds_run_in_stages(run_dir):
        metrics = run_dir / "metrics.json"
        if not metrics.is_file() or not (run_dir / "last.pt").is_file():
            return None
        frames = int(OmegaConf.load(metrics).get("frames") or 0)
        return frames if frames >= total_frames else None
    frames = int(load_checkpoint(run_dir / "last.pt", key="resume")["frames"])
    return frames if frames >= total_frames else None
