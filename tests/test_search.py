"""A search instead of a grid: every task returns its headline figure to Hydra
(``optimized_metric``), so Optuna's sweeper can drive train.py. A 3-trial search on a tiny budget."""

import math

import pytest
import yaml

from datt.tasks.common import headline

from .test_faults import run_cli
from .train.test_training import TINY

METRICS = {
    "frames": 1024,
    "conditions": {
        "clean": {"groups": {"zigzag": {"mean_m": 0.05}, "star": {"mean_m": 0.03}}},
        "x seed 0": {"groups": {"zigzag": {"mean_m": 0.10}}},
        "x seed 1": {"groups": {"zigzag": {"mean_m": 0.20}}},
        "crashed": {"groups": {"zigzag": {"mean_m": None}}},
    },
}


@pytest.mark.parametrize(
    "path, value",
    [
        ("conditions.clean.groups.zigzag.mean_m", 0.05),
        ("conditions.x seed *.groups.zigzag.mean_m", 0.15),  # several matches: their mean
        ("conditions.clean.groups.*.mean_m", 0.04),
        ("conditions.crashed.groups.zigzag.mean_m", math.inf),  # no finite error: the worst figure
        ("frames", 1024.0),
        (None, None),
        ("conditions.absent.groups.zigzag.mean_m", None),  # nothing there: no figure, one warning line
    ],
)
def test_the_headline_figure_is_the_value_at_its_path(path, value):
    assert headline(METRICS, path) == (pytest.approx(value) if value not in (None, math.inf) else value)


def test_a_three_trial_optuna_search_on_a_tiny_budget(tmp_path, monkeypatch, capsys):
    """``+search=lr`` with 3 trials: 3 job dirs, each a training run; the study's best value is
    the smallest of their clean zigzag errors, at a learning rate inside the searched interval."""
    pytest.importorskip("hydra_plugins.hydra_optuna_sweeper")
    sweep = tmp_path / "search"
    args = [
        "+search=lr",
        *TINY,
        "train.total_frames=1024",
        "eval.plots=false",
        "hydra.sweeper.n_trials=3",
        f"hydra.sweep.dir={sweep}",
    ]
    code, lines, _ = run_cli("train", args, tmp_path, monkeypatch, capsys)
    assert code == 0, lines
    results = yaml.safe_load((sweep / "optimization_results.yaml").read_text())
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and p.name.isdigit())
    assert len(jobs) == 3
    errors = []
    for job in jobs:
        metrics = yaml.safe_load((job / "metrics.json").read_text())
        errors.append(headline(metrics, "conditions.clean.groups.zigzag.mean_m"))
    assert results["best_value"] == pytest.approx(min(errors))
    assert 1e-5 <= results["best_params"]["algo.lr"] <= 1e-3
