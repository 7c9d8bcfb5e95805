"""``env.device=cuda`` moves the env, the policy, PPO, the end-of-run evaluation, eval.py and MPPI:
a tiny run on CUDA where the machine has one (skipped with the reason otherwise)."""

import json

import pytest
import torch

from .test_faults import run_cli
from .train.test_training import TINY

pytestmark = [
    pytest.mark.gpu,
    pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine"),
]
SMALL_BANK = "eval.bank={zigzag:[{traj:zigzag,seed:1000,count:2}]}"


def test_a_tiny_training_run_and_its_evaluation_run_on_cuda(tmp_path, monkeypatch, capsys):
    run = tmp_path / "run"
    args = [*TINY, "env.device=cuda", "train.total_frames=4096", "eval.plots=false", SMALL_BANK, f"hydra.run.dir={run}"]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["frames"] >= 4096 and metrics["conditions"]
    checkpoint = torch.load(run / "last.pt", map_location="cpu", weights_only=True)
    assert checkpoint["frames"] == metrics["frames"]

    for controller in ("datt", "mppi"):
        out = tmp_path / controller
        args = [
            f"controller={controller}",
            f"checkpoint={run / 'last.pt'}",
            "env.device=cuda",
            "eval.plots=false",
            "eval.timing.steps=0",
            SMALL_BANK,
            f"hydra.run.dir={out}",
        ]
        code, lines, _ = run_cli("eval", args, tmp_path, monkeypatch, capsys)
        assert code == 0, (controller, lines)
        assert json.loads((out / "metrics.json").read_text())["conditions"]
