"""The PPO wiring against hand computation: GAE's γ and λ, and the configured advantage normalisation."""

import logging

import pytest
import torch
from tensordict import TensorDict

from datt.train.loggers import CsvLogger
from datt.train.ppo import Trainer

from .test_training import tiny_cfg

GAMMA, LMBDA, VALUE = 0.9, 0.5, 0.5


def constant_critic_trainer(tmp_path, *extra):
    trainer = Trainer(tiny_cfg(f"algo.gamma={GAMMA}", f"algo.lmbda={LMBDA}", *extra), tmp_path, CsvLogger(tmp_path))
    with torch.no_grad():
        head = trainer.critic.module.head
        head.weight.zero_()
        head.bias.fill_(VALUE)
    return trainer


def three_step_batch(trainer, rewards, terminated):
    """One env, three steps; observations are zeros (the critic is constant anyway)."""
    env = trainer.env
    obs = {
        "state": torch.zeros(1, 3, env.state_dim),
        "ref": torch.zeros(1, 3, env.horizon, 3),
        "d_hat": torch.zeros(1, 3, 3),
    }
    term = torch.tensor(terminated, dtype=torch.bool).reshape(1, 3, 1)
    nxt = dict(obs, reward=torch.tensor(rewards).reshape(1, 3, 1), terminated=term, done=term.clone())
    return TensorDict(dict(obs, next=TensorDict(nxt, [1, 3])), [1, 3])


def hand_gae(rewards, terminated):
    """A_t = δ_t + γλ(1 − d_t) A_{t+1}, δ_t = r_t + γ(1 − d_t) V − V with V constant."""
    adv, running = [0.0] * 3, 0.0
    for t in reversed(range(3)):
        alive = 0.0 if terminated[t] else 1.0
        delta = rewards[t] + GAMMA * alive * VALUE - VALUE
        running = delta + GAMMA * LMBDA * alive * running
        adv[t] = running
    return adv


@pytest.mark.parametrize("terminated", [[False, False, False], [False, True, False]])
def test_gae_matches_hand_computation(tmp_path, terminated):
    rewards = [1.0, 2.0, 3.0]
    trainer = constant_critic_trainer(tmp_path)
    batch = three_step_batch(trainer, rewards, terminated)
    trainer.gae(batch)
    expect = torch.tensor(hand_gae(rewards, terminated))
    # no termination: δ = r − 0.05 -> A = [0.95 + 0.45(1.95 + 0.45·2.95), 1.95 + 0.45·2.95, 2.95]
    torch.testing.assert_close(batch["advantage"].reshape(3), expect)
    torch.testing.assert_close(batch["value_target"].reshape(3), expect + VALUE)


def _objective_for_scaled_advantages(trainer):
    """The PPO objective on one real rollout with advantages A and 10·A + 3."""
    torch.manual_seed(0)
    with torch.no_grad():
        td = trainer.env.rollout(4, trainer.actor, break_when_any_done=False).reshape(-1)
    adv = torch.linspace(-1.0, 1.0, td.shape[0]).unsqueeze(-1)
    out = []
    for scaled in (adv, 10 * adv + 3):
        data = td.clone()
        data.set("advantage", scaled)
        data.set("value_target", torch.zeros_like(scaled))
        out.append(trainer.loss(data)["loss_objective"].item())
    return out


def test_normalize_advantage_is_the_configured_one(tmp_path):
    # Normalised advantages make the objective invariant to an affine rescaling of A; raw ones do not.
    on = constant_critic_trainer(tmp_path / "on", "algo.normalize_advantage=true")
    plain, scaled = _objective_for_scaled_advantages(on)
    assert scaled == pytest.approx(plain, rel=1e-4, abs=1e-6)
    off = constant_critic_trainer(tmp_path / "off", "algo.normalize_advantage=false")
    plain, scaled = _objective_for_scaled_advantages(off)
    assert abs(scaled - plain) > 1.0, (plain, scaled)


