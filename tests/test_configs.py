"""The config tree as a whole: every option of every group composes under the entry point that
uses it, every ``_target_`` instantiates, every task node passes its typed schema, and the
library's dataclass defaults agree with the YAML (the only place a default lives)."""

from __future__ import annotations

import re
from dataclasses import asdict, fields

import pytest
from hydra.utils import instantiate
from omegaconf import OmegaConf

from datt.configuration import available_options, compose, conf_dir, config_groups, load_option, structured
from datt.control.factory import build_controller
from datt.deploy.schema import deploy_params
from datt.envs.factory import env_params_from_cfg
from datt.envs.params import EnvParams
from datt.eval import tables
from datt.eval.rollout import build_bank
from datt.eval.schema import AdapterEvalParams, EndOfRunEvalParams, EvalParams, SharedEvalParams
from datt.policies.networks import PolicyParams
from datt.tasks.tables import TablesParams
from datt.train.ppo import AlgoParams
from datt.train.schema import CurriculumParams, RmaParams, TrainParams, fit_rma_params, run_params

# the primary config whose defaults list holds each group
PRIMARY = {"controller": "eval", "deploy": "deploy"}
GROUPS = sorted(config_groups([conf_dir()]))


def _option_cases():
    for group in GROUPS:
        for option in available_options(group, [conf_dir()]):
            yield pytest.param(group, option, id=f"{group}={option}")


def _compose(group: str, option: str, tmp_path):
    if group == "sweep":
        return compose(tables.TABLES[option].entry.removesuffix(".py"), [f"+sweep={option}"])
    if group == "search":  # added to a training run, as a sweep is
        return compose("train", [f"+search={option}"])
    overrides = [f"{group}={option}"]
    if group == "bank":
        overrides = [f"bank@eval.bank={option}"]
    if group == "evaluation":
        overrides = [f"evaluation@eval={option}"]
    if (group, option) == ("traj", "csv"):
        csv = tmp_path / "ref.csv"
        csv.write_text("t,x,y,z\n0,0,0,0\n1,1,0,0\n")
        overrides.append(f"traj.path={csv}")
    return compose(PRIMARY.get(group, "train"), overrides)


def _targets(node):
    """Every mapping with a ``_target_`` in ``node`` (outermost first, not inside each other)."""
    if OmegaConf.is_dict(node):
        if "_target_" in node:
            yield node
            return
        for value in node.values():
            yield from _targets(value)
    elif OmegaConf.is_list(node):
        for value in node:
            yield from _targets(value)


@pytest.mark.parametrize("group, option", list(_option_cases()))
def test_every_option_composes_and_instantiates(group, option, tmp_path):
    cfg = _compose(group, option, tmp_path)
    if group == "controller":  # options carry a name (and maybe a fixed estimator) beside _target_
        controller, merged, labels = build_controller(cfg)
        assert labels["controller"] == cfg.controller.name and hasattr(controller, "act")
        node = merged.adaptation
    else:
        node = (
            cfg.eval.bank
            if group == "bank"
            else cfg.eval
            if group == "evaluation"
            else cfg
            if group in ("sweep", "search", "ablation", "experiment", "randomization", "vehicle")
            else cfg[group]
        )
    for target in _targets(node):
        assert instantiate(target, _convert_="all") is not None
    # the task's schemas accept what the option composes to
    if "train" in cfg and "curriculum" in cfg:
        run_params(cfg)
        for cls, key in (
            (TrainParams, "train"),
            (CurriculumParams, "curriculum"),
            (EndOfRunEvalParams, "eval"),
            (AlgoParams, "algo"),
            (PolicyParams, "policy"),
        ):
            structured(cls, cfg[key], key)
        env_params_from_cfg(cfg.env)
    if "rma" in cfg:  # fit_rma.py's config (the rma sweep)
        fit_rma_params(cfg)
        structured(RmaParams, cfg.rma, "rma")
        structured(AdapterEvalParams, cfg.eval, "eval")
    if "deploy" in cfg:
        deploy_params(cfg.deploy)
    if "eval" in cfg and "timing" in cfg.eval:  # eval.py's node
        structured(EvalParams, cfg.eval, "eval")
    if group == "bank":
        names, counts, _ = build_bank(cfg.eval.bank)
        assert names and all(c > 0 for c in counts)


