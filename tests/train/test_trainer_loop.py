"""The training loop's bookkeeping: how many batches it collects, what each metrics row holds,
which checkpoints it writes when, its progress lines, and a stop request."""

import logging
import os
import signal

import pytest
import torch

from datt.checkpoint import load_checkpoint
from datt.errors import TrainingInterrupted
from datt.train.loggers import CsvLogger
from datt.train.ppo import Trainer

from .test_training import tiny_cfg

BATCH = 64 * 16  # tiny_cfg: 64 envs × 16 rollout steps


class SpyTrainer(Trainer):
    """Keeps a copy of every collected batch as it came from the collector (``update`` scales
    the rewards in place)."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self.batches = []

    def update(self, batch):
        self.batches.append(batch.clone())
        return super().update(batch)


class CheckpointSpy(CsvLogger):
    """Records, as each row is logged, the iteration held by ``last.pt`` and ``best.pt`` (None
    when absent)."""

    def __init__(self, run_dir):
        super().__init__(run_dir)
        self.run_dir = run_dir
        self.seen = []

    def _iteration(self, name):
        path = self.run_dir / name
        return load_checkpoint(path)["iteration"] if path.exists() else None

    def log(self, metrics, step):
        super().log(metrics, step)
        self.seen.append((metrics["iteration"], self._iteration("last.pt"), self._iteration("best.pt")))


def _trainer(tmp_path, *extra, cls=Trainer, logger=None):
    cfg = tiny_cfg("train.eval_at_end=false", *extra)
    return cls(cfg, tmp_path, logger or CsvLogger(tmp_path))


def _progress_lines(caplog):
    return [r.getMessage() for r in caplog.records if r.name == "datt.progress"]


@pytest.mark.parametrize("frames_done, batches", [(0, 3), (BATCH, 2), (3 * BATCH - 1, 1)])
def test_collects_exactly_the_batches_that_reach_the_total(tmp_path, frames_done, batches):
    """Batches of 1,024 frames up to (at least) the total, counted from where the run stands."""
    trainer = _trainer(tmp_path, f"train.total_frames={3 * BATCH}", "curriculum.fixed_ref_frames=0")
    trainer.frames = frames_done
    history = trainer.train()
    assert len(history) == batches
    assert [row["frames"] for row in history] == [frames_done + BATCH * (i + 1) for i in range(batches)]
    assert [row["iteration"] for row in history] == list(range(1, batches + 1))
    assert load_checkpoint(tmp_path / "last.pt")["frames"] == frames_done + BATCH * batches


def test_a_complete_run_trains_nothing_and_writes_nothing(tmp_path, caplog):
    caplog.set_level(logging.INFO)
    trainer = _trainer(tmp_path, f"train.total_frames={2 * BATCH}")
    trainer.frames = 2 * BATCH
    before = {name: param.clone() for name, param in trainer.actor.named_parameters()}
    assert trainer.train() == []
    assert "run already complete (2048 frames)" in caplog.text
    assert not (tmp_path / "last.pt").exists() and not (tmp_path / "best.pt").exists()
    assert all(torch.equal(param, before[name]) for name, param in trainer.actor.named_parameters())


def test_each_row_describes_its_batch(tmp_path):
    """Tracking error, reward and crash rate of the batch as collected; the return estimate is
    the mean reward per step × the episode's steps; the curriculum reference is the one the batch flew."""
    trainer = _trainer(
        tmp_path,
        f"train.total_frames={3 * BATCH}",
        f"curriculum.fixed_ref_frames={BATCH}",
        "algo.reward_scale=0.5",
        "env.episode_steps=8",  # episodes that end within a batch: by truncation, and
        "env.max_tracking_error_m=0.3",  # by a crash for some drones
        cls=SpyTrainer,
    )
    history = trainer.train()
    assert [row["curriculum_ref"] for row in history] == ["fixed", "main", "main"]
    for row, batch in zip(history, trainer.batches, strict=True):
        reward = batch["next", "reward"].mean().item()  # unscaled: before update() scaled it
        done = batch["next", "done"].sum().item()
        crashed = batch["next", "terminated"].sum().item()
        assert row["tracking_error_m"] == pytest.approx(batch["next", "tracking_error_m"].mean().item())
        assert row["reward_per_step"] == pytest.approx(reward)
        assert row["episode_return_est"] == pytest.approx(reward * trainer.env.params.episode_steps)
        assert row["crash_rate"] == pytest.approx(crashed / max(done, 1))
        assert row["steps_per_s"] > 0
        assert {"loss_objective", "loss_critic", "grad_norm", "lr", "kl_approx"} <= row.keys()
        std = batch["scale"].reshape(-1, 4).mean(0)
        got = [row[f"policy_std_{a}"] for a in ("thrust", "wx", "wy", "wz")]
        assert got == pytest.approx(std.tolist())
    crash_rates = [row["crash_rate"] for row in history]
    assert all(0.0 < rate < 1.0 for rate in crash_rates), crash_rates  # both kinds of episode end


