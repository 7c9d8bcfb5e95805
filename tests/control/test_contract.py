"""Every controller option honours the interface: shapes, bounds, finite output, reset."""

import pytest
import torch
from omegaconf import OmegaConf

from datt.cli import build_controller
from datt.config import CONF_DIR, available_options, compose, make_env


def controller_for(option, checkpoint, extra=()):
    overrides = [f"controller={option}", f"checkpoint={checkpoint}", *extra]
    if "mppi" in option:
        overrides += ["controller.num_samples=32", "controller.horizon_steps=8", "controller.compile=false"]
    cfg = compose("eval", overrides)
    return build_controller(cfg)


@pytest.mark.parametrize("option", [o for o in available_options("controller") if o != "datt_rma"])
def test_contract(option, tiny_policy_checkpoint):
    ctrl, cfg, labels = controller_for(option, tiny_policy_checkpoint)
    assert labels["controller"] == OmegaConf.load(CONF_DIR / "controller" / f"{option}.yaml").name
    env = make_env(cfg, num_envs=3, seed=0)
    td = env.reset()
    ctrl.reset(env)
    for _ in range(5):
        action = ctrl.act(env, td)
        assert action.shape == (3, 4) and action.dtype == env.dtype
        assert torch.isfinite(action).all()
        assert (action >= env.action_low - 1e-4).all() or "pid" in option  # PID is clipped by the env
        td["action"] = action
        td = env.step(td)["next"].exclude("reward", "done", "terminated", "truncated")
    # reset to a different batch size works and restarts internal state
    env4 = make_env(cfg, num_envs=4, seed=1)
    td4 = env4.reset()
    ctrl.reset(env4)
    assert ctrl.act(env4, td4).shape == (4, 4)


def test_controller_adaptation_is_fixed_by_the_option(tiny_policy_checkpoint):
    _, cfg, labels = controller_for("l1_pid", tiny_policy_checkpoint, ["adaptation=none"])
    assert labels["adaptation"] == "l1"
    assert cfg.adaptation._target_.endswith("L1Adaptation")


def test_datt_fast_path_equals_torchrl_deterministic_action(tiny_policy_checkpoint):
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from datt.cli import load_actor
    from datt.control import DattController

    actor, _, _ = load_actor(tiny_policy_checkpoint)
    g = torch.Generator().manual_seed(0)
    td = TensorDict({"state": torch.randn(6, 13, generator=g), "ref": torch.randn(6, 10, 3, generator=g),
                     "d_hat": 3 * torch.randn(6, 3, generator=g)}, [6])  # fmt: skip
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = actor(td.clone())["action"]
    torch.testing.assert_close(DattController(actor).act(None, td), expected, rtol=1e-5, atol=1e-5)
