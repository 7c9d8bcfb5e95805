"""The wandb run holds what a wandb user expects: training metrics in sections (``train/``,
``losses/``, ``time/``) with summaries defined (the best error, the last lr), the end-of-run
evaluation as summary keys ``eval/<condition>/<group>/<stat>`` named as eval.py names the same
condition, the plots as captioned images, the evaluation as a numeric Table, the checkpoints as a
versioned ``model`` artifact; a resumed run continues the same wandb run; tables.py logs a
numeric Table. Read back from the offline run's record file (no login, no network)."""

from __future__ import annotations

import csv
import json
import shutil

import pytest

from ..test_faults import run_cli
from .test_training import TINY
from .wandb_record import (
    artifacts,
    history_rows,
    image_captions,
    logged_table,
    metric_summaries,
    run_info,
    summary_and_history,
)

WANDB_TINY = ["logger=wandb", *[o for o in TINY if not o.startswith("logger=")], "curriculum.fixed_ref_frames=0"]


def test_offline_run_record_holds_the_evaluation_plots_and_table_and_resume_continues_it(tmp_path, monkeypatch, capsys):
    pytest.importorskip("wandb")
    run = tmp_path / "r"
    args = [*WANDB_TINY, "train.total_frames=1024", f"hydra.run.dir={run}"]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    metrics = json.loads((run / "metrics.json").read_text())
    summary, history, ids = summary_and_history(run)
    # train.yaml's end-of-run conditions: clean = no disturbance, no adaptation; brownian = privileged d
    for cond, key in (("clean", "none-none"), ("brownian", "brownian-privileged")):
        for group, stats in metrics["conditions"][cond]["groups"].items():
            mean = stats["mean_m"]
            assert summary[f"eval/{key}/{group}/mean_m"] == (pytest.approx(mean) if mean is not None else None)
            assert summary[f"eval/{key}/{group}/crashes"] == stats["crashes"]
    assert summary["time/frames"] == metrics["frames"]
    assert {"learning_curve/_type", "tracks_clean/_type", "eval/table/_type"} <= history
    sections = {
        "train/tracking_error_m", "train/lr", "train/policy_std_thrust", "losses/loss_critic", "losses/kl_approx",
        "time/steps_per_s",
    }  # fmt: skip
    assert sections <= history and "tracking_error_m" not in history
    assert len(set(ids)) == 1
    with open(run / "metrics.csv") as f:
        csv_rows = list(csv.DictReader(f))
    logged = [r for r in history_rows(run) if "train/tracking_error_m" in r]
    assert [r["_step"] for r in logged] == [int(r["step"]) for r in csv_rows]  # wandb's step is the frame count
    errors = [float(r["tracking_error_m"]) for r in csv_rows]
    assert [r["train/tracking_error_m"] for r in logged] == pytest.approx(errors)
    kept = metric_summaries(run)
    assert kept["train/tracking_error_m"] == "min" and kept["train/lr"] == "last"
    assert summary["train/tracking_error_m"]["min"] == pytest.approx(min(errors))  # the best, not the last
    (artifact,) = [a for a in artifacts(run) if a["type"] == "model"]  # (wandb stores a Table as one too)
    assert artifact["name"] == f"policy-{ids[0]}" and artifact["type"] == "model" and artifact["aliases"] == ["latest"]
    assert {"best.pt", "last.pt", "config.yaml", "metrics.json"} <= set(artifact["files"])
    assert artifact["metadata"]["time/frames"] == metrics["frames"]
    assert image_captions(run)["learning_curve"].startswith("training: the batch's mean tracking error")
    table = logged_table(run, "eval/table")
    assert table["columns"] == ["condition", "group", "mean_m", "std_m", "crashes", "episodes"]
    assert {row[0] for row in table["data"]} == {"none-none", "brownian-privileged"}

    code, lines, _ = run_cli(
        "train",
        ["logger=wandb", "train.progress=false", f"resume={run}", "train.total_frames=2048"],
        tmp_path,
        monkeypatch,
        capsys,
    )
    assert code == 0, lines
    summary, _, resumed_ids = summary_and_history(run)
    assert set(resumed_ids) == set(ids)  # the same wandb run, carried on
    assert summary["time/frames"] == json.loads((run / "metrics.json").read_text())["frames"] >= 2048


def _as_sweep_job(tmp_path, checkpoint):
    """``checkpoint`` placed as job 3 of an ablation sweep (the layout train.py -m writes)."""
    sweep = tmp_path / "2026-01-01_00-00-00_abcd"
    job = sweep / "3"
    (job / ".hydra").mkdir(parents=True)
    (sweep / "multirun.yaml").write_text("{}\n")
    (job / "config.yaml").write_text("sweep_name: ablation\n")
    (job / ".hydra" / "config.yaml").write_text("sweep_name: ablation\n")
    shutil.copy(checkpoint, job / "last.pt")
    return job


