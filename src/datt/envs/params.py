"""Typed parameters of the tracking env (``conf/env/default.yaml``): env, observation and reward.

The YAML is the source of every default; the dataclass defaults mirror it for the Python API and
``tests/test_configs.py`` checks that the two agree.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from datt.errors import ConfigError
from datt.sim.quadrotor import QuadrotorParams


@dataclass
class RewardParams:
    """Per-step reward ``-(pos ‖p − p_ref‖ + yaw |wrap(ψ_ref − ψ)| + vel min(‖v‖, vel_cap_mps))``
    (paper §3.1 / authors' code, ψ_ref = 0). A termination (crash) adds ``-crash_penalty``: a drone
    that leaves the box must not be better off than one that keeps flying badly; 300 ≈ the
    discounted cost of staying 3 m off for the rest of an episode at γ = 0.99 (five times it at
    the training default γ = 0.95)."""

    pos: float = 1.0
    yaw: float = 0.5
    vel: float = 0.1
    vel_cap_mps: float = 1.0
    crash_penalty: float = 300.0


# ObsParams keys that shape what a policy reads (a checkpoint carries them to eval and deploy)
# and keys that describe the sensor (the environment's, never carried by a checkpoint)
OBS_LAYOUT_KEYS = ("body_frame", "feedback", "action_history", "timing")
OBS_TIMINGS = ("project", "authors")
OBS_NOISE_KEYS = ("pos_noise_std_m", "vel_noise_std_mps", "att_noise_std_rad")


@dataclass
class ObsParams:
    """How observations are built (ablations live here, never in network code).

    ``body_frame``: rotate p, v, feedback and feedforward terms by R^T (False = the paper's "no
    body frame" ablation as the authors ran it: world-frame p, v and feedback error, and the raw
    future reference positions as the feedforward input). ``feedback``: the authors' "fb_term"
    (False = their "no feedback" ablation: the absolute position leaves ``state``, zeroed to
    keep shapes, and the feedback error R^T (p − p_d(t)) stays in its place). ``pos_noise_std_m``: Gaussian noise on
    the measured position used by the observation (authors' main configs: 0.005);
    ``vel_noise_std_mps``: Gaussian noise on the measured velocity; ``att_noise_std_rad``: the
    measured attitude is the true one turned by a random rotation vector with this std per axis
    (body frame). All noise is fresh each step and enters the observation only (reward and
    tracking error use the true state).
    ``action_history``: append the last k commands sent (each scaled to [-1, 1] by the action
    bounds, oldest first) to ``state``; 0 = the paper's inputs. Not in the paper: with a one-step
    command latency and first-order actuators, the commands in flight are state the policy
    otherwise cannot see.
    ``critic_ref_points``: K > 0 adds ``critic_ref [N, K, 3]``, the same kind of feedforward
    entries as ``ref`` (errors R^T (p − p_d), or the raw positions without the body frame) at
    t + k ``critic_ref_spacing_s`` for k = 1..K. Only the critic reads it (an asymmetric critic:
    the return depends on the reference beyond the policy's window, which the policy's own
    inputs cannot explain); the policy's inputs and a checkpoint's policy are unchanged.
    ``timing``: which state the observation and the reward of a step read. ``project``: the state
    after the step with the reference at the new time. ``authors``: the state *before* the step
    with the reference at the new time t + dt, as the authors' env pairs them (their
    ``QuadSim.step_angvel_raw`` returns the state read before integrating, ``quadsim/sim.py``
    lines 134-147; ``BaseQuadsimEnv.step`` advances ``t`` and builds observation and reward from
    it, ``learning/base_env.py`` lines 239-259): the policy sees a state one step old, which with
    the one step of command latency makes two steps of dead time. The tracking error (metrics)
    is the true state against the reference at the same time under both."""

    body_frame: bool = True
    feedback: bool = True
    pos_noise_std_m: float = 0.0
    vel_noise_std_mps: float = 0.0
    att_noise_std_rad: float = 0.0
    action_history: int = 0
    critic_ref_points: int = 0
    critic_ref_spacing_s: float = 0.1
    timing: str = "project"


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
        for key in OBS_NOISE_KEYS:
            val = getattr(self.obs, key)
            need(val >= 0, f"obs.{key}", f"must be >= 0, got {val}")
        for key in ("action_history", "critic_ref_points"):
            k = getattr(self.obs, key)
            whole = isinstance(k, int) and not isinstance(k, bool) and k >= 0
            need(whole, f"obs.{key}", f"must be an integer >= 0, got {k!r}")
        need(
            self.obs.timing in OBS_TIMINGS,
            "obs.timing",
            f"unknown value {self.obs.timing!r}; allowed: {', '.join(OBS_TIMINGS)}",
        )
        ratio = self.obs.critic_ref_spacing_s / self.dt_s
        need(
            self.obs.critic_ref_spacing_s > 0 and abs(ratio - round(ratio)) < 1e-6,
            "obs.critic_ref_spacing_s",
            f"must be a whole multiple > 0 of env.dt_s={self.dt_s}, got {self.obs.critic_ref_spacing_s}",
        )
        self.quad.validate("env.quad")
        need(self.reward.crash_penalty >= 0, "reward.crash_penalty", f"must be >= 0, got {self.reward.crash_penalty}")
