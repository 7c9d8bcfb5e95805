"""The trust boundary for files: a config read from a checkpoint or a run dir is data. A crafted
``_target_`` in it is refused in one line naming the file and the key, through every entry point
and tool that reads one, and its code never runs. The crafted node is the attack that works
where Hydra's own blocklist (``exec``, ``eval``, ``os.system``) does not reach:
``torch.load`` of a second file with ``weights_only: false``, whose pickle writes a marker file."""

import pickle
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from omegaconf import OmegaConf

from datt.checkpoint import load_checkpoint, save_checkpoint
from datt.configuration import check_targets, registered_targets
from datt.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
PAYLOAD = "open('PWNED', 'w').write('ran')"


class _Pickled:
    def __reduce__(self):
        return (exec, (PAYLOAD,))


def evil_node(tmp_path: Path) -> dict:
    """``torch.load`` of a pickle that runs ``PAYLOAD`` when loaded without ``weights_only``."""
    bomb = tmp_path / "weights.pt"
    bomb.write_bytes(pickle.dumps(_Pickled()))
    return {"_target_": "torch.load", "f": str(bomb), "weights_only": False}


def crafted(tmp_path: Path, source: Path, where: tuple[str, ...] = ("traj",)) -> Path:
    """A copy of the checkpoint ``source`` whose config holds the crafted node at ``where`` and in
    the end-of-run evaluation's first condition, with more steps to train than it has (so a
    resume builds its references): the places the code before the boundary built from a file."""
    data = load_checkpoint(source)
    cfg = yaml.safe_load(data["config_yaml"])
    node = cfg
    for part in where[:-1]:
        node = node[part]
    node[where[-1]] = evil_node(tmp_path)
    cfg["eval"]["conditions"]["clean"]["disturbance"] = evil_node(tmp_path)
    cfg["train"]["total_frames"] = 10 * int(data["frames"])
    data["config_yaml"] = yaml.safe_dump(cfg)
    run_dir = tmp_path / "run"
    return save_checkpoint(run_dir / "last.pt", {k: v for k, v in data.items() if k != "format"})


