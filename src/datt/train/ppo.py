"""PPO training of the DATT policy with TorchRL parts.

One process, one batched :class:`~datt.envs.TrackingEnv` of ``algo.num_envs`` drones, a TorchRL
``Collector`` gathering ``num_envs x rollout_steps`` frames per iteration, ``GAE`` for advantages
and ``ClipPPOLoss`` optimised with Adam over shuffled minibatches. The paper used SB3's PPO
defaults (10 envs x 2048 steps, minibatch 64, 10 epochs, lr 3e-4); on a 2-core CPU those tiny
minibatches cost hours, so ``conf/algo/ppo.yaml`` uses thousands of envs, short rollouts, a few
epochs over minibatches of a few thousand and a larger learning rate (documented there);
``algo=sb3`` restores the authors' values.

Curriculum (paper §4.1): the first ``curriculum.fixed_ref_frames`` frames fly one fixed
reference (``curriculum.fixed``), then the configured family (``curriculum.fixed_ref=whole_run``:
the fixed reference for the whole run, as the authors' code ran it). Checkpoints (``last.pt`` every
``train.checkpoint_every`` iterations and at the end, ``best.pt`` on the best training tracking
error) hold everything to resume: ``resume=true`` continues the run dir to the same total.
"""

from __future__ import annotations

import logging
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from datt.checkpoint import load_checkpoint, save_checkpoint
from datt.configuration import (
    BATCH,
    FRACTION,
    LEARNING_RATE,
    POSITIVE_WEIGHT,
    UNIT_INTERVAL,
    WEIGHT,
    Range,
    check_ranges,
    check_targets,
    instantiate_option,
    ranged,
    structured,
    upgrade_saved_config,
)
from datt.envs.factory import env_params_from_cfg, make_env
from datt.errors import ConfigError, TrainingDiverged, TrainingInterrupted
from datt.paths import resolve_path
from datt.policies.networks import PolicyParams, make_actor, make_critic, widen_command_history
from datt.progress import ProgressReport
from datt.runs import StopRequest
from datt.train.loggers import Logger
from datt.train.schema import CurriculumParams, TrainParams, budget_factor

log = logging.getLogger(__name__)

LR_SCHEDULES = ("constant", "linear", "exponential", "adaptive_kl")
KL_STEP = 1.5  # adaptive_kl: factor of one lr change (rsl_rl's)


def adapt_lr(lr: float, kl: float, algo: AlgoParams) -> float:
    """The next step's lr under ``lr_schedule=adaptive_kl`` from the current lr and the
    minibatch's KL estimate (``kl_approx`` of the PPO loss, nats)."""
    if kl > 2.0 * algo.desired_kl:
        return max(lr / KL_STEP, algo.lr_min)
    if 0.0 < kl < 0.5 * algo.desired_kl:
        return min(lr * KL_STEP, algo.lr_cap)
    return lr