def test_checkpoints_every_n_iterations_and_the_best_of_the_main_stage(tmp_path):
    """``last.pt`` every ``checkpoint_every`` iterations and at the end; ``best.pt`` whenever the
    training error of a batch on the main references beats the best so far (never on the fixed one)."""
    logger = CheckpointSpy(tmp_path)
    trainer = _trainer(
        tmp_path,
        f"train.total_frames={5 * BATCH}",
        f"curriculum.fixed_ref_frames={BATCH}",
        "train.checkpoint_every=2",
        logger=logger,
    )
    history = trainer.train()
    # the row of iteration k is logged before k's checkpoints are written
    assert [last for _, last, _ in logger.seen] == [None, None, 2, 2, 4]
    assert load_checkpoint(tmp_path / "last.pt")["iteration"] == 5
    main = [row for row in history if row["curriculum_ref"] == "main"]
    best_row = min(main, key=lambda row: row["tracking_error_m"])
    best = load_checkpoint(tmp_path / "best.pt")
    assert best["iteration"] == best_row["iteration"] and best["frames"] == best_row["frames"]
    assert best["best_error_m"] == pytest.approx(best_row["tracking_error_m"])
    improved, best_so_far, expect = [], float("inf"), []
    for row in history:
        if row["curriculum_ref"] == "main" and row["tracking_error_m"] < best_so_far:
            best_so_far = row["tracking_error_m"]
            improved.append(row["iteration"])
        expect.append(improved[-1] if improved else None)
    # best.pt as seen by the next row's log: the latest improvement before it
    assert [best_it for _, _, best_it in logger.seen[1:]] == expect[:-1]


def test_a_run_that_never_leaves_the_fixed_stage_still_has_a_best(tmp_path):
    trainer = _trainer(tmp_path, f"train.total_frames={2 * BATCH}", f"curriculum.fixed_ref_frames={10 * BATCH}")
    history = trainer.train()
    assert [row["curriculum_ref"] for row in history] == ["fixed", "fixed"]
    best = load_checkpoint(tmp_path / "best.pt")
    assert best["iteration"] == 2 and best["curriculum_ref"] == "fixed"


@pytest.mark.parametrize("fixed_ref_frames, stages", [(BATCH, ["fixed"] * 3), (0, ["main"] * 3)])
def test_the_whole_run_curriculum_flies_the_fixed_reference_to_the_end_unless_skipped(
    tmp_path, fixed_ref_frames, stages
):
    trainer = _trainer(
        tmp_path,
        f"train.total_frames={3 * BATCH}",
        f"curriculum.fixed_ref_frames={fixed_ref_frames}",
        "curriculum.fixed_ref=whole_run",
    )
    assert [row["curriculum_ref"] for row in trainer.train()] == stages


def test_progress_lines_show_frames_rate_error_and_return(tmp_path, caplog, monkeypatch):
    """With ``train.progress_every_s=0`` every iteration is a line: where the run stands (a resumed
    run from its own frames), this session's rate on the report's clock, the batch's error and
    return estimate; at the end no ETA."""
    from types import SimpleNamespace

    import datt.progress

    ticks = iter([50.0, 51.0, 53.0, 57.0])  # the report's start, then one per iteration
    monkeypatch.setattr(datt.progress, "time", SimpleNamespace(monotonic=lambda: next(ticks)))
    caplog.set_level(logging.INFO)
    trainer = _trainer(
        tmp_path,
        f"train.total_frames={4 * BATCH}",
        "train.progress=true",
        "train.progress_every_s=0",
        "curriculum.fixed_ref_frames=0",
    )
    trainer.frames = BATCH  # a resumed run: the lines start where the run stands
    history = trainer.train()
    lines = _progress_lines(caplog)
    assert len(lines) == 3
    assert lines[0] == (
        f"train: 2,048 / 4,096 frames (50.0 %), err {history[0]['tracking_error_m']:.3f} m, "
        f"ret {history[0]['episode_return_est']:.2f}"
    )
    assert lines[1].startswith("train: 3,072 / 4,096 frames (75.0 %), 512 frames/s, ETA 2 s, err ")  # 1,024 / 2
    assert lines[2] == (
        f"train: 4,096 / 4,096 frames (100.0 %), 341 frames/s, err {history[2]['tracking_error_m']:.3f} m, "
        f"ret {history[2]['episode_return_est']:.2f}"
    )  # 2,048 / 6