def test_load_checks_and_restores_the_bookkeeping(tmp_path):
    from datt.checkpoint import load_checkpoint, save_checkpoint
    from datt.errors import ConfigError

    trainer = Trainer(tiny_cfg(), tmp_path, CsvLogger(tmp_path))
    trainer.history = [{"iteration": 1, "frames": 1024}]
    trainer.train_wall_s = 12.5
    trainer.frames, trainer.iteration = 1024, 1
    trainer.save()
    fresh = Trainer(tiny_cfg(), tmp_path, CsvLogger(tmp_path))
    fresh.load(tmp_path / "last.pt")
    assert fresh.history == [{"iteration": 1, "frames": 1024}] and fresh.train_wall_s == 12.5
    assert (fresh.frames, fresh.iteration) == (1024, 1)
    # a checkpoint from before the history, lineage and adaptive lr were kept: empty history and
    # lineage, no wall time, the configured lr
    old = load_checkpoint(tmp_path / "last.pt")
    del old["history"], old["train_wall_s"], old["lineage"], old["adaptive_lr"]
    save_checkpoint(tmp_path / "old.pt", {k: v for k, v in old.items() if k != "format"})
    fresh.lineage, fresh.adaptive_lr = [{"run": "another"}], 123.0
    fresh.load(tmp_path / "old.pt")
    assert fresh.history == [] and fresh.train_wall_s == 0.0
    assert fresh.lineage == [] and fresh.adaptive_lr == fresh.algo.lr
    with pytest.raises(ConfigError, match=r"^resume: file '.*nope.pt' not found$"):
        fresh.load(tmp_path / "nope.pt")
    other = Trainer(tiny_cfg("horizon=5"), tmp_path / "h5", CsvLogger(tmp_path))
    with pytest.raises(ConfigError) as info:
        other.load(tmp_path / "last.pt")
    assert str(info.value) == "resume: checkpoint has horizon=10, config has 5"


def test_init_from_copies_weights_and_checks_the_shape(tmp_path):
    from datt.errors import ConfigError

    source = Trainer(tiny_cfg(), tmp_path / "a", CsvLogger(tmp_path))
    source.frames = 2048
    ckpt = source.save()
    tuned = Trainer(tiny_cfg(f"train.init_from={ckpt}"), tmp_path / "b", CsvLogger(tmp_path))
    for name, value in source.actor.state_dict().items():
        assert torch.equal(tuned.actor.state_dict()[name], value), name
    for name, value in source.critic.state_dict().items():
        assert torch.equal(tuned.critic.state_dict()[name], value), name
    assert tuned.frames == 0  # fine-tuning starts its own count
    with pytest.raises(ConfigError) as info:
        Trainer(tiny_cfg(f"train.init_from={ckpt}", "horizon=5"), tmp_path / "c", CsvLogger(tmp_path))
    assert str(info.value) == "train.init_from: checkpoint has horizon=10, config has 5"
    with pytest.raises(ConfigError, match=r"^train.init_from: policy shape differs from policy config \(Error\(s\) in"):
        Trainer(tiny_cfg(f"train.init_from={ckpt}", "policy.hidden=[32,32]"), tmp_path / "d", CsvLogger(tmp_path))
    with pytest.raises(ConfigError, match=r"^train.init_from: file '.*nope.pt' not found$"):
        Trainer(tiny_cfg(f"train.init_from={tmp_path / 'nope.pt'}"), tmp_path / "e", CsvLogger(tmp_path))


