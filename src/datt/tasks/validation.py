"""The composed config of every entry point checked against the schemas before any work.

Each config node has one schema (a dataclass whose fields declare their ranges, or a
``_target_`` class whose ``ARG_RANGES`` do); :func:`validate_config` builds them all, so a bad
value anywhere is one line naming the key, the value and the allowed range, and exit 2, before
a run dir, a model or a radio link exists. The entry points call it on every composed variant
of the command line (``datt.cli``), and each task again on the config it runs (a resumed run's
saved config included). Files a command reads (checkpoints, run dirs) must exist.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from omegaconf import DictConfig, ListConfig, OmegaConf

from datt.configuration import SEED, THREADS, Range, check_horizon, check_option, check_target_args, structured
from datt.control.factory import refuse_unused_adaptation_overrides
from datt.envs.factory import env_params_from_cfg
from datt.errors import ConfigError
from datt.eval.schema import EndOfRunEvalParams, EvalParams
from datt.paths import resolve_path
from datt.policies.networks import PolicyParams
from datt.train.loggers import LoggerParams
from datt.train.ppo import AlgoParams
from datt.train.schema import CurriculumParams, RmaParams, TrainParams, run_params

# config name -> node -> its schema (a dataclass), beyond the nodes every config with them has
NODE_SCHEMAS: dict[str, dict[str, type]] = {
    "train": {
        "train": TrainParams,
        "curriculum": CurriculumParams,
        "rma": RmaParams,
        "algo": AlgoParams,
        "policy": PolicyParams,
        "eval": EndOfRunEvalParams,
        "logger": LoggerParams,
    },
    "eval": {"eval": EvalParams},
}
# nodes that hold a _target_ (what instantiate builds): their arguments' declared ranges
TARGET_NODES = ("traj", "disturbance", "adaptation", "controller", "curriculum", "randomization")
# keys naming a file or run dir the command reads: it must exist (null = none)
FILE_KEYS = ("checkpoint", "train.init_from", "adaptation.checkpoint")
OPTIONAL_THREADS = Range(1, THREADS.high, integer=True, optional=True)


def _check_file(cfg: DictConfig, key: str) -> None:
    value = OmegaConf.select(cfg, key, default=None)
    if value in (None, ""):
        return
    if not isinstance(value, str):
        raise ConfigError(f"{key}: must be a path, got {value!r}")
    path = resolve_path(value)
    if not path.exists():
        raise ConfigError(f"{key}: file {str(path)!r} not found")


def _check_resume(resume: Any) -> None:
    """``resume``: false/null (a new run), true (the newest run) or a run dir that exists."""
    if resume is None or isinstance(resume, bool):
        return
    if not isinstance(resume, str) or resume == "":
        raise ConfigError(f"resume: must be true, false or a run dir, got {resume!r}")
    if not resolve_path(resume).exists():
        raise ConfigError(f"resume: {str(resolve_path(resume))!r} does not exist")


def _run_level(config_name: str, cfg: DictConfig) -> None:
    if config_name == "train":
        run_params(cfg)  # horizon, seed, stage, budget
        _check_file(cfg, "base_checkpoint")
        _check_resume(cfg.get("resume"))

    if "horizon" in cfg:
        check_horizon(cfg.horizon)
    if "seed" in cfg:
        SEED.check(cfg.seed, "seed")
    if "threads" in cfg:
        OPTIONAL_THREADS.check(cfg.threads, "threads")
    if config_name == "export":
        from datt.tasks.export import check_export_options

        check_export_options(cfg)


def _train_node(cfg: DictConfig) -> None:
    from datt.tasks.phases import phase_plan

    structured(TrainParams, cfg.train, "train")
    if OmegaConf.select(cfg, "train.phases", default=None) is not None:
        phase_plan(cfg)  # names, steps and the keys each phase sets


def _controller_node(targets: Callable[[DictConfig], None]) -> Callable[[DictConfig], None]:
    """The controller option: its ``_target_`` arguments, and the estimator it fixes (an
    adaptation option) if it names one."""

    def check(cfg: DictConfig) -> None:
        targets(cfg)
        forced = OmegaConf.select(cfg, "controller.adaptation", default=None)
        if forced is not None:
            check_option("adaptation", forced, "controller.adaptation")

    return check


def _tables_runs(runs: Any) -> None:
    items = runs if isinstance(runs, (list, tuple, ListConfig)) else [runs]
    for item in items:
        if not isinstance(item, str) or not item:
            raise ConfigError(f"runs: must be a sweep or job dir (or a list of them), got {runs!r}")
        if not resolve_path(item).exists():
            raise ConfigError(f"runs: {str(resolve_path(item))!r} does not exist")


def checks(config_name: str) -> dict[str, Callable[[DictConfig], None]]:
    """Top-level node -> its check, for one entry point (``""``: the run-level keys)."""
    out: dict[str, Callable[[DictConfig], None]] = {"": lambda cfg: _run_level(config_name, cfg)}
    if config_name == "tables":
        from datt.tasks.tables import TablesParams

        def tables(cfg: DictConfig) -> None:
            structured(TablesParams, cfg, "")
            if cfg.get("runs") is not None:
                _tables_runs(cfg.runs)

        return {"": tables}
    for key, schema in NODE_SCHEMAS.get(config_name, {}).items():
        out[key] = lambda cfg, key=key, schema=schema: structured(schema, cfg[key], key)
    out["env"] = lambda cfg: env_params_from_cfg(cfg.env)
    if config_name == "train":
        out["train"] = _train_node
    for key in TARGET_NODES:
        previous = out.get(key)

        def target_check(cfg: DictConfig, key: str = key, previous=previous) -> None:
            if previous is not None:
                previous(cfg)
            node: Any = cfg.get(key)
            if isinstance(node, DictConfig):
                check_target_args(node, key)

        out[key] = target_check
    out["controller"] = _controller_node(out["controller"])
    if config_name == "deploy":
        from datt.deploy.schema import deploy_params

        out["deploy"] = lambda cfg: deploy_params(cfg.deploy)
    return out


def validate_config(config_name: str, cfg: DictConfig, only: str | None = None) -> None:
    """Check a composed config of entry point ``config_name`` (train, eval, export, deploy,
    tables, sim) against every schema that applies; raises one ConfigError. ``only``: check
    just the top-level node of that dotted key (the config fuzzer's shortcut)."""
    forced = OmegaConf.select(cfg, "controller.adaptation", default=None)
    if forced is not None:  # before the adaptation node's own checks: the override is the mistake
        refuse_unused_adaptation_overrides(str(OmegaConf.select(cfg, "controller.name", default="")), str(forced))
    node_checks = checks(config_name)
    top = only.split(".")[0] if only is not None else None
    for node, check in node_checks.items():
        if top is not None and node != (top if top in node_checks else ""):
            continue
        if node == "" or node in cfg:
            check(cfg)
    for key in FILE_KEYS:
        if config_name != "tables" and (top is None or key.split(".")[0] == top or (top not in node_checks)):
            _check_file(cfg, key)


def validate_composed(config_name: str, cfg: DictConfig, only: str | None = None) -> None:
    """:func:`validate_config` on a config with interpolations resolved where they can be
    (``${now:}`` and Hydra's own resolvers are left to the job)."""
    try:
        resolved = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True, throw_on_missing=False))
    except Exception:  # an interpolation only a running job resolves: check the raw values
        resolved = cfg
    validate_config(config_name, resolved, only)
