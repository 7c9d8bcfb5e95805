"""A schedule in stages from one command (``train.stages``, ``experiment=shipped_iid``): what each
stage trains with, that stage k starts from stage k-1's weights, resume, and every bad schedule's
error."""

import json

import pytest
import torch
from omegaconf import OmegaConf

from datt.checkpoint import load_checkpoint
from datt.errors import ConfigError
from datt.tasks.resume import resume_dir
from datt.tasks.stages import stage_config, stage_plan
from datt.tasks.train import run_train

from .test_training import tiny_cfg

ZIGZAG_ONLY = {"zigzag": 1, "poly": 0, "chained_poly": 0}
TWO_STAGES = [
    {"name": "a", "frames": 1024, "set": {"algo.lr": 2.0e-3}},
    {"name": "b", "frames": 1024, "set": {"env.reward.vel": 0.0, "traj.weights": ZIGZAG_ONLY}},
]


def one(values):
    """A single 2048-step stage that sets ``values``."""
    return {"name": "a", "frames": 2048, "set": values}


def staged_cfg(stages=TWO_STAGES, total=2048, *extra):
    cfg = tiny_cfg(
        f"train.total_frames={total}",
        "curriculum.fixed_ref_frames=512",
        "train.eval_at_end=false",
        "eval.plots=false",
        *extra,
    )
    OmegaConf.update(cfg, "train.stages", stages, merge=False)
    return cfg


def test_shipped_experiment_is_the_five_stage_schedule():
    from datt.configuration import compose

    cfg = compose("train", ["experiment=shipped_iid"])
    plan = stage_plan(cfg)
    assert [name for name, _, _ in plan] == [
        "stage1_mix",
        "stage2_zigzag5",
        "stage3_zigzag6",
        "stage4_wide",
        "stage5_no_vel",
    ]
    assert sum(frames for _, frames, _ in plan) == 64_000_000
    first, last = stage_config(cfg, 0, plan, None), stage_config(cfg, 4, plan, "p4/last.pt")
    assert first.curriculum.fixed_ref_frames == 2_500_000 and first.train.init_from is None
    assert dict(first.traj.weights) == {"zigzag": 2, "poly": 1, "chained_poly": 1}
    assert (first.algo.lr, first.algo.lr_final_frac, first.algo.num_envs) == (1e-3, 0.1, 1024)
    assert last.curriculum.fixed_ref_frames == 0 and last.train.init_from == "p4/last.pt"
    assert (last.algo.lr, last.algo.num_envs, last.algo.minibatch_size, last.env.reward.vel) == (1e-4, 2048, 4096, 0.0)
    assert dict(last.traj.weights) == {"zigzag": 6, "poly": 1, "chained_poly": 1}
    # the checkpoint's zigzags: the iid ones (the training default when it was trained)
    for family in (first.traj.families.zigzag, first.curriculum.fixed.family):
        assert (family.waypoints, family.seg_min_s, family.seg_max_s, family.range_m) == ("iid", 0.5, 1.5, 1.0)
    assert last.train.stages is None and last.train.total_frames == 10_000_000
    # the evaluation runs once, after the last stage
    assert not first.train.eval_at_end and last.train.eval_at_end


def test_stages_chain_weights_and_the_run_is_the_last_stage(tmp_path):
    metrics = run_train(staged_cfg(), run_dir=tmp_path)
    one, two = tmp_path / "stage1_a", tmp_path / "stage2_b"
    cfg_one, cfg_two = OmegaConf.load(one / "config.yaml"), OmegaConf.load(two / "config.yaml")
    assert cfg_one.algo.lr == 2e-3 and cfg_one.train.init_from is None and cfg_one.curriculum.fixed_ref_frames == 512
    assert cfg_one.env.reward.vel == 0.1
    assert cfg_two.algo.lr == 1e-3 and cfg_two.env.reward.vel == 0.0 and cfg_two.curriculum.fixed_ref_frames == 0
    assert cfg_two.train.init_from == str(one / "last.pt")
    assert dict(cfg_two.traj.weights) == {"zigzag": 1, "poly": 0, "chained_poly": 0}
    run_ckpt, last_ckpt = load_checkpoint(tmp_path / "last.pt"), load_checkpoint(two / "last.pt")
    assert all(torch.equal(run_ckpt["actor"][k], v) for k, v in last_ckpt["actor"].items())
    assert metrics["frames"] == 2048 and [p["stage"] for p in metrics["stages"]] == ["stage1_a", "stage2_b"]
    assert json.loads((tmp_path / "metrics.json").read_text())["frames"] == 2048


