"""A checkpoint records the runs its weights descend from (``lineage``): through
``train.init_from``, through the stages of a schedule, and across a resume; ``tools/lineage.py``
reads the chain back as the config changes of each step."""

import subprocess
import sys

from omegaconf import OmegaConf

from datt.checkpoint import load_checkpoint
from datt.tasks.train import run_train
from tools import lineage

from .test_stages import TWO_STAGES
from .test_training import ROOT, tiny_cfg

BATCH = 64 * 16  # TINY: 64 envs x 16 steps


def small(*extra):
    return tiny_cfg(
        f"train.total_frames={2 * BATCH}",
        "curriculum.fixed_ref_frames=0",
        "train.eval_at_end=false",
        "eval.plots=false",
        *extra,
    )


def test_a_fresh_run_has_no_lineage(tmp_path):
    run_train(small(), run_dir=tmp_path)
    assert load_checkpoint(tmp_path / "last.pt")["lineage"] == []


def test_a_chain_of_fine_tunes_and_stages_records_every_parent(tmp_path):
    first, second, third = tmp_path / "first", tmp_path / "second", tmp_path / "third"
    run_train(small("seed=3"), run_dir=first)
    run_train(small("seed=3", "algo.lr=2.0e-4", f"train.init_from={first / 'last.pt'}"), run_dir=second)
    cfg = small("seed=3", f"train.init_from={second / 'last.pt'}")
    OmegaConf.update(cfg, "train.stages", TWO_STAGES, merge=False)
    run_train(cfg, run_dir=third)

    chain = load_checkpoint(third / "last.pt")["lineage"]
    assert [entry["checkpoint"] for entry in chain] == [
        str(first / "last.pt"),
        str(second / "last.pt"),
        str(third / "stage1_a" / "last.pt"),
    ]
    assert [entry["frames"] for entry in chain] == [2 * BATCH, 2 * BATCH, BATCH]
    configs = [OmegaConf.create(entry["config_yaml"]) for entry in chain]
    assert [c.algo.lr for c in configs] == [1e-3, 2e-4, 2e-3]  # default, the fine-tune's, stage a's
    assert configs[1].train.init_from == str(first / "last.pt")
    # each entry is the parent's own config, byte for byte
    assert chain[0]["config_yaml"] == load_checkpoint(first / "last.pt")["config_yaml"]

    steps = lineage.steps(third / "last.pt")
    assert [frames for _, frames, _ in steps] == [2 * BATCH, 2 * BATCH, BATCH, BATCH]
    assert lineage.config_changes(steps[0][2], steps[1][2]) == ["algo.lr: 0.001 -> 0.0002"]
    assert "env.reward.vel: 0.1 -> 0.0" in lineage.config_changes(steps[2][2], steps[3][2])


def test_a_resumed_fine_tune_keeps_its_lineage(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    run_train(small(), run_dir=first)
    run_train(small(f"train.init_from={first / 'last.pt'}"), run_dir=second)
    before = load_checkpoint(second / "last.pt")["lineage"]
    resumed = small(f"train.init_from={first / 'last.pt'}", f"train.total_frames={3 * BATCH}", f"resume={second}")
    run_train(resumed, run_dir=second)
    after = load_checkpoint(second / "last.pt")
    assert after["frames"] == 3 * BATCH and after["lineage"] == before and len(before) == 1


def test_the_lineage_tool_prints_each_step(tmp_path):
    first, second = tmp_path / "first", tmp_path / "second"
    run_train(small(), run_dir=first)
    run_train(small("algo.epochs=3", f"train.init_from={first / 'last.pt'}"), run_dir=second)
    out = subprocess.run(
        [sys.executable, str(ROOT / "tools" / "lineage.py"), str(second / "last.pt")],
        capture_output=True,
        text=True,
        check=True,
        cwd=tmp_path,
    ).stdout
    lines = out.splitlines()
    assert lines[0].startswith(f"1. {first / 'last.pt'}: 2,048 frames (chain total 2,048), seed 0")
    step_two = lines.index(f"2. {second / 'last.pt'}: 2,048 frames (chain total 4,096), seed 0")
    assert lines[step_two + 1 :] == ["     algo.epochs: 2 -> 3"]