def test_init_from_widens_the_command_history_and_keeps_the_function(tmp_path, caplog):
    """A checkpoint with 2 commands of history fine-tuned with 4: the widened actor and critic give
    the old outputs whatever the two older commands are; narrowing is refused in one line."""
    from datt.errors import ConfigError

    caplog.set_level(logging.INFO)
    source = Trainer(tiny_cfg("env.obs.action_history=2"), tmp_path / "a", CsvLogger(tmp_path))
    with torch.no_grad():  # non-zero weights on every input, so a misplaced column shows
        for p in source.actor.parameters():
            p.normal_(0.0, 0.3)
    ckpt = source.save()
    wide = Trainer(tiny_cfg("env.obs.action_history=4", f"train.init_from={ckpt}"), tmp_path / "b", CsvLogger(tmp_path))
    gen = torch.Generator().manual_seed(0)
    n, h = 5, source.env.horizon
    state2 = torch.randn(n, 13 + 8, generator=gen)
    older = torch.randn(n, 8, generator=gen)
    state4 = torch.cat((state2[:, :13], older, state2[:, 13:]), dim=1)  # oldest first
    ref, d_hat = torch.randn(n, h, 3, generator=gen), torch.randn(n, 3, generator=gen)
    old_net, new_net = source.actor.module[0].module.net, wide.actor.module[0].module.net
    torch.testing.assert_close(new_net(state4, ref, d_hat), old_net(state2, ref, d_hat))
    torch.testing.assert_close(wide.critic.module(state4, ref, d_hat), source.critic.module(state2, ref, d_hat))
    assert "train.init_from: command history widened from 2 to 4 (zero weights)" in caplog.text
    caplog.clear()
    Trainer(tiny_cfg("env.obs.action_history=2", f"train.init_from={ckpt}"), tmp_path / "same", CsvLogger(tmp_path))
    assert "widened" not in caplog.text
    # a checkpoint from before the history input (no env.obs.action_history key): widened from 0
    data = torch.load(ckpt, weights_only=True)
    lines = data["config_yaml"].splitlines()
    data["config_yaml"] = "\n".join(line for line in lines if "action_history:" not in line)
    assert "action_history" not in data["config_yaml"]
    old_ckpt = tmp_path / "old.pt"
    torch.save(data, old_ckpt)
    with pytest.raises(ConfigError, match=r"^train.init_from: policy shape differs"):  # its weights have 2
        Trainer(
            tiny_cfg("env.obs.action_history=4", f"train.init_from={old_ckpt}"), tmp_path / "o", CsvLogger(tmp_path)
        )
    assert "widened from 0 to 4" in caplog.text
    with pytest.raises(ConfigError) as info:
        Trainer(tiny_cfg("env.obs.action_history=1", f"train.init_from={ckpt}"), tmp_path / "c", CsvLogger(tmp_path))
    assert str(info.value) == (
        "train.init_from: checkpoint has env.obs.action_history=2, config has 1 "
        "(a policy can be widened to more commands of history, not narrowed)"
    )


@pytest.mark.parametrize("schedule", ["linear", "constant", "exponential"])
def test_learning_rate_schedule(tmp_path, schedule):
    """linear: lr (1 − (1 − f) frames / total), down to f · lr at the end; exponential:
    lr · f^(frames / total), the same end; constant: lr."""
    trainer = Trainer(
        tiny_cfg(f"algo.lr_schedule={schedule}", "algo.lr=0.002", "algo.lr_final_frac=0.25", "train.total_frames=4000"),
        tmp_path,
        CsvLogger(tmp_path),
    )
    seen = []
    for frames in (0, 1000, 4000, 8000):
        trainer.frames = frames
        seen.append(trainer._lr())
    if schedule == "constant":
        assert seen == [0.002] * 4
    elif schedule == "exponential":
        assert seen == pytest.approx([0.002, 0.002 * 0.25**0.25, 0.0005, 0.0005])
    else:
        assert seen == pytest.approx([0.002, 0.002 * (1 - 0.75 * 0.25), 0.0005, 0.0005])


def _rollout_batch(trainer, steps=8):
    """A collected-like batch ``[num_envs, steps]`` from the trainer's own env and actor."""
    torch.manual_seed(1)
    with torch.no_grad():
        return trainer.env.rollout(steps, trainer.actor, break_when_any_done=False)


