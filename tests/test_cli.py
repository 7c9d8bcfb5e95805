"""End-to-end entry points: eval.py on a checkpoint, the datt console script, error lines."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def run(args, cwd, timeout=300):
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, cwd=cwd, timeout=timeout)


def test_eval_py_on_checkpoint_writes_metrics(tmp_path, tiny_policy_checkpoint):
    proc = run(
        [
            str(ROOT / "eval.py"),
            f"checkpoint={tiny_policy_checkpoint}",
            "disturbance=brownian",
            "adaptation=l1",
            "eval.seeds=[0,1]",
            f"hydra.run.dir={tmp_path}",
        ],
        tmp_path,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert list(metrics["conditions"]) == ["datt brownian/l1 seed 0", "datt brownian/l1 seed 1"]
    for cond in metrics["conditions"].values():
        assert cond["groups"]["zigzag"]["episodes"] == 10 and cond["groups"]["star"]["episodes"] == 1
    assert (tmp_path / "tracks_datt_brownian_l1_seed_0.png").exists()
    assert (tmp_path / "axes_datt_brownian_l1_seed_0.png").exists()
    assert (tmp_path / "dhat_datt_brownian_l1_seed_0.png").exists()  # the L1's estimate against d
    assert (tmp_path / "trace_seed1.pt").exists()
    assert "tracking error (m)" in proc.stdout and "zigzag_fast" in proc.stdout
    timing = metrics["inference_ms"]
    assert timing["batch"] == 1 and timing["steps"] == 200 and 0 < timing["median_ms"] <= timing["p95_ms"]
    assert (tmp_path / "metrics.csv").read_text().startswith("condition,group,mean_m,std_m,crashes,episodes")


@pytest.mark.parametrize(
    "args, message",
    [
        (["checkpoint=missing.pt"], "error: checkpoint: file"),
        (
            ["adaptation=magic"],
            "error: adaptation: unknown option 'magic'; allowed: l1, l1_paper, none, privileged, rma",
        ),
        (
            ["controller=lqr"],
            "error: controller: unknown option 'lqr'; allowed: "
            "datt, datt_l1, datt_l1_paper, datt_rma, l1_mppi, l1_pid, mppi, pid",
        ),
    ],
)
def test_eval_py_errors_are_one_line(tmp_path, args, message):
    proc = run([str(ROOT / "eval.py"), *args, f"hydra.run.dir={tmp_path}"], tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith(message), proc.stderr


def test_corrupt_checkpoint_is_one_line(tmp_path):
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00garbage")
    proc = run([str(ROOT / "eval.py"), f"checkpoint={bad}", f"hydra.run.dir={tmp_path}"], tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "warn" not in ln.lower()]
    assert proc.returncode == 2 and len(lines) == 1 and "is not a readable checkpoint" in lines[0], proc.stderr


def test_datt_console_script_usage(tmp_path):
    proc = run(["-c", "import sys; sys.argv=['datt']; from datt.cli import main; main()"], tmp_path)
    assert proc.returncode == 2 and "usage: datt {train,fit_rma,eval,tables,deploy,export}" in proc.stderr


# each entry point: a group it selects, and a group only another entry point selects
OWN_AND_FOREIGN_GROUPS = {
    "train": ("algo", "deploy"),
    "eval": ("controller", "algo"),
    "fit_rma": ("disturbance", "deploy"),
    "tables": (None, "algo"),
    "deploy": ("deploy", "algo"),
    "export": ("controller", "deploy"),
}


@pytest.mark.parametrize("entry", sorted(OWN_AND_FOREIGN_GROUPS))
def test_each_entry_points_help_says_what_it_does_and_lists_its_own_groups(entry, capsys, monkeypatch):
    """``<entry> --help``: exit 0, the sentence of what it does, the most used overrides with what
    they do, examples, and its own config groups only (Hydra's page listed the whole tree)."""
    from datt import cli
    from datt.usage import USAGE

    monkeypatch.setattr(sys, "argv", [f"{entry}.py", "--help"])
    with pytest.raises(SystemExit) as exit_info:
        cli.COMMANDS[entry]()
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    usage = USAGE[entry]
    assert text.startswith(f"usage: {entry}.py [override ...]") and usage.about in text
    assert len(usage.overrides) >= 4 and all(f"  {o}" in text for o, _ in usage.overrides)
    assert "examples:" in text and all(e in text for e in usage.examples)
    groups = [line.split(":")[0].strip().lstrip("+") for line in text.split("config groups")[1].splitlines()[1:]]
    own, foreign = OWN_AND_FOREIGN_GROUPS[entry]
    assert (own is None or own in groups) and foreign not in groups


EXAMPLES = ROOT / "tests" / "examples" / "conf"


def test_user_config_dir_adds_a_reference_family(tmp_path):
    """A new family = one module + one YAML in the user's config dir (tests/examples): eval flies
    it from a bank of the user's, with no change to the package."""
    proc = run(
        [
            str(ROOT / "eval.py"),
            "--config-dir",
            str(EXAMPLES),
            "controller=pid",
            "traj=figure8",
            "bank@eval.bank=figure8",
            "eval.timing.steps=0",
            "eval.plots=false",
            "eval.save_trace=false",
            f"hydra.run.dir={tmp_path}",
        ],
        ROOT,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    (cond,) = metrics["conditions"].values()
    assert cond["groups"]["figure8"]["episodes"] == 2 and cond["groups"]["figure8"]["mean_m"] < 0.5


def test_unknown_option_lists_the_whole_search_path(tmp_path):
    proc = run(
        [str(ROOT / "eval.py"), "--config-dir", str(EXAMPLES), "bank@eval.bank=mine", f"hydra.run.dir={tmp_path}"],
        tmp_path,
    )
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip() and "warn" not in ln.lower()]
    want = "error: bank: unknown option 'mine'; allowed: default, figure8, paper_figure"
    assert proc.returncode == 2 and lines == [want], proc.stderr


def test_sweep_runs_without_dash_m(tmp_path):
    """``+sweep=<table>`` sets hydra.mode=MULTIRUN itself (--cfg hydra shows it)."""
    proc = run([str(ROOT / "train.py"), "+sweep=horizon", "--cfg", "hydra"], tmp_path)
    assert proc.returncode == 0 and "mode: MULTIRUN" in proc.stdout, proc.stderr[-2000:]


def test_a_policy_trained_with_the_authors_timing_evaluates_with_it_and_is_refused_by_deploy_and_export(
    tmp_path, tiny_authors_timing_checkpoint
):
    from datt.configuration import compose
    from datt.control.factory import build_controller
    from datt.errors import ConfigError
    from datt.export import export_spec

    cfg = compose("eval", [f"checkpoint={tiny_authors_timing_checkpoint}"])
    _, merged, _ = build_controller(cfg)
    assert merged.env.obs.timing == "authors"  # the checkpoint carries the timing it was trained with
    label = r"trained with env.obs.timing=authors \(the state one step old\); the exported app feeds the newest"
    with pytest.raises(ConfigError, match=label):
        export_spec(compose("export", [f"checkpoint={tiny_authors_timing_checkpoint}"]))
    proc = run(
        [str(ROOT / "deploy.py"), f"checkpoint={tiny_authors_timing_checkpoint}", f"hydra.run.dir={tmp_path}"], tmp_path
    )
    assert proc.returncode == 2, proc.stderr[-2000:]
    line = proc.stderr.strip()
    assert line.count("\n") == 0 and "env.obs.timing=authors" in line and "deploy feeds the newest state" in line


@pytest.mark.parametrize(
    "args, key",
    [
        (["controller=datt_rma", "adaptation=rma", "adaptation.checkpoint=/nope.pt"], "adaptation.checkpoint"),
        (["controller=datt_l1", "adaptation=l1", "adaptation.cutoff_tau_s=-5"], "adaptation.cutoff_tau_s"),
        (["controller=l1_pid", "adaptation=privileged"], "adaptation"),
    ],
)
def test_an_adaptation_setting_a_controller_would_not_use_is_refused_not_dropped(tmp_path, args, key):
    proc = run([str(ROOT / "eval.py"), *args, f"hydra.run.dir={tmp_path}"], tmp_path)
    assert proc.returncode == 2, proc.stderr[-2000:]
    line = proc.stderr.strip()
    assert line.count("\n") == 0 and line.startswith(f"error: {key}: controller=")
    assert "flies with its own estimator" in line and not (tmp_path / "metrics.json").exists()


def test_datt_help_lists_every_subcommand_and_exits_0(tmp_path):
    from datt.cli import COMMANDS, SUBCOMMANDS

    assert set(SUBCOMMANDS) == set(COMMANDS)
    proc = subprocess.run([sys.executable, "-m", "datt", "--help"], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0 and proc.stderr == ""
    assert proc.stdout.startswith("usage: datt {train,fit_rma,eval,tables,deploy,export}")
    for name, text in SUBCOMMANDS.items():
        assert f"  {name:8} {text}" in proc.stdout
