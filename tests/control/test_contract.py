"""Every controller option honours the interface: shapes, bounds, finite output, reset."""

import pytest
import torch
from omegaconf import OmegaConf

from datt.configuration import available_options, compose, conf_dir
from datt.control.factory import build_controller
from datt.envs.factory import make_env


def controller_for(option, checkpoint, extra=()):
    overrides = [f"controller={option}", f"checkpoint={checkpoint}", *extra]
    if "mppi" in option:
        overrides += ["controller.num_samples=32", "controller.horizon_steps=8", "controller.compile=false"]
    cfg = compose("eval", overrides)
    return build_controller(cfg)


@pytest.mark.parametrize("option", [o for o in available_options("controller") if o != "datt_rma"])
def test_contract(option, tiny_policy_checkpoint):
    ctrl, cfg, labels = controller_for(option, tiny_policy_checkpoint)
    assert labels["controller"] == OmegaConf.load(conf_dir() / "controller" / f"{option}.yaml").name
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

    from datt.control import DattController
    from datt.policies.loading import load_actor

    actor, train_cfg, _ = load_actor(tiny_policy_checkpoint)
    width = 13 + 4 * int(train_cfg.env.obs.action_history)  # the training default adds two commands
    g = torch.Generator().manual_seed(0)
    td = TensorDict(
        {
            "state": torch.randn(6, width, generator=g),
            "ref": torch.randn(6, 10, 3, generator=g),
            "d_hat": 3 * torch.randn(6, 3, generator=g),
        },
        [6],
    )
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = actor(td.clone())["action"]
    torch.testing.assert_close(DattController(actor).act(None, td), expected, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize(
    "encoder, body_frame, feedback, use_d_hat, error_scale, n, history",
    [
        ("conv", True, True, True, 1.0, 5, 0),
        ("conv", True, True, True, 8.0, 5, 0),
        ("conv", False, True, True, 1.0, 5, 0),
        ("conv", True, False, False, 1.0, 5, 0),
        ("mlp", True, True, True, 8.0, 5, 0),
        ("none", True, True, True, 8.0, 5, 0),
        ("conv", True, True, True, 8.0, 40, 0),
        ("conv", True, True, True, 8.0, 5, 2),
        ("none", True, True, True, 8.0, 5, 1),
        ("authors", True, True, True, 8.0, 5, 0),
        ("authors", True, True, True, 8.0, 40, 2),
    ],
)
def test_datt_frozen_path_equals_observation_plus_network(
    encoder, body_frame, feedback, use_d_hat, error_scale, n, history
):
    """The frozen path (bilinear rotation, encoder as dense layers up to DENSE_ENCODER_MAX_BATCH
    drones and as convs above, traced) computes the same action as the env's observation fed to
    the actor's network, on tilted, moving drones."""
    from datt.control import DattController
    from datt.envs.tracking import action_bounds
    from datt.policies.networks import PolicyParams, make_actor
    from datt.sim.frames import quat_from_euler

    cfg = compose(
        "eval",
        [
            "disturbance=brownian",
            "adaptation=privileged",
            "horizon=7",
            f"env.obs.body_frame={body_frame}",
            f"env.obs.feedback={feedback}",
            f"env.obs.action_history={history}",
        ],
    )
    env = make_env(cfg, num_envs=n, seed=3)
    p = PolicyParams(encoder=encoder, use_d_hat=use_d_hat, error_scale=error_scale)
    actor = make_actor(7, *action_bounds(env.params), p, env.state_dim)
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():  # weights of a trained net's scale, not the near-constant initial head
        for param in actor.parameters():
            param.copy_(0.2 * torch.randn(param.shape, generator=gen))
    env.reset()
    g = torch.Generator().manual_seed(0)
    s = env.sim.state
    s.quat.copy_(quat_from_euler(*(0.6 * torch.randn(3, n, generator=g))))
    s.vel_mps.copy_(torch.randn(n, 3, generator=g))
    for _ in range(history):  # distinct commands in the history
        env.record_command(env.action_low + (env.action_high - env.action_low) * torch.rand(n, 4, generator=g))
    td = env.observe()
    plain, frozen = DattController(actor, frozen=False), DattController(actor, frozen=True)
    plain.reset(env), frozen.reset(env)
    expected = plain.act(env, td)
    torch.testing.assert_close(frozen.act(env, td), expected, rtol=1e-4, atol=1e-4)
    assert (expected - expected[:1]).abs().max() > 1e-2  # the drones' states really differ


def test_one_frozen_controller_serves_envs_of_other_sizes_and_observation_settings():
    """The traced graph is kept per input shape and observation setting: the same frozen
    controller, flown on 3 drones, then 5, then 5 in the world frame, acts as the plain path on each."""
    from datt.control import DattController
    from datt.envs.tracking import action_bounds
    from datt.policies.networks import PolicyParams, make_actor
    from datt.sim.frames import quat_from_euler

    def env_of(n, body_frame):
        env = make_env(compose("eval", ["horizon=7", f"env.obs.body_frame={body_frame}"]), num_envs=n, seed=n)
        env.reset()
        g = torch.Generator().manual_seed(n)
        env.sim.state.quat.copy_(quat_from_euler(*(0.6 * torch.randn(3, n, generator=g))))
        env.sim.state.vel_mps.copy_(torch.randn(n, 3, generator=g))
        return env

    first = env_of(3, True)
    actor = make_actor(7, *action_bounds(first.params), PolicyParams(), first.state_dim)
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for param in actor.parameters():
            param.copy_(0.2 * torch.randn(param.shape, generator=gen))
    frozen = DattController(actor, frozen=True)
    for env in (first, env_of(5, True), env_of(5, False)):
        plain = DattController(actor, frozen=False)
        plain.reset(env), frozen.reset(env)
        expected = plain.act(env, env.observe())
        # the frozen one builds its own observation (callers pass none: builds_observation)
        torch.testing.assert_close(frozen.act(env, None), expected, rtol=1e-4, atol=1e-4)
    assert frozen.builds_observation is True and plain.builds_observation is False


@pytest.mark.parametrize("setting", ["predict_latency", "reference_lead"])
def test_the_frozen_path_sees_the_prediction_and_the_reference_lead_as_the_observation_does(setting):
    """What the policy answers behind a state predictor (``env.obs.predict_latency``, or the
    deployment's reference lead) is the same whether the env builds the observation or the frozen
    controller does: the frozen path once read the window now and missed the lead."""
    from datt.control import DattController
    from datt.envs.tracking import action_bounds
    from datt.policies.networks import PolicyParams, make_actor

    overrides = ["horizon=7", "traj=zigzag", "env.obs.action_history=2", "env.quad.latency_steps=3"]
    if setting == "predict_latency":
        overrides.append("env.obs.predict_latency=true")
    env = make_env(compose("eval", overrides), num_envs=4, seed=3)
    actor = make_actor(7, *action_bounds(env.params), PolicyParams(), env.state_dim)
    gen = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for param in actor.parameters():
            param.copy_(0.2 * torch.randn(param.shape, generator=gen))
    td = env.reset()
    for _ in range(4):  # varied commands in flight
        td["action"] = env.hover_action + torch.randn(4, 4, generator=gen) * torch.tensor([2.0, 2.0, 2.0, 0.5])
        td = env.step(td)["next"].exclude("reward", "done", "terminated", "truncated")
    if setting == "reference_lead":
        env.set_reference_lead(1.5)
    td = env.observe()
    plain, frozen = DattController(actor, frozen=False), DattController(actor, frozen=True)
    plain.reset(env), frozen.reset(env)
    expected = plain.act(env, td)
    torch.testing.assert_close(frozen.act(env, td), expected, rtol=1e-4, atol=1e-4)
    env.set_reference_lead(0.0)
    if setting == "reference_lead":  # and the lead changed what it answers
        assert (frozen.act(env, env.observe()) - expected).abs().max() > 1e-3