def test_update_scales_rewards_and_reports_the_losses_it_optimised(tmp_path):
    """One epoch, one minibatch, a negligible lr: the returned losses are the loss of the batch
    as it went in (rewards × reward_scale before GAE), the lr is the scheduled one."""
    trainer = Trainer(
        tiny_cfg(
            "algo.epochs=1",
            "algo.minibatch_size=100000",
            "algo.lr=1e-12",
            "algo.lr_schedule=constant",
            "algo.reward_scale=2.0",
        ),  # fmt: skip
        tmp_path,
        CsvLogger(tmp_path),
    )
    batch = _rollout_batch(trainer)
    reward = batch["next", "reward"].clone()
    stats = trainer.update(batch)
    assert torch.equal(batch["next", "reward"], reward * 2.0)
    data = batch.reshape(-1)
    losses = trainer.loss(data.select(*trainer._loss_keys, strict=False))
    assert stats["loss_objective"] == pytest.approx(losses["loss_objective"].item(), rel=1e-5, abs=1e-6)
    assert stats["loss_critic"] == pytest.approx(losses["loss_critic"].item(), rel=1e-5)
    trainer.optim.zero_grad()
    (losses["loss_objective"] + losses["loss_critic"]).backward()
    grad = torch.nn.utils.clip_grad_norm_(trainer.actor.parameters(), float("inf"))
    assert stats["grad_norm"] == pytest.approx(grad.item(), rel=1e-4)
    assert stats["lr"] == trainer._lr() and trainer.optim.param_groups[0]["lr"] == trainer._lr()


def test_update_moves_the_critic_toward_its_targets(tmp_path):
    trainer = Trainer(tiny_cfg("algo.epochs=8", "algo.lr=3e-3"), tmp_path, CsvLogger(tmp_path))
    batch = _rollout_batch(trainer, steps=16)
    first = trainer.update(batch.clone())["loss_critic"]
    for _ in range(3):
        last = trainer.update(batch.clone())["loss_critic"]
    assert last < 0.8 * first, (first, last)


def test_the_asymmetric_critic_learns_from_critic_ref(tmp_path):
    """``env.obs.critic_ref_points``: the trainer's critic reads ``critic_ref`` from the rollout
    (GAE and the loss), its weights on it are trained, and the fit improves."""
    trainer = Trainer(
        tiny_cfg("env.obs.critic_ref_points=5", "algo.epochs=8", "algo.lr=3e-3"), tmp_path, CsvLogger(tmp_path)
    )
    assert "critic_ref" in trainer.critic.in_keys and "critic_ref" in trainer._loss_keys
    first_layer = trainer.critic.module.mlp[0].weight
    cols = slice(first_layer.shape[1] - 15, None)  # critic_ref enters last
    before = first_layer[:, cols].detach().clone()
    batch = _rollout_batch(trainer, steps=16)
    assert batch["critic_ref"].shape == (64, 16, 5, 3)
    first = trainer.update(batch.clone())["loss_critic"]
    for _ in range(6):
        last = trainer.update(batch.clone())["loss_critic"]
    assert last < 0.8 * first, (first, last)
    assert not torch.equal(first_layer[:, cols], before)


def test_entropy_bonus_enters_the_loss(tmp_path):
    """With entropy_coeff > 0 the optimised total includes the entropy term (a policy that can
    only raise its entropy does so)."""
    trainer = Trainer(
        tiny_cfg("algo.entropy_coeff=10.0", "algo.epochs=4", "algo.lr=1e-2"), tmp_path, CsvLogger(tmp_path)
    )
    batch = _rollout_batch(trainer)
    head_bias = dict(trainer.actor.named_parameters())["module.0.module.net.head.bias"]
    scale = lambda: head_bias[4:].mean().item()  # noqa: E731  (the pre-softplus std outputs)
    before = scale()
    trainer.update(batch)
    assert scale() > before + 1e-3


@pytest.mark.parametrize("key", [("next", "state"), ("next", "ref"), ("action",)])
def test_non_finite_batch_names_what_and_where(tmp_path, key):
    from datt.errors import TrainingDiverged

    trainer = Trainer(tiny_cfg(), tmp_path, CsvLogger(tmp_path))
    batch = _rollout_batch(trainer)
    value = batch.get(key if len(key) > 1 else key[0])
    value.view(-1)[0] = float("nan")
    with pytest.raises(TrainingDiverged) as info:
        trainer.update(batch)
    name = "/".join(key)
    assert str(info.value) == f"non-finite {name} at iteration 0 (frame 0); no checkpoint was written before it"
    trainer.save()
    batch = _rollout_batch(trainer)
    batch.get(key if len(key) > 1 else key[0]).view(-1)[0] = float("nan")
    with pytest.raises(TrainingDiverged, match=f"; last good checkpoint: {tmp_path / 'last.pt'}$"):
        trainer.update(batch)


