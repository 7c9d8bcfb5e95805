"""Build a :class:`~datt.envs.TrackingEnv` from a composed config."""

from __future__ import annotations

from omegaconf import DictConfig

from datt.configuration import check_horizon, instantiate_option, structured
from datt.envs.params import EnvParams
from datt.envs.tracking import TrackingEnv


def env_params_from_cfg(env_cfg: DictConfig | dict | None) -> EnvParams:
    """``cfg.env`` as validated :class:`EnvParams`."""
    return structured(EnvParams, env_cfg, "env")


def make_env(cfg: DictConfig, num_envs: int, seed: int | None = None, traj=None, **overrides) -> TrackingEnv:
    """The env of ``num_envs`` drones of a composed config (``env``, ``traj``, ``disturbance``,
    ``adaptation``, ``horizon``, ``seed``). ``traj`` replaces ``cfg.traj`` with a ready family (evaluation banks);
    ``disturbance: null`` / ``adaptation: null`` mean none / privileged."""
    params = env_params_from_cfg(cfg.env)
    horizon = check_horizon(cfg.horizon)
    traj = traj if traj is not None else instantiate_option(cfg, "traj")
    disturbance = instantiate_option(cfg, "disturbance") if cfg.get("disturbance") is not None else None
    adaptation = instantiate_option(cfg, "adaptation") if cfg.get("adaptation") is not None else None
    env = TrackingEnv(
        num_envs=num_envs,
        traj=traj,
        disturbance=disturbance,
        adaptation=adaptation,
        horizon=horizon,
        params=params,
        seed=int(cfg.seed) if seed is None else seed,
        **overrides,
    )
    return env.compile_kernels() if params.compile else env
