"""Re-run a training run's end-of-run evaluation on the current evaluation bank.

    python tools/reevaluate_checkpoint.py src/datt/checkpoints/datt_h10.pt src/datt/checkpoints/datt_h10_metrics.json

Loads the policy and its training config from the checkpoint, replaces the bank with today's
``conf/bank/default.yaml``, flies the run's ``eval.conditions`` and the hovering reference
exactly as ``python train.py`` does at the end of a run (the seeds ``eval.seeds``), and writes them
into the metrics file: its training facts (frames, wall time, steps/s, horizon, seed) are kept,
``conditions`` and ``hover_reference`` replaced. For a checkpoint whose recorded numbers came
from an older bank.
"""

from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from omegaconf import OmegaConf

from datt.cli import run_tool
from datt.configuration import compose
from datt.eval.conditions import evaluate_end_of_run
from datt.policies.loading import load_actor
from datt.runs import write_json
from datt.tasks.resume import KEYS_ADDED_SINCE


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("checkpoint", type=Path)
    parser.add_argument("metrics", type=Path, help="the run's metrics.json (rewritten)")
    args = parser.parse_args()
    actor, train_cfg, _ = load_actor(args.checkpoint)
    cfg = train_cfg.copy()
    OmegaConf.update(cfg, "eval.bank", compose("train").eval.bank, merge=False)  # today's bank, whole
    for key, value in KEYS_ADDED_SINCE.items():  # a config written before these keys existed
        if OmegaConf.select(cfg, key, default="absent") == "absent":
            OmegaConf.update(cfg, key, value, force_add=True)
    metrics = json.loads(args.metrics.read_text()) if args.metrics.exists() else {}
    with tempfile.TemporaryDirectory() as tmp:
        metrics["conditions"], hover = evaluate_end_of_run(cfg, actor, Path(tmp), False, "", list(cfg.eval.seeds))
    metrics["hover_reference"] = hover
    write_json(args.metrics, metrics)
    for name, cond in {**metrics["conditions"], "hover": hover}.items():
        cells = ", ".join(f"{g} {v['mean_m']:.4f} ± {v['std_m']:.4f} m" for g, v in cond["groups"].items())
        print(f"{name}: {cells}")


if __name__ == "__main__":
    run_tool(main)
