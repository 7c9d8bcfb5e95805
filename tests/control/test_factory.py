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
        ["env.quad.mass_spread=0.1", "adaptations=3", "adaptation_s=1", "l1=rma", "seed=l1", "Xadaptation=rma"],
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


def _choices(monkeypatch, overrides=None):
    """A Hydra job's choices and command line, as the factory reads them."""
    monkeypatch.setattr(factory, "hydra_choice", lambda group: f"<{group}>")
    _with_overrides(monkeypatch, overrides)


def test_a_controller_option_with_a_target_is_built_from_its_resolved_settings(monkeypatch):
    """``controller=pid`` with a gain given as an interpolation: the controller gets the value
    (the option is resolved against the whole config before it is instantiated); its labels name
    the controller and the job's disturbance and adaptation choices."""
    from datt.configuration import compose
    from datt.control.pid import PidController

    _choices(monkeypatch)
    cfg = compose("eval", ["controller=pid", "seed=3", "controller.kp=${seed}"])
    controller, merged, labels = factory.build_controller(cfg)
    assert isinstance(controller, PidController) and controller.kp == 3
    assert labels == {"controller": "pid", "disturbance": "<disturbance>", "adaptation": "<adaptation>"}
    assert merged.seed == 3


def test_a_policy_option_loads_the_checkpoint_and_labels_it(monkeypatch):
    """``controller=datt_l1``: the policy of ``checkpoint`` (frozen: it builds its own observation),
    flown with L1 whatever the job chose for ``adaptation``; the labels name the checkpoint and
    its training frames; the flying config takes the policy's horizon and stays open to keys."""
    import torch

    from datt.configuration import compose
    from datt.control.datt import DattController
    from datt.paths import resolve_path

    _choices(monkeypatch, ["controller=datt_l1"])
    cfg = compose("eval", ["controller=datt_l1", "checkpoint=checkpoints/datt_h10.pt"])
    controller, merged, labels = factory.build_controller(cfg)
    data = torch.load(resolve_path("checkpoints/datt_h10.pt"), weights_only=True)
    assert isinstance(controller, DattController) and controller.builds_observation
    assert labels == {
        "controller": "datt_l1",
        "disturbance": "<disturbance>",
        "adaptation": "l1",
        "checkpoint": "checkpoints/datt_h10.pt",
        "frames": int(data["frames"]),
        "predict_latency": False,  # trained without the state predictor (its env.obs.predict_latency)
    }
    assert merged.adaptation._target_.endswith("L1Adaptation") and merged.horizon == 10
    merged.not_a_key_before = 1  # not struct: the flying config can be extended


def test_a_controller_with_its_own_estimator_refuses_an_adaptation_override_naming_both(monkeypatch):
    from datt.configuration import compose

    _choices(monkeypatch, ["controller=l1_pid", "adaptation=rma"])
    with pytest.raises(
        ConfigError, match=r"^adaptation: controller=l1_pid flies with its own estimator \(adaptation=l1\)"
    ):
        factory.build_controller(compose("eval", ["controller=l1_pid"]))