def test_every_group_has_options():
    assert {
        "env",
        "traj",
        "disturbance",
        "adaptation",
        "policy",
        "algo",
        "ablation",
        "controller",
        "logger",
        "deploy",
        "experiment",
        "bank",
        "sweep",
    } <= set(GROUPS)


def test_tables_config_passes_its_schema():
    cfg = compose("tables")
    assert structured(TablesParams, cfg, "tables").table in tables.TABLES


def test_a_missing_key_is_a_one_line_error_naming_it():
    cfg = compose("train")
    OmegaConf.set_struct(cfg, False)
    del cfg.train["total_frames"]
    with pytest.raises(Exception, match=r"^train\.total_frames: "):
        structured(TrainParams, cfg.train, "train")


@pytest.mark.parametrize(
    "cls, path",
    [(EnvParams, "env/default.yaml"), (PolicyParams, "policy/datt.yaml"), (AlgoParams, "algo/ppo.yaml")],
)
def test_library_defaults_equal_the_yaml(cls, path):
    """The dataclasses keep defaults for the Python API; they must be the YAML's."""
    yaml = OmegaConf.to_container(OmegaConf.load(conf_dir() / path), resolve=True)
    code = asdict(cls())

    def compare(a: dict, b: dict, prefix: str) -> None:
        assert set(a) == set(b), f"{prefix}: keys differ: {set(a) ^ set(b)}"
        for k in a:
            if isinstance(a[k], dict):
                compare(a[k], b[k], f"{prefix}.{k}")
            else:
                va = list(a[k]) if isinstance(a[k], tuple) else a[k]
                vb = list(b[k]) if isinstance(b[k], tuple) else b[k]
                assert va == vb, f"{prefix}.{k}: YAML {va!r}, code {vb!r}"

    compare(yaml, code, path)


def test_a_top_level_type_error_names_the_top_level_key():
    with pytest.raises(Exception, match=r"^seed: Value 'abc'"):
        run_params(compose("train", ["seed=abc"]))


def _target_defaults_differ(node):
    """Keys where a ``_target_`` node's YAML value differs from the class's Python default."""
    import importlib
    import inspect

    module, _, name = node["_target_"].rpartition(".")
    target = getattr(importlib.import_module(module), name)
    params = inspect.signature(target).parameters
    differ = []
    for key, value in node.items():
        if key == "_target_" or key not in params or params[key].default is inspect.Parameter.empty:
            continue
        default = params[key].default
        as_tuple = tuple(value) if isinstance(value, list) else value
        if isinstance(value, dict) or default is None or (isinstance(value, str) and value.startswith("${")):
            continue  # nested, no default, or an interpolation (the value follows another key)
        if (tuple(default) if isinstance(default, (list, tuple)) else default) != as_tuple:
            differ.append(f"{key}: yaml {value!r} vs python {default!r}")
    return differ


def _own_package_options():
    """(group, option) of every option that lives under its group's key (not ``@package
    _global_``): the ones a condition, a bank or a tool loads by name."""
    out = []
    for group in sorted(config_groups()):
        for option in available_options(group):
            text = (conf_dir() / group / f"{option}.yaml").read_text()
            if "@package _global_" not in text:
                out.append((group, option))
    return out


@pytest.mark.parametrize("group, option", _own_package_options())
def test_an_option_loaded_by_name_is_the_option_hydra_composes(group, option):
    """An evaluation condition (``{disturbance: constant_authors}``) or a bank item (``traj:
    poly_authors``) names an option; it must load as ``+group=option`` composes it, its own
    defaults list included (``constant_authors`` builds on ``constant``: loaded as the bare file
    it had no ``_target_`` and the end-of-run evaluation died)."""
    composed = OmegaConf.select(compose(None, [f"+{group}={option}"]), group.replace("/", "."))
    assert OmegaConf.to_container(load_option(group, option)) == OmegaConf.to_container(composed)