def test_stage_two_starts_from_stage_one(tmp_path, monkeypatch):
    """The weights stage 2 starts from are stage 1's last ones (not a fresh policy)."""
    from datt.train import ppo

    loaded = []
    original = ppo.Trainer.init_weights

    def spy(self, path):
        original(self, path)
        loaded.append((path, {k: v.clone() for k, v in self.actor.state_dict().items()}))

    monkeypatch.setattr(ppo.Trainer, "init_weights", spy)
    run_train(staged_cfg(), run_dir=tmp_path)
    assert len(loaded) == 1 and loaded[0][0] == str(tmp_path / "stage1_a" / "last.pt")
    one = load_checkpoint(tmp_path / "stage1_a" / "last.pt")["actor"]
    assert all(torch.equal(loaded[0][1][k], v) for k, v in one.items())


def test_the_first_stage_starts_from_the_runs_init_from(tmp_path, monkeypatch):
    """A schedule can fine-tune a checkpoint (experiment=deploy): stage 1 loads ``train.init_from``,
    stage 2 stage 1's weights."""
    from datt.train import ppo

    run_train(staged_cfg(), run_dir=tmp_path / "base")
    start = tmp_path / "base" / "last.pt"
    loaded = []
    original = ppo.Trainer.init_weights

    def spy(self, path):
        original(self, path)
        loaded.append(path)

    monkeypatch.setattr(ppo.Trainer, "init_weights", spy)
    run_train(staged_cfg(TWO_STAGES, 2048, f"train.init_from={start}"), run_dir=tmp_path / "tuned")
    assert loaded == [str(start), str(tmp_path / "tuned" / "stage1_a" / "last.pt")]
    assert OmegaConf.load(tmp_path / "tuned" / "stage1_a" / "config.yaml").train.init_from == str(start)


def test_resume_keeps_finished_stages_and_runs_the_rest(tmp_path):
    run_train(staged_cfg(), run_dir=tmp_path)
    one = tmp_path / "stage1_a"
    kept = {p.name: p.stat().st_mtime_ns for p in one.iterdir()}
    for name in ("metrics.json", "last.pt"):
        (tmp_path / name).unlink()
    for p in (tmp_path / "stage2_b").iterdir():
        if p.is_file():
            p.unlink()
    # a stage dir (what resume=true finds newest) stands for its whole run
    assert resume_dir(str(one)) == tmp_path and resume_dir(str(tmp_path)) == tmp_path
    metrics = run_train(staged_cfg(TWO_STAGES, 2048, f"resume={tmp_path}"))
    assert {p.name: p.stat().st_mtime_ns for p in one.iterdir()} == kept
    assert (tmp_path / "stage2_b" / "last.pt").is_file() and metrics["frames"] == 2048
    # finished: nothing is written
    before = (tmp_path / "last.pt").stat().st_mtime_ns
    run_train(staged_cfg(TWO_STAGES, 2048, f"resume={tmp_path}"))
    assert (tmp_path / "last.pt").stat().st_mtime_ns == before


def test_a_run_begun_when_stages_were_named_phases_resumes_without_retraining(tmp_path):
    """Its config says ``train.phases`` and its dirs ``phase<k>_<name>``: the finished stage is
    kept (moved to its ``stage<k>_`` name), the unfinished one trains."""
    run_train(staged_cfg(), run_dir=tmp_path)
    for name in ("metrics.json", "last.pt"):
        (tmp_path / name).unlink()
    for p in (tmp_path / "stage2_b").iterdir():
        if p.is_file():
            p.unlink()
    kept = {p.name: p.stat().st_mtime_ns for p in (tmp_path / "stage1_a").iterdir()}
    for k, name in ((1, "a"), (2, "b")):
        (tmp_path / f"stage{k}_{name}").rename(tmp_path / f"phase{k}_{name}")
    saved = tmp_path / "config.yaml"
    saved.write_text(saved.read_text().replace("  stages:", "  phases:"))
    assert "phases" in OmegaConf.load(saved).train and "stages" not in OmegaConf.load(saved).train
    assert resume_dir(str(tmp_path)) == tmp_path
    metrics = run_train(staged_cfg(TWO_STAGES, 2048, f"resume={tmp_path}"))
    assert {p.name: p.stat().st_mtime_ns for p in (tmp_path / "stage1_a").iterdir()} == kept
    assert [s["stage"] for s in metrics["stages"]] == ["stage1_a", "stage2_b"] and metrics["frames"] == 2048
    assert not list(tmp_path.glob("phase*")) and "phases" not in OmegaConf.load(saved).train


