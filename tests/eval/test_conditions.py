"""The end-of-run evaluation of a training run (``datt.eval.conditions``) over ``eval.seeds``."""

from omegaconf import OmegaConf

from datt.configuration import compose
from datt.eval.conditions import evaluate_conditions, evaluate_end_of_run

BANK = {"zigzag": [{"traj": "zigzag", "seed": 1000, "count": 3}]}
BROWNIAN = {"disturbance": "brownian", "adaptation": "privileged"}


def train_cfg(seeds):
    cfg = compose("train", ["env.compile=false", f"eval.seeds={seeds}"])
    OmegaConf.set_struct(cfg, False)
    cfg.eval.bank = BANK
    cfg.eval.conditions = {"brownian": BROWNIAN}
    return cfg


def groups(result):
    return {name: cond["groups"]["zigzag"]["mean_m"] for name, cond in result.items()}


def test_several_seeds_give_one_condition_per_seed_each_its_own_seeds_evaluation(tmp_path):
    cfg = train_cfg("[0,1]")
    conditions, hover = evaluate_end_of_run(cfg, None, tmp_path, False, "t", cfg.eval.seeds)
    at = {s: evaluate_conditions(cfg, None, {"b": BROWNIAN}, tmp_path, False, "t", seed=s)["b"] for s in (0, 1)}
    assert groups(conditions) == {
        "brownian seed 0": groups({"b": at[0]})["b"],
        "brownian seed 1": groups({"b": at[1]})["b"],
    }
    assert groups(conditions)["brownian seed 0"] != groups(conditions)["brownian seed 1"]  # the draws differ
    first = evaluate_conditions(
        cfg, None, {"hover": {"disturbance": "none", "adaptation": "none"}}, tmp_path, False, "h"
    )
    assert hover["groups"] == first["hover"]["groups"]  # the reference point: the first seed's bank


def test_one_seed_keeps_the_plain_condition_names_at_that_seed(tmp_path):
    cfg = train_cfg("[1]")
    conditions, _ = evaluate_end_of_run(cfg, None, tmp_path, False, "t", cfg.eval.seeds)
    at_one = evaluate_conditions(cfg, None, {"brownian": BROWNIAN}, tmp_path, False, "t", seed=1)
    assert groups(conditions) == groups(at_one)