def test_the_options_that_build_on_another_are_among_those_checked():
    built = {(g, o) for g, o in _own_package_options() if "defaults:" in (conf_dir() / g / f"{o}.yaml").read_text()}
    assert {("disturbance", "constant_authors"), ("traj", "mixed_authors"), ("deploy", "crazyflie")} <= built


@pytest.mark.parametrize("group", ["traj", "disturbance", "adaptation", "controller"])
def test_python_defaults_are_the_config_defaults(group):
    """``Wind()`` in a notebook is the same wind as ``disturbance=wind``: one default per value.
    A class behind several options (``Polygon``: ``polygon`` and ``star``) matches one of them."""
    by_target: dict[str, dict[str, list[str]]] = {}
    for option in available_options(group):
        node = OmegaConf.to_container(load_option(group, option), resolve=False)
        if "_target_" in node:
            by_target.setdefault(node["_target_"], {})[option] = _target_defaults_differ(node)
    assert by_target
    for target, options in by_target.items():
        assert any(not differ for differ in options.values()), (target, options)


@pytest.mark.parametrize(
    "override, replacement",
    [
        ("env.num_envs=512", "use algo.num_envs (training) or rma.num_envs"),
        ("train.threads=1", "use threads"),
        ("stage=rma", "use python fit_rma.py base_checkpoint=<policy> to fit an RMA adapter"),
        ("train.total_steps=1000", "use train.total_frames (the same number: frames"),
        ("curriculum.fixed_ref_steps=0", "use curriculum.fixed_ref_frames (the same number: frames)"),
        ("train.phases=null", "use train.stages (the same list: a training schedule in stages)"),
        ("eval.seed=1", "use eval.seeds (a list, as in eval.py: eval.seeds=[0] or [0,1,2])"),
    ],
    ids=[
        "env.num_envs",
        "train.threads",
        "stage",
        "train.total_steps",
        "curriculum.fixed_ref_steps",
        "train.phases",
        "eval.seed",
    ],
)
def test_a_retired_key_on_the_command_line_is_one_line_naming_its_replacement(override, replacement):
    from datt.cli import preflight
    from datt.errors import ConfigError

    key = override.partition("=")[0]
    with pytest.raises(ConfigError, match="^" + re.escape(f"{key}: no longer a setting; {replacement}")):
        preflight([override])
    with pytest.raises(ConfigError, match=rf"^{key}: "):
        preflight([f"+{override}"])


def test_a_saved_config_with_retired_keys_is_read_in_todays_keys():
    from datt.configuration import upgrade_saved_config

    old = OmegaConf.create({"env": {"num_envs": 1024, "dt_s": 0.02}, "train": {"threads": 2, "progress": True}})
    OmegaConf.set_struct(old, True)
    new = upgrade_saved_config(old)
    assert OmegaConf.to_container(new) == {"env": {"dt_s": 0.02}, "train": {"progress": True}, "threads": 2}
    assert OmegaConf.is_struct(new)
    # today's value wins over a moved one; a config without retired keys is unchanged
    both = upgrade_saved_config(OmegaConf.create({"train": {"threads": 2}, "threads": 4}))
    assert OmegaConf.to_container(both) == {"train": {}, "threads": 4}
    today = {"env": {"dt_s": 0.02}, "threads": None}
    assert OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(today))) == today
    # a training config saved when train.py also fitted RMA adapters (stage=, base_checkpoint=, rma:)
    fitted = {"train": {"progress": True}, "stage": "ppo", "base_checkpoint": None, "rma": {"num_envs": 1024}}
    assert OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(fitted))) == {"train": {"progress": True}}
    # frames once named steps: the run's total, the curriculum's fixed reference, each stage's length
    # (and the stages once named phases)
    counted = {
        "train": {"total_steps": 2048, "phases": [{"name": "a", "steps": 2048, "set": {}}]},
        "curriculum": {"fixed_ref_steps": 1024},
    }
    assert OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(counted))) == {
        "train": {"stages": [{"name": "a", "set": {}, "frames": 2048}], "total_frames": 2048},
        "curriculum": {"fixed_ref_frames": 1024},
    }
    # the end-of-run evaluation's one seed, now a list as in every job's eval node
    seeded = {"eval": {"seed": 3, "plots": True}}
    upgraded = OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(seeded)))
    assert upgraded == {"eval": {"plots": True, "seeds": [3]}}
    rma_run = {"rma": {"num_envs": 1024}, "base_checkpoint": "p.pt"}  # an RMA fit's own config keeps them
    assert OmegaConf.to_container(upgrade_saved_config(OmegaConf.create(rma_run))) == rma_run