def test_update_reports_the_mean_over_every_minibatch_of_every_epoch(tmp_path):
    """Two epochs of four minibatches at a negligible lr: the reported losses are the mean of the
    eight minibatch losses (same permutations, replayed from the same seed)."""
    trainer = Trainer(
        tiny_cfg(
            "algo.epochs=2",
            "algo.minibatch_size=128",
            "algo.lr=1e-12",
            "algo.lr_schedule=constant",
            "algo.reward_scale=1.0",
        ),  # fmt: skip
        tmp_path,
        CsvLogger(tmp_path),
    )
    batch = _rollout_batch(trainer)  # 64 envs × 8 steps = 512 frames: 4 minibatches of 128
    torch.manual_seed(7)
    stats = trainer.update(batch.clone())
    data = batch.clone()
    with torch.no_grad():
        trainer.gae(data)
    data = data.reshape(-1).select(*trainer._loss_keys, strict=False)
    torch.manual_seed(7)
    objective, critic, grad = [], [], []
    for _ in range(2):
        for idx in torch.randperm(data.shape[0]).split(128):
            losses = trainer.loss(data[idx])
            objective.append(losses["loss_objective"].item())
            critic.append(losses["loss_critic"].item())
            trainer.optim.zero_grad()
            (losses["loss_objective"] + losses["loss_critic"]).backward()
            grad.append(torch.nn.utils.clip_grad_norm_(trainer.actor.parameters(), float("inf")).item())
    assert len(objective) == 2 * 4
    assert stats["loss_objective"] == pytest.approx(sum(objective) / 8, rel=1e-4, abs=1e-6)
    assert stats["loss_critic"] == pytest.approx(sum(critic) / 8, rel=1e-4)
    assert stats["grad_norm"] == pytest.approx(sum(grad) / 8, rel=1e-4)
    assert stats["loss_critic"] != pytest.approx(critic[-1], rel=1e-3)  # not the last minibatch's
    assert stats["grad_norm"] != pytest.approx(grad[-1], rel=1e-3)


@pytest.mark.parametrize(
    "kind, distance",
    [
        ("l2", lambda d: d**2),
        ("l1", lambda d: d.abs()),
        ("smooth_l1", lambda d: torch.where(d.abs() < 1, 0.5 * d**2, d.abs() - 0.5)),
    ],
)
def test_critic_loss_is_the_configured_distance_times_its_coefficient(tmp_path, kind, distance):
    trainer = Trainer(
        tiny_cfg(f"algo.loss_critic_type={kind}", "algo.critic_coeff=0.7", "algo.reward_scale=1.0"),
        tmp_path,
        CsvLogger(tmp_path),
    )
    batch = _rollout_batch(trainer)
    with torch.no_grad():
        trainer.gae(batch)
        data = batch.reshape(-1)
        value = trainer.critic(data.clone())["state_value"]
        expect = 0.7 * distance(data["value_target"] - value).mean()
        got = trainer.loss(data.select(*trainer._loss_keys, strict=False))["loss_critic"]
    assert (data["value_target"] - value).abs().max() > 1.0  # both branches of smooth_l1 are in play
    torch.testing.assert_close(got, expect, rtol=1e-5, atol=1e-6)