def test_eval_py_logs_its_evaluation_to_wandb_beside_the_training_run(
    tmp_path, monkeypatch, capsys, tiny_policy_checkpoint
):
    pytest.importorskip("wandb")
    job = _as_sweep_job(tmp_path, tiny_policy_checkpoint)
    out = tmp_path / "e"
    args = [
        f"checkpoint={job / 'last.pt'}",
        "logger=wandb",
        "eval.seeds=[0,1]",
        "eval.timing.steps=20",
        "eval.timing.compile=false",
        "eval.bank={zigzag:[{traj:zigzag,seed:1000,count:2}]}",
        "logger.tags=[mine]",
        "logger.project=myproject",
        f"hydra.run.dir={out}",
    ]
    code, lines, _ = run_cli("eval", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    metrics = json.loads((out / "metrics.json").read_text())
    summary, history, _ = summary_and_history(out)
    (run,) = run_info(out)
    assert run["group"] == "ablation/2026-01-01_00-00-00_abcd" and run["job_type"] == "eval"
    assert run["project"] == "myproject" and run["name"] == "eval-e" and run["tags"] == ["mine"]
    assert list(out.glob("wandb/offline-run-*"))  # offline, as logger=wandb's mode says
    pngs = sorted(p.stem for p in out.glob("*.png"))
    assert pngs and all(f"{stem}/_type" in history for stem in pngs)  # the plots as images
    assert run["config"]["train_run_id"] == "2026-01-01_00-00-00_abcd-3"  # train.py's id for that job
    for seed, (_, result) in enumerate(sorted(metrics["conditions"].items())):
        for group, stats in result["groups"].items():
            key = f"eval/none-none-seed{seed}/{group}"
            assert summary[f"{key}/crashes"] == stats["crashes"] and summary[f"{key}/episodes"] == stats["episodes"]
            mean = stats["mean_m"]  # every episode of a barely trained policy may crash: no mean (null)
            assert summary[f"{key}/mean_m"] == (pytest.approx(mean) if mean is not None and mean == mean else None)
    assert summary["inference/median_ms"] == pytest.approx(metrics["inference_ms"]["median_ms"])
    assert "eval/table/_type" in history


def test_eval_py_names_a_condition_as_the_training_run_does(tmp_path, monkeypatch, capsys, tiny_policy_checkpoint):
    """One seed, no disturbance, no adaptation: eval.py's keys are the training run's clean ones."""
    pytest.importorskip("wandb")
    out = tmp_path / "e"
    args = [
        f"checkpoint={tiny_policy_checkpoint}",
        "logger=wandb",
        "eval.timing.steps=0",
        "eval.plots=false",
        "eval.bank={zigzag:[{traj:zigzag,seed:1000,count:2}]}",
        f"hydra.run.dir={out}",
    ]
    code, lines, _ = run_cli("eval", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    summary, _, _ = summary_and_history(out)
    conditions = {k.split("/")[1] for k in summary if k.startswith("eval/") and not k.startswith("eval/table")}
    assert conditions == {"none-none"}  # train.py's key of its clean condition (no seed suffix for one seed)
    assert "eval/none-none/zigzag/mean_m" in summary


def test_tables_py_logs_the_table_to_its_sweep_s_group(tmp_path, monkeypatch, capsys):
    pytest.importorskip("wandb")
    sweep = tmp_path / "2026-01-01_00-00-00_abcd"
    for num, h in enumerate([1, 5]):
        job = sweep / str(num)
        (job / ".hydra").mkdir(parents=True)
        (job / ".hydra" / "config.yaml").write_text("sweep_name: horizon\n")
        (job / ".hydra" / "overrides.yaml").write_text(f"- horizon={h}\n- seed=0\n")
        cond = {"groups": {"zigzag": {"mean_m": 0.05 + h / 1000, "std_m": 0.01, "crashes": 0, "episodes": 2}}}
        (job / "metrics.json").write_text(json.dumps({"frames": 10, "conditions": {"clean": cond}}))
    (sweep / "multirun.yaml").write_text("{}\n")
    code, lines, _ = run_cli(
        "tables", ["horizon", f"runs={sweep}", "logger=wandb", "plots=false"], tmp_path, monkeypatch, capsys
    )
    assert code == 0, lines
    summary, history, _ = summary_and_history(sweep)
    (run,) = run_info(sweep)
    assert run["group"] == "horizon/2026-01-01_00-00-00_abcd" and run["job_type"] == "table"
    assert summary["jobs"] == 2 and "table/horizon/_type" in history
    table = logged_table(sweep, "table/horizon")  # numbers, not "0.051 ± 0.010" strings
    columns = ["row", "column", "mean", "std", "ci95_low", "ci95_high", "values", "failed", "total", "paper"]
    assert table["columns"] == columns
    means = {row[0]: row[2] for row in table["data"]}
    assert means == {"H = 1 (0.06 s)": pytest.approx(0.051), "H = 5 (0.30 s)": pytest.approx(0.055)}
    assert all(row[4] is None and row[5] is None for row in table["data"])  # one seed per row: no interval
    paper = {row[0]: row[9] for row in table["data"]}
    assert all(value is None or isinstance(value, float) for value in paper.values())
    assert summary["table/H = 5 (0.30 s)/zigzag error (m)"] == pytest.approx(0.055)
    quiet = tmp_path / "quiet"
    args = ["horizon", f"runs={sweep}", "logger=wandb", "logger.mode=disabled", f"out_dir={quiet}", "plots=false"]
    code, lines, _ = run_cli("tables", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    assert (quiet / "horizon.md").is_file() and not list(quiet.glob("wandb/*run-*"))  # disabled: no wandb run