@pytest.mark.parametrize(
    "stages, total, message",
    [
        (TWO_STAGES, 4096, "train.stages: the stages add up to 2,048 frames but train.total_frames is 4,096; "),
        ([one({"algo.lrr": 1.0})], 2048, "train.stages[0].set: unknown config key 'algo.lrr'"),
        ([one({"seed": 3})], 2048, "train.stages[0].set: seed cannot change between stages"),
        ([one({"train.init_from": "x.pt"})], 2048, "train.stages[0].set: train.init_from cannot"),
        ([{"name": "a b", "frames": 2048}], 2048, "train.stages[0].name: 'a b' must be unique"),
        ([{"name": "a", "frames": 1024}, {"name": "a", "frames": 1024}], 2048, "train.stages[1].name: 'a' must be"),
        ([{"name": "a", "frames": 0}], 2048, "train.stages[0].frames: must be an integer >= 1, got 0"),
        ([{"name": "a", "frames": 2048, "lr": 1}], 2048, "train.stages[0]: must be a mapping with keys name, frames"),
        ([], 2048, "train.stages: empty list; use null"),
    ],
)
def test_bad_schedules_are_refused_before_anything_is_written(tmp_path, stages, total, message):
    with pytest.raises(ConfigError) as info:
        run_train(staged_cfg(stages, total), run_dir=tmp_path / "run")
    assert str(info.value).startswith(message)
    assert not (tmp_path / "run").exists()


def test_a_bad_schedule_on_the_command_line_is_one_line(tmp_path, monkeypatch, capsys):
    from ..test_faults import TINY, one_line, run_cli

    args = [*TINY, "experiment=shipped_iid", "train.total_frames=1000"]
    result = run_cli("train", args, tmp_path, monkeypatch, capsys)
    one_line(result, "error: train.stages: the stages add up to 64,000,000 frames but train.total_frames is 1,000; ")
    assert not (tmp_path / "outputs").exists() or not list((tmp_path / "outputs").rglob("*.pt"))


def test_what_a_stage_sets_wins_over_what_the_plan_sets_for_it():
    """The plan sets each stage's frames, its parent's weights, the fixed reference's frames (0 after
    the first) and whether it evaluates at the end; a stage that sets one of the last two itself
    keeps its own value (the order shows only when both set the same key)."""
    stages = [
        {"name": "a", "frames": 1024, "set": {"train.eval_at_end": True}},
        {"name": "b", "frames": 1024, "set": {"curriculum.fixed_ref_frames": 256}},
        {"name": "c", "frames": 1024, "set": {"train.eval_at_end": False}},
    ]
    cfg = staged_cfg(stages, 3072)
    OmegaConf.update(cfg, "train.eval_at_end", True)
    plan = stage_plan(cfg)
    a, b, c = (stage_config(cfg, k, plan, f"p{k}/last.pt") for k in range(3))
    assert a.train.eval_at_end is True  # the plan says only the last evaluates; the stage says otherwise
    assert b.curriculum.fixed_ref_frames == 256  # the plan would reset it to 0 after the first stage
    assert c.train.eval_at_end is False  # the last stage, which the plan would evaluate
    assert (a.train.total_frames, b.train.total_frames) == (1024, 1024)
    assert b.train.init_from == "p1/last.pt" and a.train.init_from is None
    plain = stage_config(staged_cfg(TWO_STAGES, 2048), 1, stage_plan(staged_cfg(TWO_STAGES, 2048)), "x")
    assert plain.curriculum.fixed_ref_frames == 0  # a stage that does not set it: the plan's 0