def test_clip_epsilon_bounds_the_ratio_in_the_objective(tmp_path):
    """With every sample's old log-probability lowered by 1 (ratio e ≈ 2.72) and positive
    advantages, the clipped objective is −(1 + ε)·A: the configured ε, not the default."""
    trainer = Trainer(
        tiny_cfg("algo.clip_epsilon=0.3", "algo.normalize_advantage=false"), tmp_path, CsvLogger(tmp_path)
    )
    batch = _rollout_batch(trainer)
    with torch.no_grad():
        trainer.gae(batch)
        data = batch.reshape(-1).select(*trainer._loss_keys, strict=False)
        log_prob_key = trainer.loss.tensor_keys.sample_log_prob
        data[log_prob_key] = data[log_prob_key] - 1.0
        data["advantage"] = torch.ones_like(data["advantage"])
        got = trainer.loss(data)["loss_objective"]
    torch.testing.assert_close(got, torch.tensor(-1.3), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("section, cls", [("algo", "AlgoParams"), ("policy", "PolicyParams"),
                                          ("train", "TrainParams"), ("curriculum", "CurriculumParams")])  # fmt: skip
def test_an_unknown_key_is_named_with_its_section(tmp_path, section, cls):
    from datt.errors import ConfigError

    with pytest.raises(ConfigError) as info:
        Trainer(tiny_cfg(f"+{section}.bogus=1"), tmp_path, CsvLogger(tmp_path))
    assert str(info.value) == f"{section}.bogus: Key 'bogus' not in '{cls}'"


@pytest.mark.parametrize("coeff", [0.0, 0.05, 2.0])  # 0.05: not torchrl's default 0.01
def test_the_entropy_bonus_is_on_exactly_when_its_coefficient_is_positive(tmp_path, coeff):
    trainer = Trainer(tiny_cfg(f"algo.entropy_coeff={coeff}"), tmp_path, CsvLogger(tmp_path))
    assert trainer.loss.entropy_bonus == (coeff > 0)
    if coeff > 0:
        assert float(trainer.loss.entropy_coeff) == pytest.approx(coeff)


def test_the_smallest_budgets_are_accepted(tmp_path):
    """One step of training and one step of the fixed reference are valid settings."""
    trainer = Trainer(tiny_cfg("train.total_frames=1", "curriculum.fixed_ref_frames=1"), tmp_path, CsvLogger(tmp_path))
    assert trainer.total_frames == 1 and trainer.fixed_traj is not None and trainer.curriculum_ref == "fixed"


def test_crash_rate_is_the_share_of_ended_episodes_that_crashed():
    from datt.train.ppo import crash_rate

    def flags(*idx):
        out = torch.zeros(8, 32, 1, dtype=torch.bool)
        for i in idx:
            out[i] = True
        return out

    one_crash = flags((3, 7))
    assert crash_rate(one_crash, one_crash) == 1.0  # exactly one episode ended, and it crashed
    assert crash_rate(flags(), flags((0, 31))) == 0.0  # one ended, truncated
    assert crash_rate(flags((1, 2)), flags((1, 2), (4, 31), (5, 31))) == pytest.approx(1 / 3)
    assert crash_rate(flags(), flags()) == 0.0  # none ended


ALGO_BAD = [
    ("num_envs", 0, "must be an integer in [1, 1048576], got 0"),
    ("rollout_steps", 0, "must be an integer in [1, 100000], got 0"),
    ("epochs", 0, "must be an integer in [1, 1000], got 0"),
    ("minibatch_size", 0, "must be an integer in [1, 1048576], got 0"),
    ("lr", 0.0, "must be a finite number in (0, 10], got 0.0"),
    ("lr_final_frac", -0.1, "must be a finite number in [0, 1], got -0.1"),
    ("lr_final_frac", 1.5, "must be a finite number in [0, 1], got 1.5"),
    ("reward_scale", 0.0, "must be a finite number in (0, 1000], got 0.0"),
    ("gamma", 0.0, "must be a finite number in (0, 1], got 0.0"),
    ("gamma", 1.01, "must be a finite number in (0, 1], got 1.01"),
    ("lmbda", -0.1, "must be a finite number in [0, 1], got -0.1"),
    ("lmbda", 1.01, "must be a finite number in [0, 1], got 1.01"),
    ("loss_critic_type", "huber", "unknown value 'huber'; allowed: l1, l2, smooth_l1"),
    ("desired_kl", 0.0, "must be a finite number in (0, 10], got 0.0"),
    ("lr_min", 0.0, "must be a finite number in (0, 10], got 0.0"),
    ("max_grad_norm", -1.0, "must be a finite number in (0, 1000], got -1.0"),
    ("clip_epsilon", -0.2, "must be a finite number in (0, 1], got -0.2"),
    ("entropy_coeff", float("nan"), "must be a finite number in [0, 1000], got nan"),
]


@pytest.mark.parametrize("key, value, message", ALGO_BAD, ids=[f"{k}_{i}" for i, (k, _, _) in enumerate(ALGO_BAD)])
def test_each_algo_bound_names_its_key_and_rule(key, value, message):
    from datt.errors import ConfigError
    from datt.train.ppo import AlgoParams

    with pytest.raises(ConfigError) as info:
        AlgoParams(**{key: value}).validate()
    assert str(info.value) == f"algo.{key}: {message}"


def test_the_algo_bounds_themselves_are_allowed():
    from datt.train.ppo import AlgoParams

    AlgoParams(
        num_envs=1, rollout_steps=1, epochs=1, minibatch_size=1, lr_final_frac=0.0, gamma=1.0, lmbda=0.0
    ).validate()
    AlgoParams(lr_final_frac=1.0, lmbda=1.0, lr_schedule="exponential").validate()
    AlgoParams(lr_schedule="adaptive_kl", lr=1e-5, lr_min=1e-5, lr_max=1e-5).validate()
    for critic in ("l1", "l2", "smooth_l1"):
        AlgoParams(loss_critic_type=critic).validate()


@pytest.mark.parametrize("lr", [1e-6, 0.02])
def test_adaptive_kl_needs_a_starting_lr_within_its_bounds(lr):
    from datt.errors import ConfigError
    from datt.train.ppo import AlgoParams

    with pytest.raises(ConfigError) as info:
        AlgoParams(lr_schedule="adaptive_kl", lr=lr, lr_max=0.01).validate()
    assert str(info.value) == (
        f"algo.lr: must be in [lr_min, lr_max] = [1e-05, 0.01] with lr_schedule=adaptive_kl, got {lr}"
    )
    AlgoParams(lr_schedule="constant", lr=lr, lr_max=0.01).validate()  # the bounds belong to adaptive_kl alone
    if lr > 0.01:  # lr_max null: the starting lr is the cap, so any lr above lr_min is valid
        AlgoParams(lr_schedule="adaptive_kl", lr=lr).validate()
        assert AlgoParams(lr=lr).lr_cap == lr


def test_adapt_lr_is_the_rsl_rl_rule():
    """÷ 1.5 above 2 × desired, × 1.5 below desired / 2 (a KL estimate <= 0 changes nothing),
    unchanged in between and at both edges, clamped to [lr_min, lr_max]."""
    from datt.train.ppo import AlgoParams, adapt_lr

    algo = AlgoParams(lr_schedule="adaptive_kl", desired_kl=0.01, lr_min=1e-4, lr_max=1e-3)
    assert adapt_lr(9e-4, 1e-6, AlgoParams(lr=9e-4, lr_min=1e-4)) == 9e-4  # lr_max null: the start caps
    assert adapt_lr(6e-4, 0.0201, algo) == pytest.approx(4e-4)
    assert adapt_lr(4e-4, 0.0049, algo) == pytest.approx(6e-4)
    for kl in (0.02, 0.005, 0.01, 0.0, -0.003):
        assert adapt_lr(4e-4, kl, algo) == 4e-4
    assert adapt_lr(1.2e-4, 1.0, algo) == 1e-4
    assert adapt_lr(9e-4, 1e-6, algo) == 1e-3


def test_adaptive_kl_steers_each_step_by_the_kl_of_the_step_before_it(tmp_path, monkeypatch):
    """The lr of every gradient step is the rule applied to that minibatch's KL estimate
    (``kl_approx`` of the loss), starting from the lr the last update left; the optimiser runs
    at it, the reported lr is the last one and the reported KL the mean. A checkpoint keeps it."""
    from datt.train import ppo

    trainer = Trainer(
        tiny_cfg("algo.lr_schedule=adaptive_kl", "algo.lr=1e-3", "algo.desired_kl=0.01", "algo.lr_max=1e-2",
                 "algo.epochs=2", "algo.minibatch_size=128"),
        tmp_path,
        CsvLogger(tmp_path),
    )  # fmt: skip
    kls = iter([0.03, 0.03, 0.001, 0.01, 0.03, 0.001, 0.001, 0.001])  # 2 epochs x 4 minibatches
    real_loss = trainer.loss.forward
    used_lrs = []

    def fake_kl(td):
        out = real_loss(td)
        out.set("kl_approx", torch.tensor(next(kls)))
        return out

    real_step = trainer.optim.step

    def record_step(*args, **kwargs):
        used_lrs.append(trainer.optim.param_groups[0]["lr"])
        return real_step(*args, **kwargs)

    monkeypatch.setattr(trainer.loss, "forward", fake_kl)
    monkeypatch.setattr(trainer.optim, "step", record_step)
    stats = trainer.update(_rollout_batch(trainer))  # 512 frames: 4 minibatches of 128
    expect, lr = [], 1e-3
    for kl in [0.03, 0.03, 0.001, 0.01, 0.03, 0.001, 0.001, 0.001]:
        lr = ppo.adapt_lr(lr, kl, trainer.algo)
        expect.append(lr)
    assert used_lrs == pytest.approx(expect)
    assert expect[-1] != pytest.approx(1e-3)
    assert stats["lr"] == pytest.approx(expect[-1]) == trainer._lr()
    assert stats["kl_approx"] == pytest.approx(sum([0.03, 0.03, 0.001, 0.01, 0.03, 0.001, 0.001, 0.001]) / 8)
    trainer.save()
    fresh = Trainer(trainer.cfg, tmp_path / "fresh", CsvLogger(tmp_path / "fresh"))
    assert fresh._lr() == 1e-3
    fresh.load(tmp_path / "last.pt")
    assert fresh._lr() == pytest.approx(expect[-1])


@pytest.mark.parametrize("value", [0, -1, float("nan"), 1001, "half"], ids=["zero", "negative", "nan", "huge", "word"])
def test_a_bad_budget_is_refused_naming_its_key_where_a_run_scales_its_steps(value):
    """``budget_factor`` is what the trainer and the RMA fit multiply their step counts by; a
    config made in code (not through the schema) still gets its budget checked there, in one line
    naming the key and the allowed range; a good budget is returned as a float."""
    from omegaconf import OmegaConf

    from datt.errors import ConfigError
    from datt.train.schema import budget_factor

    with pytest.raises(ConfigError) as info:
        budget_factor(OmegaConf.create({"budget": value}))
    line = str(info.value)
    assert line.startswith("budget: must be a finite number in (0, 1000], got ") and "\n" not in line
    assert budget_factor(OmegaConf.create({"budget": 0.25})) == 0.25


def _hand_gae_batch(rewards, terminated, done, value):
    """GAE by hand over ``[envs, steps]`` with a constant value: δ = r + γ(1 − term)V − V and
    A_t = δ_t + γλ(1 − done_t) A_{t+1} (an episode's end cuts the recursion; only a termination
    cuts the bootstrap)."""
    adv = torch.zeros_like(rewards)
    running = torch.zeros(rewards.shape[0], dtype=rewards.dtype)
    for t in reversed(range(rewards.shape[1])):
        alive = (~terminated[:, t]).to(rewards.dtype)
        cont = (~done[:, t]).to(rewards.dtype)
        delta = rewards[:, t] + GAMMA * alive * value - value
        running = delta + GAMMA * LMBDA * cont * running
        adv[:, t] = running
    return adv


@pytest.mark.parametrize("scale", [2.0, 0.25])
def test_the_advantage_and_value_target_are_computed_from_the_scaled_rewards(tmp_path, scale):
    """reward_scale acts before GAE: the advantage and the value target of a constant critic are the
    hand-computed ones of the scaled rewards (scaling after GAE would leave them the unscaled
    rewards' while the batch's rewards read scaled)."""
    trainer = constant_critic_trainer(
        tmp_path, "algo.epochs=1", "algo.minibatch_size=100000", "algo.lr=1e-12", f"algo.reward_scale={scale}"
    )
    batch = _rollout_batch(trainer, steps=6)
    rewards = batch["next", "reward"].squeeze(-1).clone()
    terminated = batch["next", "terminated"].squeeze(-1)
    done = batch["next", "done"].squeeze(-1)
    trainer.update(batch)
    want = _hand_gae_batch(rewards * scale, terminated, done, VALUE)
    torch.testing.assert_close(batch["advantage"].squeeze(-1), want, rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(batch["value_target"].squeeze(-1), want + VALUE, rtol=1e-5, atol=1e-5)
    unscaled = _hand_gae_batch(rewards, terminated, done, VALUE)
    assert (want - unscaled).abs().max() > 1e-2  # the case tells the two orders apart