def run(args, cwd):
    return subprocess.run([sys.executable, *args], cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize(
    "command",
    [  # the two where the pickle ran before the boundary stay in the default suite
        ["train.py", "resume={run}", "logger=csv"],
        pytest.param(
            ["train.py", "train.init_from={ckpt}", "logger=csv", "train.total_frames=1"], marks=pytest.mark.slow
        ),
        pytest.param(["fit_rma.py", "base_checkpoint={ckpt}"], marks=pytest.mark.slow),
        pytest.param(["eval.py", "checkpoint={ckpt}"], marks=pytest.mark.slow),
        pytest.param(["deploy.py", "checkpoint={ckpt}"], marks=pytest.mark.slow),
        ["tools/reevaluate_checkpoint.py", "{ckpt}", "{run}/metrics.json"],
    ],
    ids=["resume", "init_from", "rma", "eval", "deploy", "reevaluate_tool"],
)
def test_a_crafted_checkpoint_cannot_run_code_through_any_entry_point(tmp_path, tiny_policy_checkpoint, command):
    ckpt = crafted(tmp_path, tiny_policy_checkpoint)
    args = [c.format(ckpt=ckpt, run=ckpt.parent) for c in command]
    proc = run([str(ROOT / args[0]), *args[1:]], tmp_path)
    assert not (tmp_path / "PWNED").exists(), "the checkpoint's code ran"
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    line = proc.stderr.strip().splitlines()[-1]
    assert "Traceback" not in proc.stderr
    assert "._target_: 'torch.load' is not the target of any config option" in line
    assert str(ckpt) in line


def test_a_crafted_run_dir_config_cannot_run_code_on_resume(tmp_path, tiny_policy_checkpoint):
    ckpt = crafted(tmp_path, tiny_policy_checkpoint, ("curriculum", "fixed", "family"))
    cfg = OmegaConf.create(load_checkpoint(ckpt)["config_yaml"])
    cfg.curriculum.fixed.family = OmegaConf.create(evil_node(tmp_path))
    (ckpt.parent / "config.yaml").write_text(OmegaConf.to_yaml(cfg))
    proc = run([str(ROOT / "train.py"), f"resume={ckpt.parent}", "logger=csv"], tmp_path)
    assert not (tmp_path / "PWNED").exists()
    assert proc.returncode == 2 and "Traceback" not in proc.stderr
    assert "._target_: 'torch.load' is not the target of any config option" in proc.stderr
    assert str(ckpt.parent / "config.yaml") in proc.stderr


def test_the_registry_is_every_target_of_the_config_tree_and_a_users_config_dir(tmp_path):
    package = registered_targets()
    assert {"datt.refs.Zigzag", "datt.sim.Brownian", "datt.adapt.L1Adaptation", "datt.refs.Fixed"} <= package
    assert not any(t.startswith(("builtins", "os", "subprocess", "torch")) for t in package)
    user = tmp_path / "conf"
    (user / "traj").mkdir(parents=True)
    (user / "traj" / "figure8.yaml").write_text("_target_: my_refs.Figure8\nperiod_s: 4.0\n")
    from datt.configuration import conf_dir

    assert "my_refs.Figure8" in registered_targets([user, conf_dir()])
    check_targets({"traj": {"_target_": "datt.refs.Mixed", "families": {"a": {"_target_": "datt.refs.Poly"}}}}, "cfg")
    with pytest.raises(ConfigError, match=r"^cfg\.traj\.families\.a\._target_: 'os\.system' is not"):
        check_targets({"traj": {"_target_": "datt.refs.Mixed", "families": {"a": {"_target_": "os.system"}}}}, "cfg")
    with pytest.raises(ConfigError, match=r"cfg\[1\]\._target_: 'posix\.system'"):
        check_targets([{"_target_": "datt.refs.Poly"}, {"_target_": "posix.system"}], "cfg")


def _with_a_nan_weight(tmp_path: Path) -> Path:

    data = load_checkpoint(ROOT / "src/datt/checkpoints/datt_h10_smooth.pt")
    data.pop("format")
    name = next(k for k, v in data["actor"].items() if v.is_floating_point())
    data["actor"][name] = data["actor"][name].clone()
    data["actor"][name].view(-1)[3] = float("nan")
    return save_checkpoint(tmp_path / "diverged.pt", data)


def test_a_checkpoint_with_non_finite_weights_is_refused_naming_the_tensor(tmp_path):
    path = _with_a_nan_weight(tmp_path)
    with pytest.raises(ConfigError) as info:
        load_checkpoint(path, key="checkpoint")
    message = str(info.value)
    assert message.startswith(f"checkpoint: {str(path)!r} holds non-finite values (actor.") and "1 of " in message
    assert "use an earlier checkpoint (its best.pt) or train again" in message


@pytest.mark.parametrize("entry, args", [("deploy", []), ("eval", ["eval.timing.steps=0"]), ("export", [])])
def test_no_entry_point_uses_a_checkpoint_with_non_finite_weights(tmp_path, monkeypatch, capsys, entry, args):
    """Before: ``deploy.py`` flew it (armed, took off, KILLed at 1 m)."""
    from .test_faults import one_line, run_cli

    path = _with_a_nan_weight(tmp_path)
    result = run_cli(entry, [f"checkpoint={path}", *args, "hydra.run.dir=r"], tmp_path, monkeypatch, capsys)
    one_line(result, f"error: checkpoint: {str(path)!r} holds non-finite values (actor.")
    assert not (tmp_path / "r" / "flight.csv").exists()


# what a policy checkpoint fixes, each set on the command line to another value than it was trained with
CONTRADICTIONS = [
    ("horizon=5", "horizon", "10"),
    ("env.obs.action_history=4", "env.obs.action_history", "2"),
    ("env.obs.body_frame=false", "env.obs.body_frame", "True"),
    ("+policy.hidden=[8,8]", "policy.hidden", None),  # eval, deploy and export have no policy node: added
]


@pytest.mark.parametrize("entry, args", [("deploy", []), ("eval", ["eval.timing.steps=0"]), ("export", [])])
@pytest.mark.parametrize("override, key, trained", CONTRADICTIONS)
def test_an_override_that_contradicts_the_checkpoint_is_refused(
    tmp_path, monkeypatch, capsys, tiny_policy_checkpoint, entry, args, override, key, trained
):
    """Before: the policy flew its own layout and the run recorded the override it did not fly."""
    from .test_faults import one_line, run_cli

    ckpt = f"checkpoint={tiny_policy_checkpoint}"
    result = run_cli(entry, [ckpt, override, *args, "hydra.run.dir=r"], tmp_path, monkeypatch, capsys)
    start = f"error: {key}: the checkpoint was trained with {key}=" + (trained or "")
    one_line(result, start)
    assert f"drop {override!r}" in result[1][0]
    assert not (tmp_path / "r" / "flight.csv").exists()


def test_an_override_equal_to_the_checkpoints_value_is_accepted(tmp_path, monkeypatch, capsys, tiny_policy_checkpoint):
    from .test_faults import run_cli

    args = [f"checkpoint={tiny_policy_checkpoint}", "horizon=10", "env.obs.action_history=2", "eval.timing.steps=0"]
    args += ["eval.plots=false", "eval.bank={zigzag:[{traj:zigzag,seed:1000,count:2}]}", "hydra.run.dir=r"]
    code, lines, _ = run_cli("eval", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
