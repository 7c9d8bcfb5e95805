"""The wandb run holds what the tables show: the end-of-run evaluation as summary keys
``eval/<condition>/<group>/<stat>``, the learning curve and tracking plots as images, the table as
a wandb Table; a resumed run continues the same wandb run. Read back from the offline run's
record file (no login, no network)."""

from __future__ import annotations

import json

import pytest

from ..test_faults import run_cli
from .test_training import TINY
from .wandb_record import summary_and_history

WANDB_TINY = ["logger=wandb", *[o for o in TINY if not o.startswith("logger=")], "curriculum.fixed_ref_steps=0"]


def test_offline_run_record_holds_the_evaluation_plots_and_table_and_resume_continues_it(tmp_path, monkeypatch, capsys):
    pytest.importorskip("wandb")
    run = tmp_path / "r"
    args = [*WANDB_TINY, "train.total_steps=1024", f"hydra.run.dir={run}"]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    metrics = json.loads((run / "metrics.json").read_text())
    summary, history, ids = summary_and_history(run)
    for cond, result in metrics["conditions"].items():
        for group, stats in result["groups"].items():
            assert summary[f"eval/{cond}/{group}/mean_m"] == pytest.approx(stats["mean_m"])
            assert summary[f"eval/{cond}/{group}/crashes"] == stats["crashes"]
    assert summary["frames"] == metrics["frames"]
    assert {"learning_curve/_type", "tracks_clean/_type", "eval/table/_type", "tracking_error_m"} <= history
    assert len(set(ids)) == 1

    code, lines, _ = run_cli(
        "train",
        ["logger=wandb", "train.progress=false", f"resume={run}", "train.total_steps=2048"],
        tmp_path,
        monkeypatch,
        capsys,
    )
    assert code == 0, lines
    summary, _, resumed_ids = summary_and_history(run)
    assert set(resumed_ids) == set(ids)  # the same wandb run, carried on
    assert summary["frames"] == json.loads((run / "metrics.json").read_text())["frames"] >= 2048