@dataclass
class AlgoParams:
    """``conf/algo/ppo.yaml``."""

    num_envs: int = ranged(1024, BATCH)
    rollout_steps: int = ranged(32, Range(1, 100_000, integer=True))
    epochs: int = ranged(4, Range(1, 1000, integer=True))
    minibatch_size: int = ranged(2048, BATCH)
    lr: float = ranged(1e-3, LEARNING_RATE)
    # constant | linear | exponential: to lr_final_frac * lr along a straight line, or
    # geometrically (the same factor every frame, so more of the run at low lr); adaptive_kl:
    # start at lr and, before every gradient step, divide it by 1.5 when the minibatch's KL from
    # the policy that collected the batch exceeds 2 x desired_kl, multiply it by 1.5 when the KL
    # is below desired_kl / 2, within [lr_min, lr_max] (the rule of rsl_rl's PPO; lr_max null =
    # lr: the schedule only ever lowers the configured lr). The step size then follows the
    # policy's own sensitivity instead of the frame count.
    lr_schedule: str = ranged("linear", Range(choices=LR_SCHEDULES))
    lr_final_frac: float = ranged(0.05, UNIT_INTERVAL)
    desired_kl: float = ranged(0.05, Range(0.0, 10.0, low_open=True))
    lr_min: float = ranged(1e-5, LEARNING_RATE)
    lr_max: float | None = ranged(None, Range(0.0, 10.0, low_open=True, optional=True))
    # 0.95 (a return horizon of ~20 steps, 0.4 s) rather than SB3's 0.99 (~2 s): the policy sees
    # the reference 0.54 s ahead, so with 0.99 most of the return depends on reference it cannot
    # see, and that noise swamps the advantage of a precise action (docs/training.md).
    gamma: float = ranged(0.95, FRACTION)
    lmbda: float = ranged(0.95, UNIT_INTERVAL)
    clip_epsilon: float = ranged(0.2, Range(0.0, 1.0, low_open=True))
    entropy_coeff: float = ranged(0.0, WEIGHT)
    critic_coeff: float = ranged(0.5, POSITIVE_WEIGHT)
    loss_critic_type: str = ranged("l2", Range(choices=("l1", "l2", "smooth_l1")))
    max_grad_norm: float = ranged(0.5, POSITIVE_WEIGHT)
    normalize_advantage: bool = True
    # Rewards are multiplied by this before GAE (returns here are O(100): 500-step episodes, the
    # crash penalty). 0.01 ≈ (1 − γ) keeps values O(1), but measured by time to accuracy the
    # unscaled rewards learned faster (docs/training.md), so 1.0 is the default.
    reward_scale: float = ranged(1.0, POSITIVE_WEIGHT)

    def validate(self) -> None:
        """Rules across fields (each field's own range is declared with it, :func:`ranged`)."""

        def need(ok: bool, key: str, msg: str) -> None:
            if not ok:
                raise ConfigError(f"algo.{key}: {msg}")

        check_ranges(self, "algo")
        check_rollout_memory(self.num_envs, self.rollout_steps)
        need(
            self.lr_schedule != "adaptive_kl" or self.lr_min <= self.lr <= self.lr_cap,
            "lr",
            f"must be in [lr_min, lr_max] = [{self.lr_min}, {self.lr_cap}] with lr_schedule=adaptive_kl, got {self.lr}",
        )
        need(
            self.lr_schedule != "exponential" or self.lr_final_frac > 0,
            "lr_final_frac",
            "must be > 0 with lr_schedule=exponential (a geometric decay never reaches 0)",
        )

    @property
    def lr_cap(self) -> float:
        """adaptive_kl's upper bound: ``lr_max``, or the starting lr when it is null."""
        return self.lr if self.lr_max is None else self.lr_max


# A lower bound on what one frame of a rollout holds (float32): the observation and the next one
# (13 state entries + 10 reference points x 3 at the default horizon, each), the action, its
# log-probability, the value and its target, the reward and the done flags: (2 x 43 + 4 + 4) x 4 B.
ROLLOUT_BYTES_PER_FRAME_MIN = 376


