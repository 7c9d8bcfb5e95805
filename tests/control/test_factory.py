"""The controller factory's refusals: a controller that fixes its estimator refuses the command
line's ``adaptation`` settings it would not use, and a vehicle refuses a policy trained on the
one-step-old state. Each refusal is one line naming the key and what is allowed."""

import pytest
from omegaconf import OmegaConf

from datt.control import factory
from datt.control.factory import refuse_unused_adaptation_overrides, require_current_state_timing
from datt.errors import ConfigError


def _with_overrides(monkeypatch, overrides):
    monkeypatch.setattr(factory, "command_overrides", lambda: overrides)


@pytest.mark.parametrize(
    "overrides",
    [
        None,  # outside Hydra: the caller composed the config itself
        [],
        ["adaptation=l1"],  # the estimator the controller flies with anyway
        ["+adaptation=l1", "~adaptation=l1"],
        ["env.quad.mass_spread=0.1", "adaptations=3", "adaptation_s=1", "l1=rma", "seed=l1"],
    ],
)
def test_overrides_the_controller_does_not_drop_are_accepted(monkeypatch, overrides):
    _with_overrides(monkeypatch, overrides)
    assert refuse_unused_adaptation_overrides("datt_l1", "l1") is None


@pytest.mark.parametrize(
    "override, key",
    [
        ("adaptation=rma", "adaptation"),
        ("+adaptation=none", "adaptation"),
        ("adaptation.cutoff_tau_s=0.5", "adaptation.cutoff_tau_s"),
        ("~adaptation.a_s", "adaptation.a_s"),
        ("adaptation.a_s=l1", "adaptation.a_s"),  # a value spelled like the forced option is still a setting
    ],
)
def test_an_adaptation_setting_the_controller_would_drop_is_refused_naming_it(monkeypatch, override, key):
    _with_overrides(monkeypatch, ["seed=1", "adaptation=l1", override])
    with pytest.raises(ConfigError) as err:
        refuse_unused_adaptation_overrides("datt_l1", "l1")
    assert str(err.value) == (
        f"{key}: controller=datt_l1 flies with its own estimator (adaptation=l1) and would not use "
        f"{override!r}; drop it, or choose datt, pid or mppi with adaptation=<option> and your settings"
    )


def test_the_refusal_names_the_controller_and_its_estimator(monkeypatch):
    _with_overrides(monkeypatch, ["adaptation=l1"])
    with pytest.raises(
        ConfigError, match=r"^adaptation: controller=l1_pid flies with its own estimator \(adaptation=rma\)"
    ):
        refuse_unused_adaptation_overrides("l1_pid", "rma")


@pytest.mark.parametrize("who", ["deploy", "export"])
def test_a_policy_trained_on_the_old_state_is_refused_by_a_vehicle(who):
    merged = OmegaConf.create({"env": {"obs": {"timing": "authors"}}})
    with pytest.raises(ConfigError) as err:
        require_current_state_timing(merged, who)
    assert str(err.value) == (
        "checkpoint: trained with env.obs.timing=authors (the state one step old); "
        f"{who} feeds the newest state; allowed: a policy trained with env.obs.timing=project"
    )


def test_a_policy_trained_on_the_current_state_flies():
    assert require_current_state_timing(OmegaConf.create({"env": {"obs": {"timing": "project"}}}), "deploy") is None
