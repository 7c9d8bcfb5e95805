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

from omegaconf import DictConfig, OmegaConf

from datt.configuration import SEED, THREADS, Range, check_horizon, check_option, check_target_args, structured
from datt.control.factory import refuse_unused_adaptation_overrides
from datt.envs.factory import env_params_from_cfg
from datt.errors import ConfigError
from datt.eval.schema import AdapterEvalParams, EndOfRunEvalParams, EvalParams
from datt.export import check_export_options
from datt.paths import resolve_path
from datt.policies.networks import PolicyParams
from datt.tasks.resume import resume_dir
from datt.train.loggers import LoggerParams
from datt.train.ppo import AlgoParams
from datt.train.schema import (
    CurriculumParams,
    RmaParams,
    TrainParams,
    check_metric_path,
    fit_rma_params,
    run_params,
)

# config name -> node -> its schema (a dataclass), beyond the nodes every config with them has
NODE_SCHEMAS: dict[str, dict[str, type]] = {
    "train": {
        "curriculum": CurriculumParams,
        "algo": AlgoParams,
        "policy": PolicyParams,
        "eval": EndOfRunEvalParams,
        "logger": LoggerParams,
    },
    "eval": {"eval": EvalParams, "logger": LoggerParams},
    "fit_rma": {"rma": RmaParams, "eval": AdapterEvalParams},
}
# nodes that hold a _target_ (what instantiate builds): their arguments' declared ranges
TARGET_NODES = ("traj", "disturbance", "adaptation", "controller", "curriculum", "randomization")
OPTIONAL_THREADS = Range(1, THREADS.high, integer=True, optional=True)
Check = Callable[[DictConfig], None]


def _check_file(cfg: DictConfig, key: str) -> None:
    """A file or run dir the command reads (``key``; null = none) must exist."""
    value = OmegaConf.select(cfg, key, default=None)
    if value in (None, ""):
        return
    if not isinstance(value, str):
        raise ConfigError(f"{key}: must be a path, got {value!r}")
    path = resolve_path(value)
    if not path.exists():
        raise ConfigError(f"{key}: file {str(path)!r} not found")


def _run_level(config_name: str, cfg: DictConfig) -> None:
    if config_name == "train":
        run_params(cfg)  # horizon, seed, budget, resume, threads
        resume = cfg.get("resume")
        if isinstance(resume, str):  # a run dir: it must hold a run to carry on
            resume_dir(resume)
        elif resume is not None and not isinstance(resume, bool):
            raise ConfigError(f"resume: must be true, false or a run dir, got {resume!r}")
    elif config_name == "fit_rma":
        fit_rma_params(cfg)  # seed, budget, base_checkpoint, threads
        _check_file(cfg, "base_checkpoint")
    else:
        if "horizon" in cfg:
            check_horizon(cfg.horizon)
        if "seed" in cfg:
            SEED.check(cfg.seed, "seed")
    if "threads" in cfg:
        OPTIONAL_THREADS.check(cfg.threads, "threads")
    if "optimized_metric" in cfg:
        check_metric_path(cfg.optimized_metric)
    _check_file(cfg, "checkpoint")
    if config_name == "export":
        check_export_options(cfg)


def _stages(cfg: DictConfig) -> None:
    from datt.tasks.stages import in_stages, stage_plan

    if in_stages(cfg):
        stage_plan(cfg)  # names, frames and the keys each stage sets


def _fixed_estimator(cfg: DictConfig) -> None:
    """The estimator a controller option fixes is an adaptation option."""
    forced = OmegaConf.select(cfg, "controller.adaptation", default=None)
    if forced is not None:
        check_option("adaptation", forced, "controller.adaptation")


def checks(config_name: str) -> dict[str, list[Check]]:
    """Top-level node -> its checks, for one entry point (``""``: the run-level keys)."""
    if config_name == "tables":
        from datt.tasks.tables import TablesParams, run_roots

        def tables(cfg: DictConfig) -> None:
            structured(TablesParams, cfg, "")
            if cfg.get("runs") is not None:
                run_roots(cfg.runs)

        return {"": [tables]}
    out: dict[str, list[Check]] = {"": [lambda cfg: _run_level(config_name, cfg)]}
    for key, schema in NODE_SCHEMAS.get(config_name, {}).items():
        out[key] = [lambda cfg, key=key, schema=schema: structured(schema, cfg[key], key)]
    if config_name == "train":
        out["train"] = [lambda cfg: structured(TrainParams, cfg.train, "train"), _stages]
        out["train"].append(lambda cfg: _check_file(cfg, "train.init_from"))
    out["env"] = [lambda cfg: env_params_from_cfg(cfg.env)]
    for key in TARGET_NODES:
        out.setdefault(key, []).append(
            lambda cfg, key=key: check_target_args(cfg[key], key) if isinstance(cfg.get(key), DictConfig) else None
        )
    out["adaptation"].append(lambda cfg: _check_file(cfg, "adaptation.checkpoint"))
    out["controller"].append(_fixed_estimator)
    if config_name == "deploy":
        from datt.deploy.schema import deploy_params

        out["deploy"] = [lambda cfg: deploy_params(cfg.deploy)]
    return out


def validate_config(config_name: str, cfg: DictConfig, only: str | None = None) -> None:
    """Check a composed config of entry point ``config_name`` (train, eval, export, deploy,
    tables, sim) against every schema that applies; raises one ConfigError. ``only``: check
    just the top-level node of that dotted key (the config fuzzer's shortcut; a key outside
    every node is a run-level key)."""
    forced = OmegaConf.select(cfg, "controller.adaptation", default=None)
    if forced is not None:  # before the adaptation node's own checks: the override is the mistake
        refuse_unused_adaptation_overrides(str(OmegaConf.select(cfg, "controller.name", default="")), str(forced))
    node_checks = checks(config_name)
    top = None if only is None else (only.split(".")[0] if only.split(".")[0] in node_checks else "")
    for node, node_check in node_checks.items():
        if (top is None or node == top) and (node == "" or node in cfg):
            for check in node_check:
                check(cfg)


def validate_composed(config_name: str, cfg: DictConfig, only: str | None = None) -> None:
    """:func:`validate_config` on a config with interpolations resolved where they can be
    (``${now:}`` and Hydra's own resolvers are left to the job)."""
    try:
        resolved = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True, throw_on_missing=False))
    except Exception:  # an interpolation only a running job resolves: check the raw values
        resolved = cfg
    validate_config(config_name, resolved, only)
