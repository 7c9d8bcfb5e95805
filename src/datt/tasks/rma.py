"""``fit_rma.py base_checkpoint=<policy>``: fit an RMA adapter for a frozen policy, then
evaluate DATT under the fit's disturbance (``disturbance=``, the paper's Brownian by default) with
d̂ = 0, L1, RMA and the privileged d."""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig, OmegaConf

from datt.configuration import structured
from datt.eval.conditions import evaluate_conditions, print_metrics
from datt.eval.schema import AdapterEvalParams, per_seed_name
from datt.policies.loading import load_actor
from datt.runs import write_json
from datt.tasks.common import console, hydra_run_dir, set_threads
from datt.tasks.validation import validate_config
from datt.train.rma import train_rma
from datt.train.schema import fit_rma_params


def run_fit_rma(cfg: DictConfig, run_dir: Path | None = None) -> dict:
    """The ``fit_rma.py`` command: validate, then :func:`run_rma` in the Hydra run dir."""
    validate_config("fit_rma", cfg)
    set_threads(fit_rma_params(cfg).threads)
    return run_rma(cfg, run_dir or hydra_run_dir())


def run_rma(cfg: DictConfig, run_dir: Path) -> dict:
    """Fit, save ``rma.pt`` and compare the four sources of d̂; returns ``metrics.json``."""
    end_eval = structured(AdapterEvalParams, cfg.eval, "eval")
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    result = train_rma(cfg, run_dir, progress=True)
    actor, train_cfg, _ = load_actor(cfg.base_checkpoint, key="base_checkpoint")
    eval_cfg = OmegaConf.merge(train_cfg, {"env": {"compile": False}})
    # the fit's own evaluation settings and bank, whole: a merge would keep the groups of the
    # policy's bank that this bank does not name
    eval_cfg.eval = OmegaConf.create(OmegaConf.to_container(cfg.eval, resolve=True))
    conditions = {}
    rma = OmegaConf.create({"_target_": "datt.adapt.RmaAdaptation", "checkpoint": str(run_dir / "rma.pt")})
    sources = {"d_hat=0": "none", "l1": "l1", "rma": rma, "privileged": "privileged"}
    # the disturbance the adapter was fitted under (the run records the whole node it flew)
    disturbance = OmegaConf.create(OmegaConf.to_container(cfg.disturbance, resolve=True))
    for seed in end_eval.seeds:
        for source, adaptation in sources.items():
            name = per_seed_name(source, seed, end_eval.seeds)
            cond = {name: {"disturbance": disturbance, "adaptation": adaptation}}
            res = evaluate_conditions(eval_cfg, actor, cond, run_dir, end_eval.plots, "rma", int(seed))
            conditions[name] = {**res[name], "adaptation": source}
    kind = str(disturbance.get("_target_", "none")).rsplit(".", 1)[-1]
    print_metrics(console, f"DATT under the {kind} disturbance by adaptation", conditions)
    metrics = {"rma_train_wall_s": result["wall_s"], "rma_history": result["history"], "conditions": conditions}
    write_json(run_dir / "metrics.json", metrics)
    return metrics