SHARED_EVAL_KEYS = ("protocol", "diverged_error_m", "seeds", "plots")


@pytest.mark.parametrize("job", ["train", "eval", "fit_rma"])
def test_the_shared_eval_keys_have_one_home(job):
    """protocol, diverged_error_m, seeds and plots come from conf/evaluation/common.yaml in every job: none of the
    job files sets them, and a job's eval node holds exactly the shared schema's keys plus its own."""
    own = OmegaConf.load(conf_dir() / f"{job}.yaml").get("eval") or {}
    assert not set(own) & set(SHARED_EVAL_KEYS), f"{job}.yaml sets a shared eval key"
    home = OmegaConf.load(conf_dir() / "evaluation" / "common.yaml")
    cfg = compose(job)
    assert {k: cfg.eval[k] for k in SHARED_EVAL_KEYS} == {k: home[k] for k in SHARED_EVAL_KEYS}
    cls = {"train": EndOfRunEvalParams, "eval": EvalParams, "fit_rma": AdapterEvalParams}[job]
    assert set(cfg.eval) == {f.name for f in fields(cls)}
    assert {f.name for f in fields(SharedEvalParams)} == {*SHARED_EVAL_KEYS, "bank"}


def test_the_authors_adaptive_experiment_is_their_configs_setting():
    """``experiment=authors_adaptive`` (their configuration/datt_wind_adaptive.py): a constant
    U(±1) m/s² force per axis and episode without a random walk, starts at the origin, position
    noise 0.005 m; everything else as the training defaults."""
    import torch

    from datt.configuration import instantiate_option
    from datt.sim import ConstantForce

    cfg = compose("train", ["experiment=authors_adaptive"])
    base = compose("train", [])
    dist = instantiate_option(cfg, "disturbance")
    assert type(dist) is ConstantForce and dist.max_mps2 == 1.0  # not Brownian: no walk
    assert cfg.env.init_pos_range_m == 0.0 and cfg.env.obs.pos_noise_std_m == 0.005
    changed = {
        k
        for k in ("algo", "policy", "traj", "adaptation", "train", "curriculum")
        if OmegaConf.to_container(cfg[k]) != OmegaConf.to_container(base[k])
    }
    assert changed == set()
    assert OmegaConf.to_container(cfg.eval.conditions) == {
        "clean": {"disturbance": "none", "adaptation": "none"},
        "brownian": None,
        "constant_authors": {"disturbance": "constant_authors", "adaptation": "privileged"},
    }
    from datt.envs.factory import make_env

    env = make_env(OmegaConf.merge(cfg, {"env": {"compile": False}}), num_envs=256, seed=0)
    env.reset()
    d = env.disturbance.current_mps2
    assert d.abs().max() <= 1.0 and d.abs().max() > 0.9  # U(±1) per axis, spanning it
    assert torch.equal(env.sim.state.pos_m, torch.zeros_like(env.sim.state.pos_m))  # at the origin


def test_an_option_without_self_in_its_defaults_overrides_what_it_builds_on(tmp_path, monkeypatch):
    """As Hydra (1.1 on) composes it: a defaults list without ``_self_`` merges the file's own
    keys last, so they win over the option they build on (a user's --config-dir may omit it)."""
    import datt.configuration as configuration

    (tmp_path / "disturbance").mkdir()
    (tmp_path / "disturbance" / "base.yaml").write_text("max_mps2: 0.5\nsigma2: 0.1\n")
    (tmp_path / "disturbance" / "mine.yaml").write_text("defaults:\n  - base\nmax_mps2: 2.0\n")
    monkeypatch.setattr(configuration, "search_roots", lambda: [tmp_path])
    assert OmegaConf.to_container(load_option("disturbance", "mine")) == {"max_mps2": 2.0, "sigma2": 0.1}