def test_no_progress_lines_when_switched_off(tmp_path, caplog):
    caplog.set_level(logging.INFO)
    trainer = _trainer(tmp_path, f"train.total_frames={BATCH}", "train.progress=false")
    trainer.train()
    assert _progress_lines(caplog) == []


def test_a_stop_signal_saves_and_stops_after_the_batch(tmp_path):
    """SIGTERM during iteration 2: the batch is finished, ``last.pt`` written (though
    checkpoint_every is 100), and the run stops with the resume command; the handlers are restored."""

    class SignalAt2(CsvLogger):
        def log(self, metrics, step):
            super().log(metrics, step)
            if metrics["iteration"] == 2:
                os.kill(os.getpid(), signal.SIGTERM)

    handler = signal.getsignal(signal.SIGTERM)
    trainer = _trainer(
        tmp_path, f"train.total_frames={5 * BATCH}", "train.checkpoint_every=100", logger=SignalAt2(tmp_path)
    )
    with pytest.raises(TrainingInterrupted) as info:
        trainer.train()
    assert str(info.value) == (
        f"SIGTERM: checkpoint at 2,048 of 5,120 frames in {tmp_path / 'last.pt'}; resume with resume={tmp_path}"
    )
    assert info.value.signal == "SIGTERM"  # which signal: a scheduler's is handed back to it for a requeue
    assert load_checkpoint(tmp_path / "last.pt")["iteration"] == 2
    assert signal.getsignal(signal.SIGTERM) is handler


def test_budget_scales_the_total_and_the_fixed_stage(tmp_path):
    trainer = _trainer(tmp_path, "budget=0.5", "train.total_frames=4096", "curriculum.fixed_ref_frames=2048")
    assert (trainer.total_frames, trainer.fixed_ref_frames) == (2048, 1024)
    from datt.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^train.total_frames: must be >= 1, got 0$"):
        _trainer(tmp_path, "budget=0.0001", "train.total_frames=4096")


def test_the_env_flies_the_main_family_once_the_fixed_stage_is_over(tmp_path):
    trainer = _trainer(tmp_path, f"train.total_frames={2 * BATCH}", f"curriculum.fixed_ref_frames={BATCH}")
    assert trainer.curriculum_ref == "fixed" and trainer.env.traj is trainer.fixed_traj
    trainer.train()
    assert trainer.curriculum_ref == "main" and trainer.env.traj is trainer.main_traj
    trainer.frames = 0  # e.g. a checkpoint from before the switch: back to the fixed reference
    trainer._update_curriculum_ref()
    assert trainer.curriculum_ref == "fixed" and trainer.env.traj is trainer.fixed_traj
    no_curriculum = _trainer(tmp_path, "curriculum.fixed_ref_frames=0")
    assert no_curriculum.curriculum_ref == "main" and no_curriculum.fixed_traj is None


@pytest.mark.parametrize("stagger", [True, False])
def test_first_episodes_are_staggered_only_when_configured(tmp_path, stagger):
    """With staggering, some drones' first episode ends early (truncated, not crashed); without,
    none ends before ``episode_steps``."""
    trainer = _trainer(tmp_path, f"train.stagger_episodes={str(stagger).lower()}", "env.episode_steps=40")
    env = trainer.env
    td = env.reset()
    ended = torch.zeros(env.n, dtype=torch.bool)
    for _ in range(39):
        td["action"] = env.hover_action
        out = env.step(td)
        ended |= out["next", "truncated"].squeeze(-1)
        td = out["next"]
    assert bool(ended.any()) is stagger


def test_rates_and_wall_time_come_from_the_clock(tmp_path, monkeypatch):
    """A run resumed at 1,024 frames, with a clock that reads 100 at the start, 101 when
    collection starts and 103, 107 after its two batches: steps/s per batch is 1,024 / 2 and
    1,024 / 4, and the training wall time 6 s."""
    from types import SimpleNamespace

    import datt.train.ppo as ppo

    ticks = iter([101.0, 103.0, 107.0])
    monkeypatch.setattr(ppo, "time", SimpleNamespace(perf_counter=lambda: next(ticks)))
    trainer = _trainer(tmp_path, f"train.total_frames={3 * BATCH}", "curriculum.fixed_ref_frames=0")
    trainer.frames = BATCH
    history = trainer.train()
    assert [row["steps_per_s"] for row in history] == [BATCH / 2, BATCH / 4]
    assert trainer.train_wall_s == 6.0 and load_checkpoint(tmp_path / "last.pt")["train_wall_s"] == 6.0


