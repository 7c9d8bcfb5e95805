"""Sweeps and tables: a tiny multirun end to end, sweep files compose, failed/incomplete runs."""

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from datt.configuration import available_options
from datt.errors import ConfigError
from datt.eval import tables

REPO = Path(__file__).resolve().parents[1]
TINY = [
    "train.total_frames=4096",
    "algo.num_envs=64",
    "algo.rollout_steps=16",
    "algo.minibatch_size=512",
    "algo.epochs=1",
    "curriculum.fixed_ref_frames=1024",
    "logger=csv",
    "env.compile=false",
    "train.progress=false",
    "eval.plots=false",
    "eval.bank={zigzag:[{traj:zigzag,seed:1000,count:2}]}",
    "eval.conditions.brownian=null",
]


def run(script, *args, cwd):
    return subprocess.run(
        [sys.executable, str(REPO / script), *args], cwd=cwd, capture_output=True, text=True, timeout=600
    )


def test_multirun_then_table_end_to_end(tmp_path):
    out = run("train.py", "-m", "horizon=1,5", *TINY, cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    (sweep,) = list((tmp_path / "outputs" / "multirun" / "train").iterdir())
    out = run("tables.py", "horizon", f"runs={sweep}", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    md = (sweep / "horizon.md").read_text()
    assert "H = 1 " in md and "H = 5 " in md  # both rows
    assert "0.240 ± 0.008" in md  # next to the paper's number
    assert "train.total_frames" not in md  # a fixed override is not a row key
    rows = (sweep / "horizon.csv").read_text().splitlines()
    assert len(rows) == 3
    assert (sweep / "horizon.tex").read_text().startswith("\\begin{tabular}")
    assert (sweep / "horizon_curves.png").stat().st_size > 1000


@pytest.mark.parametrize("name", available_options("sweep"))
def test_every_sweep_composes_from_any_directory(tmp_path, name):
    script = tables.TABLES[name].entry
    out = run(script, f"+sweep={name}", "--cfg", "all", cwd=tmp_path)  # the hydra node and the job's config
    assert out.returncode == 0, out.stderr[-2000:]
    assert "params:" in out.stdout and f"outputs/sweeps/{name}/" in out.stdout
    assert f"sweep_name: {name}" in out.stdout


def test_ablation_sweep_settings_and_budget(tmp_path):
    out = run("train.py", "+sweep=ablation", "budget=0.1", "--cfg", "job", "--resolve", cwd=tmp_path)
    assert "_target_: datt.refs.Zigzag" in out.stdout and "datt.sim.NoDisturbance" in out.stdout
    assert "total_frames: 15000000" in out.stdout and "budget: 0.1" in out.stdout
    assert "brownian: null" in out.stdout


def test_the_paper_setting_ablation_sweep_is_the_ablation_sweep_with_the_authors_options(tmp_path):
    out = run("train.py", "+sweep=ablation_authors", "--cfg", "job", "--resolve", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    from omegaconf import OmegaConf

    cfg = OmegaConf.create(out.stdout)
    assert cfg.sweep_name == "ablation_authors" and cfg.train.total_frames == 15_000_000
    assert cfg.env.obs.timing == "authors" and cfg.env.quad.initial_thrust_mps2 == 0.0
    assert cfg.policy.encoder == "authors" and cfg.curriculum.fixed_ref == "whole_run"
    assert cfg.eval.protocol == "authors" and cfg.eval.conditions.brownian is None
    assert cfg.env.obs.action_history == 0 and cfg.traj._target_ == "datt.refs.Zigzag"


def test_the_paper_ppo_sweep_is_the_paper_setting_sweep_trained_as_the_authors_trained(tmp_path):
    from omegaconf import OmegaConf

    def job_cfg(sweep):
        out = run("train.py", f"+sweep={sweep}", "--cfg", "job", "--resolve", cwd=tmp_path)
        assert out.returncode == 0, out.stderr[-2000:]
        return OmegaConf.create(out.stdout)

    sb3, authors = job_cfg("ablation_sb3"), job_cfg("ablation_authors")
    assert sb3.sweep_name == "ablation_sb3"
    # SB3 1.6's PPO defaults (the authors' learning/train_policy.py sets none of them)
    algo = sb3.algo
    assert (algo.num_envs, algo.rollout_steps, algo.epochs, algo.minibatch_size) == (10, 2048, 10, 64)
    assert (algo.lr, algo.lr_schedule, algo.gamma, algo.lmbda, algo.clip_epsilon) == (3e-4, "constant", 0.99, 0.95, 0.2)
    # their exploration (std 1 in action units, no ceiling) and no crash termination or penalty
    assert list(sb3.policy.init_std) == [0.05, 0.05, 0.05, 0.5] and sb3.policy.max_std == 1.0
    assert min(sb3.env.safety_box_m) >= 1000.0 and sb3.env.reward.crash_penalty == 0.0
    # everything else is the paper-setting sweep's
    for key in ("env.obs", "env.quad", "traj", "curriculum", "eval", "train.total_frames", "policy.encoder"):
        assert OmegaConf.select(sb3, key) == OmegaConf.select(authors, key), key
    rows = set(tables.get_spec("ablation_sb3").row_order)
    assert rows == {"ablation=none", "ablation=no_fixed_ref", "ablation=no_body_frame", "ablation=no_feedback"}


def test_an_authors_protocol_row_counts_every_episode_and_the_title_names_the_protocol(tmp_path):
    def metrics(values, crashed):
        row = {
            "mean_m": sum(values) / len(values),
            "std_m": 0.0,
            "crashes": sum(crashed),
            "episodes": len(values),
            "per_episode_m": values,
            "per_episode_crashed": crashed,
            "protocol": "authors",
        }
        return {"controller": "datt", "conditions": {"clean": {"groups": {"zigzag": row, "smooth": row}}}}

    _job(tmp_path, 0, ["+sweep=ablation_authors", "ablation=none", "seed=0"], metrics([0.04, 0.08], [False, True]))
    _job(tmp_path, 1, ["controller=datt"], metrics([0.05, float("nan")], [False, False]))
    _job(tmp_path, 2, ["+sweep=ablation", "ablation=none", "seed=0"], _train_metrics(0.03))
    jobs = tables.find_jobs([tmp_path])
    spec = tables.get_spec("ablation_authors")
    train_jobs = [jobs[0], jobs[2]]
    rows, _ = tables.collect(spec, train_jobs)
    assert rows["ablation=none@authors"][0].values == [pytest.approx(0.06)]  # the crashed episode counts
    assert rows["ablation=none"][0].values == [0.03]
    rendered = tables.render(spec, rows, train_jobs)
    assert "evaluation protocol authors, project" in rendered["md"]
    labels = [r[0] for r in rendered["rows"]]  # both protocols' rows side by side, each beside the paper's number
    assert labels == [
        "Feedforward horizon 10 (base, used in main experiments) [1 run]",
        "Feedforward horizon 10 (base, used in main experiments) (authors' protocol) [1 run]",
    ]
    assert [r[-1] for r in rendered["rows"]] == ["0.055 ± 0.007"] * 2
    main = tables.get_spec("main")
    rows, _ = tables.collect(main, [jobs[1]])
    zigzag = rows["datt@authors"][1]
    assert zigzag.values == [0.05] and zigzag.failed == 1  # only a non-finite episode fails


def test_launchers_compose_and_build(tmp_path):
    out = run("train.py", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2", "--cfg", "hydra", cwd=tmp_path)
    assert "JoblibLauncher" in out.stdout and "n_jobs: 2" in out.stdout
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    out = run("train.py", "hydra/launcher=submitit_slurm", "--cfg", "hydra", "--resolve", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    launcher_cfg = OmegaConf.create(out.stdout)["hydra"]["launcher"]
    launcher = instantiate(launcher_cfg)
    assert type(launcher).__name__ == "SlurmLauncher"


def _job(root: Path, num: int, overrides: list[str], metrics: dict | None = None, failed: str | None = None) -> Path:
    job = root / str(num)
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "config.yaml").write_text("{}\n")
    (job / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    if metrics is not None:
        (job / "metrics.json").write_text(json.dumps(metrics))
    if failed is not None:
        (job / "failed.json").write_text(json.dumps({"message": failed}))
    return job


def _train_metrics(err, crashed=False):
    row = {"mean_m": err, "std_m": 0.0, "crashes": 2 if crashed else 0, "episodes": 2, "per_episode_m": [err, err]}
    return {"conditions": {"clean": {"groups": {"zigzag": row}}}}


def test_a_run_whose_drones_mostly_diverged_is_the_papers_failed_under_either_protocol(tmp_path):
    def metrics(diverged, protocol):
        row = {"mean_m": 0.8, "std_m": 0.1, "crashes": 0, "diverged": diverged, "episodes": 4, "protocol": protocol}
        row["per_episode_m"] = [0.8] * 4
        return {"conditions": {"clean": {"groups": {"zigzag": row}}}}

    for num, (seed, diverged) in enumerate([(0, 3), (1, 2)]):
        for offset, protocol in ((0, "project"), (10, "authors")):
            overrides = ["+sweep=ablation", "ablation=h1", f"seed={seed}"]
            _job(tmp_path, num + offset, [*overrides, f"eval.protocol={protocol}"], metrics(diverged, protocol))
    spec = tables.get_spec("ablation")
    rows, _ = tables.collect(spec, tables.find_jobs([tmp_path]))
    for key in ("ablation=h1", "ablation=h1@authors"):
        cell = rows[key][0]  # 3 of 4 diverged: failed; 2 of 4 (not most): its error counts
        assert (cell.failed, cell.total, cell.values) == (1, 2, [0.8]), key
        assert cell.text().endswith("(1/2 failed)")


def test_failed_and_incomplete_runs_are_reported(tmp_path):
    _job(tmp_path, 0, ["+sweep=ablation", "ablation=none", "seed=0"], _train_metrics(0.05))
    _job(tmp_path, 1, ["+sweep=ablation", "ablation=none", "seed=1"], _train_metrics(0.07))
    _job(tmp_path, 2, ["+sweep=ablation", "ablation=no_body_frame", "seed=0"], failed="NaN in loss")
    _job(tmp_path, 3, ["+sweep=ablation", "ablation=no_body_frame", "seed=1"], _train_metrics(0.9, crashed=True))
    inc = _job(tmp_path, 4, ["+sweep=ablation", "ablation=h5", "seed=0"])
    (inc / "metrics.csv").write_text("step,frames,tracking_error_m\n1,32768,0.5\n2,65536,0.4\n")
    spec = tables.get_spec("ablation")
    jobs = tables.find_jobs([tmp_path])
    rows, _ = tables.collect(spec, jobs)
    rendered = tables.render(spec, rows, jobs)
    by_label = {r[0].split(" [")[0]: r for r in rendered["rows"]}
    # two seeds 0.05, 0.07: t(0.975, 1) = 12.706 x sample std 0.01414 / sqrt(2) = 0.127 either side
    assert by_label["Feedforward horizon 10 (base, used in main experiments)"][1] == "0.060 ± 0.010 [-0.067, 0.187]"
    assert by_label["No body frame"][1] == "failed"
    assert "incomplete" in rendered["md"] and "65,536 frames" in rendered["md"]
    assert "NaN in loss" in rendered["md"]


def test_main_table_pools_seeds_and_reports_inference(tmp_path):
    def metrics(controller, smooth, zig, ms, crashed=(False, False)):
        g = lambda v, c: {
            "mean_m": 0,
            "std_m": 0,
            "crashes": sum(c),
            "episodes": 2,
            "per_episode_m": v,  # noqa: E731
            "per_episode_crashed": list(c),
        }
        cond = {"groups": {"smooth": g(smooth, (False, False)), "zigzag": g(zig, crashed)}}
        return {"controller": controller, "conditions": {"s0": cond, "s1": cond}, "inference_ms": {"median_ms": ms}}

    _job(tmp_path, 0, ["+sweep=main", "controller=pid"], metrics("pid", [0.1, 0.1], [0.3, 2.0], 0.2, (False, True)))
    _job(tmp_path, 1, ["+sweep=main", "controller=datt"], metrics("datt", [0.03, 0.05], [0.06, 0.08], 0.1))
    spec = tables.get_spec("main")
    jobs = tables.find_jobs([tmp_path])
    rendered = tables.render(spec, tables.collect(spec, jobs)[0], jobs)
    rows = {r[0]: r for r in rendered["rows"]}
    assert rows["Nonlinear tracking control (PID)"][2] == "0.300 ± 0.000 [0.300, 0.300] (2/4 failed)"
    # 0.03, 0.05, 0.03, 0.05: t(0.975, 3) = 3.182 x sample std 0.01155 / sqrt(4) = 0.018 either side
    assert rows["DATT (d̂ = 0)"][1] == "0.040 ± 0.010 [0.022, 0.058]" and rows["DATT (d̂ = 0)"][3] == "0.10"
    assert rows["DATT (d̂ = 0)"][5] == "0.089 ± 0.026"  # paper column
    # side-by-side plot from the traces eval.py saves
    import torch

    for num in (0, 1):
        pos = torch.zeros(3, 11, 3)
        torch.save(
            {
                "pos_m": pos,
                "ref_m": pos + 0.1 * num,
                "err_m": torch.full((3, 10), 0.1 * num),
                "crashed_at": torch.tensor([10, 10, 10]),
                "names": ["smooth", "zigzag"],
                "counts": [2, 1],
            },
            tmp_path / str(num) / "trace_seed0.pt",
        )
    png = tables.plot_side_by_side_from_jobs(tables.find_jobs([tmp_path]), "zigzag", 0, tmp_path / "sbs.png")
    assert png is not None and png.stat().st_size > 1000


def test_unknown_table_and_missing_sweep_are_one_line(tmp_path):
    out = run("tables.py", "nope", cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0
    allowed = "ablation, ablation_authors, ablation_sb3, horizon, main, rma, wind"
    assert f"table: unknown table 'nope'; allowed: {allowed}" in out.stderr
    out = run("tables.py", "ablation", cwd=tmp_path)
    assert out.returncode == 2 and "python train.py +sweep=ablation" in out.stderr


def test_the_documented_sweep_override_form_parses_and_the_bare_form_says_how_to_quote(tmp_path):
    documented = "sweep_overrides=['budget=0.2','eval.seeds=[0]']"  # conf/tables.yaml, docs/results.md
    out = run("tables.py", "main", "run=true", documented, "--cfg", "job", cwd=tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "- budget=0.2\n- eval.seeds=[0]" in out.stdout
    out = run("tables.py", "main", "run=true", "sweep_overrides=[budget=0.2]", cwd=tmp_path)
    assert out.returncode == 2 and out.stderr.strip().count("\n") == 0
    assert "quote each item of a list that holds overrides" in out.stderr


@pytest.mark.parametrize("table, ran_by", [("main", "train"), ("ablation", "eval"), ("rma", "train")])
def test_a_sweep_of_another_entry_point_is_refused_in_one_line(tmp_path, table, ran_by):
    """Before: ``tables.py main runs=<a training sweep>`` printed a table with a ``?`` row, exit 0."""
    job = _job(tmp_path, 0, ["seed=0"], _train_metrics(0.05))
    (job / ".hydra" / "hydra.yaml").write_text(f"hydra:\n  job:\n    config_name: {ran_by}\n")
    spec = tables.get_spec(table)
    with pytest.raises(ConfigError) as info:
        tables.check_jobs_are_the_tables(spec, tables.find_jobs([tmp_path]))
    assert str(info.value) == (
        f"runs: {job} is a {ran_by}.py job; table {table} is made from {spec.entry} jobs "
        f"(python {spec.entry} +sweep={table}, or tables.py {table} run=true)"
    )
    (job / ".hydra" / "hydra.yaml").write_text(f"hydra:\n  job:\n    config_name: {spec.entry[:-3]}\n")
    tables.check_jobs_are_the_tables(spec, tables.find_jobs([tmp_path]))  # its own: accepted


@pytest.mark.parametrize(
    "values, low, high",
    [
        # mean ± t(0.975, n - 1) * sample std / sqrt(n), t from the printed tables: 12.706 (1 df), 2.776 (4 df)
        ([1.0, 3.0], 2.0 - 12.706 * math.sqrt(2.0) / math.sqrt(2.0), 2.0 + 12.706),
        ([1.0, 2.0, 3.0, 4.0, 5.0], 3.0 - 2.776 * math.sqrt(2.5) / math.sqrt(5.0), 3.0 + 2.776 * math.sqrt(0.5)),
    ],
)
def test_the_interval_is_students_t_interval_of_the_mean(values, low, high):
    cell = tables.Cell()
    for v in values:
        cell.add(v)
    got = cell.interval95()
    assert got == pytest.approx((low, high), abs=2e-3)


def test_one_value_has_no_interval_and_failed_runs_are_not_in_it():
    cell = tables.Cell()
    cell.add(0.05)
    cell.add(float("nan"))  # a failed run
    assert cell.interval95() is None and cell.text() == "0.050 (1/2 failed)"
