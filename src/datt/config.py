"""Structured config schemas, validation and builders shared by every entry point.

Errors in user config surface as :class:`ConfigError`: one line that names the offending key
and, where there is a fixed set, the allowed values.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from omegaconf import DictConfig, OmegaConf
from omegaconf.errors import OmegaConfBaseException

from datt.sim.quadrotor import QuadrotorParams

CONF_DIR = Path(__file__).resolve().parents[2] / "conf"
# Hydra search-path root of the paper-table sweeps: ``+sweep=<name>`` loads sweeps/sweep/<name>.yaml
SWEEPS_DIR = CONF_DIR.parent / "sweeps"


class ConfigError(ValueError):
    """A user-facing configuration error (one line, names the key)."""


class TrainingDiverged(RuntimeError):
    """A NaN/inf appeared in the loss, observations or actions (raised by ``datt.train.ppo``;
    defined here so the entry points can catch it without importing TorchRL's collectors)."""


@dataclass
class RewardParams:
    """Per-step reward ``-(pos ‖p − p_ref‖ + yaw |wrap(ψ_ref − ψ)| + vel min(‖v‖, vel_cap_mps))``
    (paper §3.1 / authors' code, ψ_ref = 0). A termination (crash) adds ``-crash_penalty``: a drone
    that leaves the box must not be better off than one that keeps flying badly; 300 ≈ the
    discounted cost (γ = 0.99) of staying 3 m off for the rest of an episode."""

    pos: float = 1.0
    yaw: float = 0.5
    vel: float = 0.1
    vel_cap_mps: float = 1.0
    crash_penalty: float = 300.0


@dataclass
class ObsParams:
    """How observations are built (ablations live here, never in network code).

    ``body_frame``: rotate p, v, feedback and feedforward terms by R^T (False = paper's "no body
    frame" ablation, world-frame inputs). ``feedback``: include R^T (p − p_d(t)) in ``state``
    (False zeroes those three entries, keeping shapes). ``pos_noise_std_m``: Gaussian noise on
    the measured position used by the observation (authors' main configs: 0.005).
    ``action_history``: append the last k commands sent (each scaled to [-1, 1] by the action
    bounds, oldest first) to ``state``; 0 = the paper's inputs. Not in the paper: with a one-step
    command latency and first-order actuators, the commands in flight are state the policy
    otherwise cannot see."""

    body_frame: bool = True
    feedback: bool = True
    pos_noise_std_m: float = 0.0
    action_history: int = 0


@dataclass
class EnvParams:
    """Tracking env settings (``conf/env/default.yaml``). Units in the names; see
    :class:`datt.envs.TrackingEnv` for their meaning."""

    num_envs: int = 1024
    dt_s: float = 0.02
    episode_steps: int = 500
    ref_spacing_s: float = 0.06
    init_pos_range_m: float = 0.5
    safety_box_m: list[float] = field(default_factory=lambda: [3.0, 3.0, 3.0])
    max_tracking_error_m: Any = None
    thrust_offset_bounds_mps2: list[float] = field(default_factory=lambda: [-9.8, 30.0])
    rate_bounds_radps: list[float] = field(default_factory=lambda: [20.0, 20.0, 2.0])
    dtype: str = "float32"
    device: str = "cpu"
    compile: bool = False
    quad: QuadrotorParams = field(default_factory=QuadrotorParams)
    obs: ObsParams = field(default_factory=ObsParams)
    reward: RewardParams = field(default_factory=RewardParams)

    def validate(self) -> None:
        def need(ok: bool, key: str, msg: str) -> None:
            if not ok:
                raise ConfigError(f"env.{key}: {msg}")

        need(self.num_envs >= 1, "num_envs", f"must be >= 1, got {self.num_envs}")
        need(self.dt_s > 0, "dt_s", f"must be > 0, got {self.dt_s}")
        need(self.episode_steps >= 1, "episode_steps", f"must be >= 1, got {self.episode_steps}")
        need(self.ref_spacing_s > 0, "ref_spacing_s", f"must be > 0, got {self.ref_spacing_s}")
        ratio = self.ref_spacing_s / self.dt_s
        need(
            abs(ratio - round(ratio)) < 1e-6,
            "ref_spacing_s",
            f"must be a whole multiple of env.dt_s={self.dt_s}, got {self.ref_spacing_s}",
        )
        need(self.init_pos_range_m >= 0, "init_pos_range_m", f"must be >= 0, got {self.init_pos_range_m}")
        need(
            len(self.safety_box_m) == 3 and all(b > 0 for b in self.safety_box_m),
            "safety_box_m",
            f"must be three half-extents > 0, got {list(self.safety_box_m)}",
        )
        need(
            self.max_tracking_error_m is None or float(self.max_tracking_error_m) > 0,
            "max_tracking_error_m",
            f"must be null or > 0, got {self.max_tracking_error_m}",
        )
        lo, hi = (list(self.thrust_offset_bounds_mps2) + [None, None])[:2]
        need(
            len(self.thrust_offset_bounds_mps2) == 2 and lo < hi,
            "thrust_offset_bounds_mps2",
            f"must be [low, high] with low < high, got {list(self.thrust_offset_bounds_mps2)}",
        )
        need(
            lo + self.quad.gravity_mps2 >= 0,
            "thrust_offset_bounds_mps2",
            f"low + g must be >= 0 (thrust cannot pull down), got {lo}",
        )
        need(
            len(self.rate_bounds_radps) == 3 and all(r > 0 for r in self.rate_bounds_radps),
            "rate_bounds_radps",
            f"must be three values > 0, got {list(self.rate_bounds_radps)}",
        )
        need(self.dtype in ("float32", "float64"), "dtype", f"unknown value {self.dtype!r}; allowed: float32, float64")
        need(self.obs.pos_noise_std_m >= 0, "obs.pos_noise_std_m", f"must be >= 0, got {self.obs.pos_noise_std_m}")
        k = self.obs.action_history
        need(isinstance(k, int) and not isinstance(k, bool) and k >= 0, "obs.action_history", f"must be an integer >= 0, got {k!r}")
        self.quad.validate("env.quad")
        need(self.reward.crash_penalty >= 0, "reward.crash_penalty", f"must be >= 0, got {self.reward.crash_penalty}")


def one_line(exc: BaseException) -> str:
    """Collapse an exception (and Hydra/OmegaConf wrappers) to its innermost one-line message."""
    while exc.__cause__ is not None:
        exc = exc.__cause__
    msg = str(exc).strip().splitlines()
    return msg[0] if msg else type(exc).__name__


def structured(cls, node, key: str):
    """Merge ``node`` onto the dataclass schema ``cls`` (type-checked), build it and call its
    ``validate()``; type errors become one-line ConfigErrors under ``key``."""
    try:
        merged = OmegaConf.merge(OmegaConf.structured(cls), node or {})
    except OmegaConfBaseException as exc:
        sub = getattr(exc, "full_key", "") or ""
        raise ConfigError(f"{key}.{sub}: {one_line(exc)}" if sub else f"{key}: {one_line(exc)}") from None
    obj = OmegaConf.to_object(merged)
    obj.validate()
    return obj


def env_params_from_cfg(env_cfg: DictConfig | dict | None) -> EnvParams:
    """``cfg.env`` as validated :class:`EnvParams`."""
    return structured(EnvParams, env_cfg, "env")


def check_horizon(horizon: Any) -> int:
    if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
        raise ConfigError(f"horizon: must be an integer >= 1 (number of future reference points), got {horizon!r}")
    return horizon


def instantiate_option(cfg: DictConfig, group: str) -> Any:
    """``hydra.utils.instantiate(cfg[group])`` with errors reduced to one line naming the group."""
    from hydra.utils import instantiate

    node = cfg.get(group)
    if node is None:
        raise ConfigError(f"{group}: missing; choose one of {', '.join(available_options(group))}")
    try:
        return instantiate(node, _convert_="all")
    except Exception as exc:  # Hydra wraps constructor errors in InstantiationException
        msg = one_line(exc)
        raise ConfigError(msg if msg.startswith(f"{group}.") else f"{group}: {msg}") from None


def available_options(group: str) -> list[str]:
    """Names of the YAML options of a config group (``conf/<group>/*.yaml``; the ``sweep`` group
    lives on the sweeps search path)."""
    root = SWEEPS_DIR if group == "sweep" else CONF_DIR
    return sorted(p.stem for p in (root / group).glob("*.yaml"))


def load_option(group: str, name: str) -> DictConfig:
    """The YAML of one option of a config group (``conf/<group>/<name>.yaml``)."""
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        raise ConfigError(f"{group}: unknown option {name!r}; allowed: {', '.join(available_options(group))}")
    node = OmegaConf.load(path)
    assert isinstance(node, DictConfig)
    return node


def with_options(cfg: DictConfig, **choices) -> DictConfig:
    """Copy of ``cfg`` with whole option nodes swapped: a name loads ``conf/<group>/<name>.yaml``
    (``with_options(cfg, disturbance="none")``), a mapping is used as the node itself."""
    out = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    OmegaConf.set_struct(out, False)
    for group, choice in choices.items():
        out[group] = load_option(group, choice) if isinstance(choice, str) else choice
    return out


def make_env(cfg: DictConfig, num_envs: int | None = None, seed: int | None = None, traj=None, **overrides):
    """Build :class:`~datt.envs.TrackingEnv` from a composed config (``env``, ``traj``,
    ``disturbance``, ``adaptation``, ``horizon``, ``seed``). ``traj`` replaces ``cfg.traj`` with
    a ready family (evaluation banks)."""
    from datt.envs.tracking import TrackingEnv

    params = env_params_from_cfg(cfg.get("env"))
    horizon = check_horizon(cfg.get("horizon", 10))
    traj = traj if traj is not None else instantiate_option(cfg, "traj")
    disturbance = instantiate_option(cfg, "disturbance") if cfg.get("disturbance") is not None else None
    adaptation = instantiate_option(cfg, "adaptation") if cfg.get("adaptation") is not None else None
    env = TrackingEnv(
        num_envs=num_envs or params.num_envs,
        traj=traj,
        disturbance=disturbance,
        adaptation=adaptation,
        horizon=horizon,
        params=params,
        seed=cfg.get("seed", 0) if seed is None else seed,
        **overrides,
    )
    return env.compile_kernels() if params.compile else env


_MISSING_OPTION = re.compile(r"Could not find '([^'/]+)/([^']+)'")
_BAD_OVERRIDE = re.compile(r"Could not override '([^']+)'")


def hydra_error_to_config_error(exc: BaseException) -> ConfigError:
    """Turn Hydra's multi-line composition errors into one line naming key and allowed values."""
    text = str(exc)
    m = _MISSING_OPTION.search(text)
    if m:
        group, name = m.groups()
        allowed = ", ".join(available_options(group))
        return ConfigError(f"{group}: unknown option {name!r}; allowed: {allowed}")
    m = _BAD_OVERRIDE.search(text)
    if m:
        key = m.group(1)
        return ConfigError(f"{key}: no such key ({one_line(exc)}); to add a new key use +{key}=...")
    return ConfigError(one_line(exc))


def compose(config_name: str = "sim", overrides: list[str] | None = None) -> DictConfig:
    """Compose ``conf/<config_name>.yaml`` with Hydra overrides, outside ``@hydra.main``."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.errors import HydraException

    GlobalHydra.instance().clear()
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            return hydra_compose(config_name=config_name, overrides=list(overrides or []))
    except (HydraException, OmegaConfBaseException) as exc:
        raise hydra_error_to_config_error(exc) from None
