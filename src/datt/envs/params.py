"""Typed parameters of the tracking env (``conf/env/default.yaml``): env, observation and reward.

The YAML is the source of every default; the dataclass defaults mirror it for the Python API and
``tests/test_configs.py`` checks that the two agree.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from datt.configuration import DISTANCE_M, NOISE, SPEED_MPS, WEIGHT, Range, check_ranges, ranged
from datt.errors import ConfigError
from datt.sim.quadrotor import QuadrotorParams


@dataclass
class RewardParams:
    """Per-step reward ``-(pos ‖p − p_ref‖ + yaw |wrap(ψ_ref − ψ)| + vel min(‖v‖, vel_cap_mps))``
    (paper §3.1 / authors' code, ψ_ref = 0). A termination (crash) adds ``-crash_penalty``: a drone
    that leaves the box must not be better off than one that keeps flying badly; 300 ≈ the
    discounted cost of staying 3 m off for the rest of an episode at γ = 0.99 (five times it at
    the training default γ = 0.95).

    ``rate_change`` (not in the paper; 0 = the paper's reward): adds ``rate_change ‖ω_cmd(t) −
    ω_cmd(t − 1)‖`` per step, the body-rate command's change from the previous step's (rad/s;
    after the action bounds; the first step of an episode against hover's zero rates). A
    smoothness cost for a policy that flies a longer real loop than it trained on (docs/deploy.md)."""

    pos: float = ranged(1.0, WEIGHT)
    yaw: float = ranged(0.5, WEIGHT)
    vel: float = ranged(0.1, WEIGHT)
    vel_cap_mps: float = ranged(1.0, SPEED_MPS)
    crash_penalty: float = ranged(300.0, Range(0.0, 1e5))
    rate_change: float = ranged(0.0, WEIGHT)  # per rad/s of body-rate command change per step


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
    is the true state against the reference at the same time under both.
    ``predict_latency``: the measured state the policy sees is rolled forward over the commands
    in flight beyond one step (a drone with d steps of latency: the d − 1 commands sent before the
    last one, through the controller's nominal model, :mod:`datt.envs.prediction`) and the
    reference window is read that many steps ahead, so that every drone's policy answers a state
    whose next command in flight is the last one sent, as at the nominal one step. Training with it
    teaches a policy the state predictor it flies behind off-board (``deploy.predictor``).
    ``predict_latency_error_steps`` = e: each drone is predicted over its true delay plus a uniform
    integer in −e..e (drawn per episode, within 1..``quad.latency_steps_max``), as a deployed
    predictor whose latency is measured rather than known (0: the true delay)."""

    body_frame: bool = True
    feedback: bool = True
    pos_noise_std_m: float = ranged(0.0, NOISE)
    vel_noise_std_mps: float = ranged(0.0, NOISE)
    att_noise_std_rad: float = ranged(0.0, NOISE)
    action_history: int = ranged(0, Range(0, 100, integer=True))
    critic_ref_points: int = ranged(0, Range(0, 1000, integer=True))
    critic_ref_spacing_s: float = ranged(0.1, Range(0.0, 10.0, low_open=True))  # and a whole multiple of env.dt_s
    timing: str = ranged("project", Range(choices=OBS_TIMINGS))
    predict_latency: bool = False
    predict_latency_error_steps: int = ranged(0, Range(0, 10, integer=True))


def check_device(device: str) -> None:
    """``env.device``: a torch device this machine has (cpu, cuda, cuda:<index>)."""
    import torch

    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise ConfigError(f"env.device: unknown value {device!r}; allowed: cpu, cuda, cuda:<index>") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"env.device: {device!r} but this machine has no CUDA device; use env.device=cpu")
    if dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"env.device: unknown value {device!r}; allowed: cpu, cuda, cuda:<index>")


@dataclass
class EnvParams:
    """Tracking env settings (``conf/env/default.yaml``). Units in the names; see
    :class:`datt.envs.TrackingEnv` for their meaning."""

    dt_s: float = ranged(0.02, Range(0.0, 1.0, low_open=True))
    episode_steps: int = ranged(500, Range(1, 10**7, integer=True))
    ref_spacing_s: float = ranged(0.06, Range(0.0, 10.0, low_open=True))  # and a whole multiple of dt_s
    init_pos_range_m: float = ranged(0.5, DISTANCE_M)
    safety_box_m: list[float] = ranged([3.0, 3.0, 3.0], Range(0.0, 1000.0, low_open=True, length=3))
    max_tracking_error_m: Any = ranged(None, Range(0.0, 100.0, low_open=True, optional=True))
    thrust_offset_bounds_mps2: list[float] = ranged([-9.8, 30.0], Range(-200.0, 200.0, length=2))  # [low, high]
    rate_bounds_radps: list[float] = ranged([20.0, 20.0, 2.0], Range(0.0, 100.0, low_open=True, length=3))
    dtype: str = ranged("float32", Range(choices=("float32", "float64")))
    device: str = "cpu"
    compile: bool = False
    quad: QuadrotorParams = field(default_factory=QuadrotorParams)
    obs: ObsParams = field(default_factory=ObsParams)
    reward: RewardParams = field(default_factory=RewardParams)

    def validate(self) -> None:
        """Rules across fields (each field's own range is declared with it, :func:`ranged`)."""

        def need(ok: bool, key: str, msg: str) -> None:
            if not ok:
                raise ConfigError(f"env.{key}: {msg}")

        check_ranges(self, "env")
        for key, spacing in (
            ("ref_spacing_s", self.ref_spacing_s),
            ("obs.critic_ref_spacing_s", self.obs.critic_ref_spacing_s),
        ):
            ratio = spacing / self.dt_s
            need(
                abs(ratio - round(ratio)) < 1e-6 and round(ratio) >= 1,
                key,
                f"must be a whole multiple of env.dt_s={self.dt_s}, got {spacing}",
            )
        lo, hi = self.thrust_offset_bounds_mps2
        need(lo < hi, "thrust_offset_bounds_mps2", f"must be [low, high] with low < high, got {[lo, hi]}")
        need(
            lo + self.quad.gravity_mps2 >= 0,
            "thrust_offset_bounds_mps2",
            f"low + g must be >= 0 (thrust cannot pull down), got {lo}",
        )
        self.quad.validate("env.quad")
        need(
            not (self.obs.predict_latency and self.obs.timing == "authors"),
            "obs.predict_latency",
            "true needs env.obs.timing=project (the prediction starts from the state after the step)",
        )
        check_device(self.device)
