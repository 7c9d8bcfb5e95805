"""The shipped checkpoint loads from the package and evaluates to the numbers recorded beside it
(``checkpoints/datt_h10_metrics.json``, written by the run that produced it)."""

import json

import pytest

from datt.configuration import compose
from datt.control.factory import build_controller
from datt.eval.rollout import evaluate
from datt.paths import PACKAGE_DIR, resolve_path


def test_shipped_checkpoint_is_found_from_any_directory(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert resolve_path("checkpoints/datt_h10.pt") == PACKAGE_DIR / "checkpoints" / "datt_h10.pt"


def test_shipped_policy_evaluates_to_its_recorded_numbers(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    recorded = json.loads((PACKAGE_DIR / "checkpoints" / "datt_h10_metrics.json").read_text())
    clean = recorded["conditions"]["clean"]["groups"]
    cfg = compose("eval", ["controller=datt", "checkpoint=checkpoints/datt_h10.pt"])
    controller, merged, _ = build_controller(cfg)
    res = evaluate(merged, lambda env: controller, "none", "none", seed=0)
    assert set(res["groups"]) == set(clean) == {"zigzag", "zigzag_fast", "smooth", "star"}
    for group in clean:
        assert res["groups"][group]["crashes"] == 0
        assert res["groups"][group]["mean_m"] == pytest.approx(clean[group]["mean_m"], abs=2e-4), group