def machine_memory_bytes() -> int | None:
    """The machine's physical memory (not what is free now: a check that hangs on the load of
    the moment would pass or fail by chance); None where the platform does not say."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, OSError, ValueError):
        return None


def check_rollout_memory(num_envs: int, rollout_steps: int, memory_bytes: int | None = None) -> None:
    """Refuse in one line a rollout that cannot fit in the machine's memory, before anything is
    allocated (an allocation that size ends in the kernel's out-of-memory kill, or a swap storm)."""
    memory_bytes = machine_memory_bytes() if memory_bytes is None else memory_bytes
    frames = int(num_envs) * int(rollout_steps)
    need_bytes = frames * ROLLOUT_BYTES_PER_FRAME_MIN
    if memory_bytes is not None and need_bytes > memory_bytes:
        raise ConfigError(
            f"algo.num_envs x algo.rollout_steps: {frames:,} frames a rollout need at least "
            f"{need_bytes / 1e9:.1f} GB ({ROLLOUT_BYTES_PER_FRAME_MIN} B a frame); this machine has "
            f"{memory_bytes / 1e9:.1f} GB: lower algo.num_envs or algo.rollout_steps"
        )


ACTION_NAMES = ("thrust", "wx", "wy", "wz")


def policy_std(scale: torch.Tensor) -> dict[str, float]:
    """Mean pre-tanh std of the policy per action over a batch (``scale [..., 4]``), as
    ``policy_std_<action>``: the exploration left, and the policy's sensitivity (a KL of a given
    size is a smaller change of the mean when the std is small)."""
    mean = scale.reshape(-1, scale.shape[-1]).mean(0)
    return {f"policy_std_{name}": value.item() for name, value in zip(ACTION_NAMES, mean, strict=True)}


def crash_rate(terminated: torch.Tensor, done: torch.Tensor) -> float:
    """Share of the episodes that ended in a batch that ended in a crash (``terminated``; the
    others were truncated at the episode length); 0 when none ended. Both ``[..., 1]`` booleans."""
    return (terminated.sum() / done.sum().clamp_min(1)).item()


class Trainer:
    """Owns env, modules, loss, optimiser and the loop. ``cfg`` is the composed train config."""

    def __init__(self, cfg: DictConfig, run_dir: str | Path, logger: Logger) -> None:
        self.cfg = cfg
        self.run_dir = Path(run_dir)
        self.logger = logger
        self.algo: AlgoParams = structured(AlgoParams, cfg.algo, "algo")
        self.policy_params: PolicyParams = structured(PolicyParams, cfg.policy, "policy")
        train_params = self.train_params = structured(TrainParams, cfg.train, "train")
        curriculum = structured(CurriculumParams, cfg.curriculum, "curriculum")
        budget = budget_factor(cfg)
        self.total_frames = int(int(train_params.total_frames) * budget)
        if self.total_frames < 1:
            raise ConfigError(f"train.total_frames: must be >= 1, got {self.total_frames}")
        self.fixed_ref_frames = int(curriculum.fixed_ref_frames * budget)
        if curriculum.fixed_ref == "whole_run" and self.fixed_ref_frames > 0:
            self.fixed_ref_frames = self.total_frames
        self.main_traj = instantiate_option(cfg, "traj")
        self.fixed_traj = instantiate_option(cfg.curriculum, "fixed") if self.fixed_ref_frames > 0 else None
        seed = int(cfg.seed)
        torch.manual_seed(seed)
        self.env = make_env(cfg, num_envs=self.algo.num_envs, seed=seed, traj=self.fixed_traj or self.main_traj)
        self.curriculum_ref = "fixed" if self.fixed_traj is not None else "main"
        if train_params.stagger_episodes:
            self.env.stagger_episodes()
        self.actor = make_actor(
            self.env.horizon, self.env.action_low, self.env.action_high, self.policy_params, self.env.state_dim
        ).to(self.env.device)  # env.device: the policy, the critic and PPO's tensors live beside the drones
        self.critic = make_critic(
            self.env.horizon, self.policy_params, self.env.state_dim, len(self.env.critic_offsets)
        ).to(self.env.device)
        self._make_update()
        # the checkpoints this run's weights descend from, oldest first: each one's whole config
        # and frames, so a chain of fine-tunes stays reproducible after its files are gone
        self.lineage: list[dict] = []
        if train_params.init_from:
            self.init_weights(train_params.init_from)
        self.frames_per_batch = self.algo.num_envs * self.algo.rollout_steps
        self.frames = 0
        self.iteration = 0
        self.best_error = math.inf
        self.history: list[dict] = []  # one row per iteration, kept in the checkpoint (whole learning curve)
        self.train_wall_s = 0.0  # training time summed over every segment of the run
        self.adaptive_lr = self.algo.lr  # lr_schedule=adaptive_kl: the lr the last gradient step left

    def _make_update(self) -> None:
        """PPO's parts over the actor and critic: the clipped loss, GAE and Adam."""
        algo = self.algo
        self.loss = ClipPPOLoss(
            self.actor,
            self.critic,
            clip_epsilon=algo.clip_epsilon,
            entropy_bonus=algo.entropy_coeff > 0,
            entropy_coeff=algo.entropy_coeff if algo.entropy_coeff > 0 else None,
            critic_coeff=algo.critic_coeff,
            loss_critic_type=algo.loss_critic_type,
            normalize_advantage=algo.normalize_advantage,
            # the modules' own parameters: the functional form swaps a parameter copy into each
            # module on every call, ~45 % of a minibatch-64 step (algo=sb3); the same maths
            functional=False,
        )
        self.gae = GAE(gamma=algo.gamma, lmbda=algo.lmbda, value_network=self.critic, average_gae=False, shifted=True)
        # fused: one kernel for every parameter's update instead of a Python loop over them (the
        # same Adam; a step of a small minibatch is mostly per-tensor overhead)
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=algo.lr, fused=True)
        keys = self.loss.tensor_keys
        self._loss_keys = sorted(
            {k for k in self.loss.in_keys if isinstance(k, str)}
            | {keys.advantage, keys.value_target, keys.value, keys.sample_log_prob, keys.action}
        )

    # -- checkpoints -------------------------------------------------------------------------
    def state(self) -> dict:
        return {
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "optimizer": self.optim.state_dict(),
            "frames": self.frames,
            "iteration": self.iteration,
            "best_error_m": self.best_error,
            "curriculum_ref": self.curriculum_ref,
            "horizon": self.env.horizon,
            "config_yaml": OmegaConf.to_yaml(self.cfg, resolve=True),
            "rng_torch": torch.get_rng_state(),
            "rng_env": self.env.generator.get_state(),
            "history": self.history,
            "train_wall_s": self.train_wall_s,
            "lineage": self.lineage,
            "adaptive_lr": self.adaptive_lr,
        }

    def save(self, name: str = "last.pt") -> Path:
        return save_checkpoint(self.run_dir / name, self.state())

    def init_weights(self, path: str | Path) -> None:
        """Start from another run's actor/critic weights (fine-tuning); optimiser, frame count
        and curriculum start fresh. The horizon and policy shape must match, except that a
        checkpoint with fewer commands of history (``env.obs.action_history``) is widened: the
        older commands enter with zero weights (:func:`widen_command_history`)."""
        data = load_checkpoint(resolve_path(path), key="train.init_from")
        if int(data["horizon"]) != self.env.horizon:
            raise ConfigError(
                f"train.init_from: checkpoint has horizon={data['horizon']}, config has {self.env.horizon}"
            )
        actor, critic = data["actor"], data["critic"]
        # the checkpoint's layout as load_actor reads it (no key: ObsParams' default, no commands)
        parent_cfg = upgrade_saved_config(OmegaConf.create(data["config_yaml"]))
        check_targets(parent_cfg, "train.init_from", source=str(path))  # carried on in the lineage: data only
        old = env_params_from_cfg(parent_cfg.env).obs.action_history
        new = self.env.params.obs.action_history
        if old > new:
            raise ConfigError(
                f"train.init_from: checkpoint has env.obs.action_history={old}, config has {new} "
                f"(a policy can be widened to more commands of history, not narrowed)"
            )
        if old < new:
            actor, critic = (widen_command_history(w, old, new) for w in (actor, critic))
            log.info("train.init_from: command history widened from %d to %d (zero weights)", old, new)
        try:
            self.actor.load_state_dict(actor)
            self.critic.load_state_dict(critic)
        except RuntimeError as exc:
            raise ConfigError(
                f"train.init_from: policy shape differs from policy config ({str(exc).splitlines()[0]})"
            ) from None
        parent = {"checkpoint": str(path), "frames": int(data["frames"]), "config_yaml": data["config_yaml"]}
        self.lineage = [*(dict(entry) for entry in data.get("lineage", [])), parent]

    def load(self, path: str | Path) -> None:
        data = load_checkpoint(path, key="resume")
        if int(data["horizon"]) != self.env.horizon:
            raise ConfigError(f"resume: checkpoint has horizon={data['horizon']}, config has {self.env.horizon}")
        self.actor.load_state_dict(data["actor"])
        self.critic.load_state_dict(data["critic"])
        self.optim.load_state_dict(data["optimizer"])
        self.frames = int(data["frames"])
        self.iteration = int(data["iteration"])
        self.best_error = float(data["best_error_m"])
        torch.set_rng_state(data["rng_torch"])
        self.env.generator.set_state(data["rng_env"])
        self.history = [dict(row) for row in data.get("history", [])]
        self.lineage = [dict(entry) for entry in data.get("lineage", [])]
        self.train_wall_s = float(data.get("train_wall_s", 0.0))
        self.adaptive_lr = float(data.get("adaptive_lr", self.algo.lr))
        self._update_curriculum_ref()

    # -- loop -------------------------------------------------------------------------------
    def _interrupted(self, signal_name: str) -> TrainingInterrupted:
        return TrainingInterrupted(
            f"{signal_name}: checkpoint at {self.frames:,} of {self.total_frames:,} frames in "
            f"{self.run_dir / 'last.pt'}; resume with resume={self.run_dir}",
            signal=signal_name,
        )

    def _update_curriculum_ref(self) -> None:
        # Drones pick up the new family as their episodes end (within one episode).
        if self.curriculum_ref == "fixed" and self.frames >= self.fixed_ref_frames:
            self.curriculum_ref = "main"
            self.env.traj = self.main_traj
        elif self.curriculum_ref == "main" and self.fixed_traj is not None and self.frames < self.fixed_ref_frames:
            self.curriculum_ref = "fixed"
            self.env.traj = self.fixed_traj

    def _lr(self) -> float:
        algo = self.algo
        if algo.lr_schedule == "constant":
            return algo.lr
        if algo.lr_schedule == "adaptive_kl":
            return self.adaptive_lr
        frac = min(1.0, self.frames / self.total_frames)
        if algo.lr_schedule == "exponential":
            return algo.lr * algo.lr_final_frac**frac
        return algo.lr * (1.0 - (1.0 - algo.lr_final_frac) * frac)

    def _set_lr(self, lr: float) -> None:
        for group in self.optim.param_groups:
            group["lr"] = lr

    def _check_finite(self, name: str, value: torch.Tensor) -> None:
        if not torch.isfinite(value).all():
            last = self.run_dir / "last.pt"
            where = f"last good checkpoint: {last}" if last.is_file() else "no checkpoint was written before it"
            raise TrainingDiverged(f"non-finite {name} at iteration {self.iteration} (frame {self.frames}); {where}")

    def update(self, batch) -> dict:
        """GAE + PPO epochs on one collected batch ``[num_envs, rollout_steps]``."""
        algo = self.algo
        for key in (("next", "state"), ("next", "ref"), "action"):
            self._check_finite("/".join(key) if isinstance(key, tuple) else key, batch.get(key))
        with torch.no_grad():
            if algo.reward_scale != 1.0:
                batch.set(("next", "reward"), batch.get(("next", "reward")) * algo.reward_scale)
            self.gae(batch)
        # Only what the loss reads: indexing all ~25 rollout keys per minibatch cost ~6 % of
        # each gradient step. The ("next", ...) entries were needed by GAE only.
        data = batch.reshape(-1).select(*self._loss_keys, strict=False)
        lr = self._lr()
        self._set_lr(lr)
        stats = {"loss_objective": 0.0, "loss_critic": 0.0, "grad_norm": 0.0, "kl_approx": 0.0}
        adaptive = algo.lr_schedule == "adaptive_kl"
        count = 0
        for _ in range(algo.epochs):
            for idx in torch.randperm(data.shape[0]).split(algo.minibatch_size):
                losses = self.loss(data[idx])
                total = losses["loss_objective"] + losses["loss_critic"]
                if "loss_entropy" in losses.keys():
                    total = total + losses["loss_entropy"]
                self._check_finite("loss", total.detach())
                kl = losses["kl_approx"].item()
                if adaptive:
                    lr = self.adaptive_lr = adapt_lr(lr, kl, algo)
                    self._set_lr(lr)
                self.optim.zero_grad(set_to_none=True)
                total.backward()
                # Clip actor and critic separately: the critic's gradient (returns of order
                # 100 with the crash penalty) would otherwise eat the actor's share of the norm.
                grad = torch.nn.utils.clip_grad_norm_(self.actor.parameters(), algo.max_grad_norm)
                torch.nn.utils.clip_grad_norm_(self.critic.parameters(), algo.max_grad_norm)
                self._check_finite("gradient", grad)
                self.optim.step()
                stats["loss_objective"] += losses["loss_objective"].item()
                stats["loss_critic"] += losses["loss_critic"].item()
                stats["grad_norm"] += grad.item()
                stats["kl_approx"] += kl
                count += 1
        out = {k: v / count for k, v in stats.items()}
        out["lr"] = lr  # adaptive_kl: the lr after the iteration's last step
        return out

    def _progress(self) -> ProgressReport:
        """Lines of the run's progress (frames, rate, ETA, the batch's error and return
        estimate): one per ``train.progress_every_s`` seconds; none with ``train.progress=false``."""
        return ProgressReport(
            "train",
            self.total_frames,
            "frames",
            every_s=self.train_params.progress_every_s,
            enabled=self.train_params.progress,
        )

    def _row(self, batch: TensorDict, ret_per_step: float, stats: dict, iter_s: float) -> dict:
        """One iteration's history row (and logged metrics): the batch's mean tracking error,
        reward and crash rate, throughput over ``iter_s`` seconds, policy std and update stats."""
        return {
            "frames": self.frames,
            "iteration": self.iteration,
            "tracking_error_m": batch["next", "tracking_error_m"].mean().item(),
            "reward_per_step": ret_per_step,
            "episode_return_est": ret_per_step * self.env.params.episode_steps,
            "crash_rate": crash_rate(batch["next", "terminated"], batch["next", "done"]),
            "steps_per_s": batch.numel() / iter_s,
            "curriculum_ref": self.curriculum_ref,
            **policy_std(batch["scale"]),
            **stats,
        }

    def train(self) -> list[dict]:
        remaining = self.total_frames - self.frames
        if remaining <= 0:
            log.info("run already complete (%d frames)", self.frames)
            return self.history
        collector = Collector(
            self.env,
            self.actor,
            frames_per_batch=self.frames_per_batch,
            total_frames=math.ceil(remaining / self.frames_per_batch) * self.frames_per_batch,
            auto_register_policy_transforms=False,  # the policy is stateless: no InitTracker needed
        )
        every = max(1, self.train_params.checkpoint_every)
        progress = self._progress()
        stop = StopRequest()
        with stop:
            t_iter = t_last = time.perf_counter()
            for batch in collector:
                ret_per_step = batch["next", "reward"].mean().item()  # before update() scales it
                stats = self.update(batch)
                self.frames += batch.numel()
                self.iteration += 1
                now = time.perf_counter()
                row = self._row(batch, ret_per_step, stats, now - t_iter)
                err = row["tracking_error_m"]
                t_iter = now
                self.history.append(row)
                self.logger.log({k: v for k, v in row.items() if k != "curriculum_ref"}, step=self.frames)
                progress.update(self.frames, err=f"{err:.3f} m", ret=f"{row['episode_return_est']:.2f}")
                if self.curriculum_ref == "main" and err < self.best_error:
                    self.best_error = err
                    self.save("best.pt")
                self._update_curriculum_ref()
                self.train_wall_s += now - t_last
                t_last = now
                if self.iteration % every == 0 or stop.signal:
                    self.save("last.pt")
                if stop.signal:
                    collector.shutdown()
                    raise self._interrupted(stop.signal)
        collector.shutdown()
        self.save("last.pt")
        if self.curriculum_ref != "main" or not (self.run_dir / "best.pt").exists():
            self.save("best.pt")
        return self.history
