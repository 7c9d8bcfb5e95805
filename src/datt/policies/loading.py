"""A trained actor from a checkpoint, rebuilt with the observation layout it was trained with."""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

from datt.checkpoint import load_checkpoint
from datt.configuration import check_targets, structured, upgrade_saved_config
from datt.envs.factory import env_params_from_cfg
from datt.envs.observations import state_width
from datt.envs.tracking import action_bounds
from datt.errors import ConfigError
from datt.paths import resolve_path
from datt.policies.networks import PolicyParams, make_actor


def load_actor(path: str | Path, key: str = "checkpoint"):
    """``(actor, train_cfg, data)`` from a policy checkpoint (file or run dir; ``key`` names the
    config key in errors). The actor is in eval mode."""
    data = load_checkpoint(resolve_path(path), key=key)
    if "actor" not in data:
        what = "an RMA adapter, not a policy" if "rma" in data else "not a policy"
        raise ConfigError(f"{key}: {str(path)!r} is {what} checkpoint; pass a policy checkpoint (.pt or run dir)")
    train_cfg = upgrade_saved_config(OmegaConf.create(data["config_yaml"]))
    check_targets(train_cfg, key, source=str(path))  # the file's config is data, not code to build
    params = structured(PolicyParams, train_cfg.policy, "policy")
    env_params = env_params_from_cfg(train_cfg.env)
    low, high = action_bounds(env_params)
    actor = make_actor(int(data["horizon"]), low, high, params, state_width(env_params.obs))
    actor.load_state_dict(data["actor"])
    actor.eval()
    return actor, train_cfg, data