def test_update_sets_the_scheduled_lr_and_averages_its_minibatches(tmp_path):
    """Each update sets every parameter group to the schedule's learning rate (whatever the
    optimiser held), and its loss and gradient-norm figures are the means over its minibatches."""
    trainer = _trainer(
        tmp_path, f"train.total_frames={4 * BATCH}", "algo.lr_schedule=linear", "curriculum.fixed_ref_frames=0",
        cls=SpyTrainer,
    )  # fmt: skip
    trainer.train()  # collects the batches the update below reuses
    trainer.frames = 2 * BATCH  # half way: the linear schedule is between lr and its final value
    for group in trainer.optim.param_groups:
        group["lr"] = 123.0
    seen = []
    loss = trainer.loss

    def recording_loss(td):
        out = loss(td)
        seen.append(out["loss_objective"].item())
        return out

    trainer.loss = recording_loss
    stats = trainer.update(trainer.batches[0].clone())
    assert stats["lr"] == trainer._lr() != trainer.algo.lr
    assert all(group["lr"] == stats["lr"] for group in trainer.optim.param_groups)
    assert len(seen) == trainer.algo.epochs * (BATCH // trainer.algo.minibatch_size)
    assert stats["loss_objective"] == pytest.approx(sum(seen) / len(seen))


@pytest.mark.parametrize("what", ["loss", "gradient"])
def test_divergence_names_what_went_non_finite(tmp_path, what):
    from datt.errors import TrainingDiverged

    trainer = _trainer(tmp_path, f"train.total_frames={BATCH}", "curriculum.fixed_ref_frames=0", cls=SpyTrainer)
    trainer.train()
    loss = trainer.loss
    weight = next(trainer.actor.parameters())

    def poisoned(td):
        out = loss(td)
        if what == "loss":
            out["loss_objective"] = out["loss_objective"] * float("nan")
        else:  # finite value, non-finite gradient: d sqrt(u) / du at u = 0 is infinite
            out["loss_objective"] = out["loss_objective"] + 0.0 * torch.sqrt((weight - weight.detach()).abs().sum())
        return out

    trainer.loss = poisoned
    with pytest.raises(TrainingDiverged) as info:
        trainer.update(trainer.batches[0].clone())
    assert str(info.value).startswith(f"non-finite {what} at iteration 1 (frame {BATCH}); last good checkpoint: ")


def test_a_resumed_main_stage_at_the_fixed_stage_end_stays_main(tmp_path):
    trainer = _trainer(tmp_path, f"train.total_frames={4 * BATCH}", f"curriculum.fixed_ref_frames={BATCH}")
    trainer.curriculum_ref, trainer.frames = "main", BATCH
    trainer._update_curriculum_ref()
    assert trainer.curriculum_ref == "main"
    trainer.frames = BATCH - 1  # below it: back to the fixed reference
    trainer._update_curriculum_ref()
    assert trainer.curriculum_ref == "fixed"


def test_a_main_stage_that_never_beat_its_best_still_writes_one(tmp_path):
    """A resumed main stage whose batches never beat the best error it carried (best.pt lost):
    the end of the run writes best.pt from the last state."""
    trainer = _trainer(tmp_path, f"train.total_frames={BATCH}", "curriculum.fixed_ref_frames=0")
    trainer.best_error = -1.0
    trainer.train()
    assert load_checkpoint(tmp_path / "best.pt")["iteration"] == 1


def test_checkpoints_hold_the_resolved_config(tmp_path):
    trainer = _trainer(tmp_path, f"train.total_frames={BATCH}", "adaptation=l1")
    trainer.train()
    text = load_checkpoint(tmp_path / "last.pt")["config_yaml"]
    assert "${" not in text and "k_thrust: 0.4" in text


def test_the_logger_gets_numbers_only(tmp_path):
    """Each row's curriculum reference (a word) stays in the history; the logger (CSV, wandb) gets the numbers."""

    class KeySpy(CsvLogger):
        def __init__(self, run_dir):
            super().__init__(run_dir)
            self.keys = []

        def log(self, metrics, step):
            self.keys.append(set(metrics))
            super().log(metrics, step)

    logger = KeySpy(tmp_path)
    history = _trainer(tmp_path, f"train.total_frames={2 * BATCH}", logger=logger).train()
    assert logger.keys and all("curriculum_ref" not in keys for keys in logger.keys)
    assert all("tracking_error_m" in keys for keys in logger.keys)
    assert all(row["curriculum_ref"] in ("fixed", "main") for row in history)
