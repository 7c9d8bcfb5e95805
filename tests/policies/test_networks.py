import pytest
import torch
from torchrl.envs.utils import ExplorationType, set_exploration_type

from datt.configuration import compose
from datt.envs.factory import make_env
from datt.errors import ConfigError
from datt.policies.networks import PolicyParams, RefEncoder, make_actor, make_critic


@pytest.mark.parametrize("horizon", [1, 5, 10, 20])
@pytest.mark.parametrize("encoder", ["conv", "mlp", "none", "authors"])
def test_actor_critic_shapes_for_every_horizon_and_encoder(horizon, encoder):
    env = make_env(compose("sim", [f"horizon={horizon}"]), num_envs=6)
    p = PolicyParams(encoder=encoder)
    actor = make_actor(horizon, env.action_low, env.action_high, p)
    critic = make_critic(horizon, p)
    td = env.reset()
    out = actor(td.clone())
    assert out["action"].shape == (6, 4) and out["action_log_prob"].shape == (6,)
    assert critic(td.clone())["state_value"].shape == (6, 1)
    assert (out["action"] >= env.action_low).all() and (out["action"] <= env.action_high).all()


def test_paper_encoder_structure():
    enc = RefEncoder(10, PolicyParams())
    convs = [m for m in enc.conv if isinstance(m, torch.nn.Conv1d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size[0]) for c in convs] == [(3, 16, 3), (16, 16, 3), (16, 16, 3)]
    assert enc.proj.out_features == 32 and enc(torch.zeros(7, 10, 3)).shape == (7, 32)


@pytest.mark.parametrize("horizon", [5, 10, 15, 20])
def test_the_authors_encoder_is_two_unpadded_convs_whose_width_grows_with_the_horizon(horizon):
    enc = RefEncoder(horizon, PolicyParams(encoder="authors"))
    convs = [m for m in enc.conv if isinstance(m, torch.nn.Conv1d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size[0], c.padding[0]) for c in convs] == [
        (3, 8, 3, 0),
        (8, 8, 3, 0),
    ]
    assert enc.out_dim == 8 * (horizon - 4)
    ref = torch.randn(4, horizon, 3)
    expect = convs[1](torch.relu(convs[0](ref.transpose(1, 2)))).flatten(1)  # no ReLU after the second
    assert torch.allclose(enc(ref), expect, atol=1e-6)


@pytest.mark.parametrize("horizon", [1, 4])
def test_the_authors_encoder_below_five_points_is_their_flatten_extractor(horizon):
    enc = RefEncoder(horizon, PolicyParams(encoder="authors"))
    ref = torch.randn(3, horizon, 3)
    assert enc.kind == "none" and enc.out_dim == 3 * horizon and torch.equal(enc(ref), ref.flatten(1))


def test_initial_policy_hovers():
    env = make_env(compose("sim"), num_envs=3)
    actor = make_actor(10, env.action_low, env.action_high, PolicyParams())
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        a = actor(env.reset())["action"]
    assert torch.allclose(a[:, 0], torch.full((3,), 9.81), atol=0.05)
    assert a[:, 1:].abs().max() < 0.05


def test_d_hat_input_can_be_disabled():
    env = make_env(compose("sim", ["disturbance=constant"]), num_envs=4)
    td = env.reset()
    for use in (True, False):
        torch.manual_seed(0)
        critic = make_critic(10, PolicyParams(use_d_hat=use))
        changed = td.clone()
        changed["d_hat"] = changed["d_hat"] + 1.0
        same = torch.allclose(critic(td.clone())["state_value"], critic(changed)["state_value"])
        assert same is (not use)


def test_the_asymmetric_critic_reads_critic_ref_and_the_actor_does_not():
    """``env.obs.critic_ref_points=K``: the critic's first layer is 3K wider and its value moves
    with ``critic_ref``; the actor's distribution ignores it."""
    env = make_env(compose("sim", ["env.obs.critic_ref_points=7"]), num_envs=4)
    td = env.reset()
    torch.manual_seed(0)
    critic = make_critic(10, PolicyParams(), env.state_dim, critic_points=7)
    plain = make_critic(10, PolicyParams(), env.state_dim)
    assert critic.module.mlp[0].in_features == plain.module.mlp[0].in_features + 21
    assert critic.in_keys == ["state", "ref", "d_hat", "critic_ref"] and plain.in_keys == ["state", "ref", "d_hat"]
    actor = make_actor(10, env.action_low, env.action_high, PolicyParams(), env.state_dim)
    changed = td.clone()
    changed["critic_ref"] = changed["critic_ref"] + 1.0
    assert not torch.allclose(critic(td.clone())["state_value"], critic(changed.clone())["state_value"])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        assert torch.equal(actor(td.clone())["action"], actor(changed)["action"])


@pytest.mark.parametrize(
    "kwargs, key",
    [
        ({"encoder": "lstm"}, "policy.encoder"),
        ({"kernel_size": 2}, "policy.kernel_size"),
        ({"hidden": []}, "policy.hidden"),
        ({"error_scale": 0.0}, "policy.error_scale"),
    ],
)
def test_bad_policy_params(kwargs, key):
    with pytest.raises(ConfigError, match=key):
        PolicyParams(**kwargs).validate()


@pytest.mark.parametrize("min_std", [0.0, 0.05, 0.2])
def test_the_std_floor_must_be_positive_and_below_the_initial_std(min_std):
    with pytest.raises(ConfigError) as info:
        PolicyParams(min_std=min_std, init_std=[0.15, 0.15, 0.05, 0.15]).validate()
    below = f"policy.min_std: must be > 0 and below every policy.init_std (0.05), got {min_std}"
    positive = f"policy.min_std: must be a finite number in (0, 10], got {min_std}"  # its own range, declared once
    assert str(info.value) == (positive if min_std <= 0 else below)
    PolicyParams(min_std=0.049, init_std=[0.15, 0.15, 0.05, 0.15]).validate()


@pytest.mark.parametrize("min_std", [1e-4, 0.01])
def test_the_policy_std_never_falls_below_its_floor(min_std):
    """A head that asks for a vanishing std (its std outputs driven to -50) gets exactly the
    floor; the location is untouched by it."""
    env = make_env(compose("sim"), num_envs=5)
    actor = make_actor(10, env.action_low, env.action_high, PolicyParams(min_std=min_std))
    td = env.reset()
    loc_before = actor(td.clone())["loc"]
    with torch.no_grad():
        head = actor.module[0].module.net.head
        head.weight[4:].zero_()
        head.bias[4:] = -50.0
    out = actor(td.clone())
    assert torch.equal(out["scale"], torch.full((5, 4), min_std))
    torch.testing.assert_close(out["loc"], loc_before)


def test_a_std_ceiling_bounds_the_std_on_both_sides_and_starts_at_init_std():
    """``policy.max_std``: the std starts at ``init_std`` exactly and stays within
    [min_std, max_std] for any head output (driven to ±50); the location is untouched by it."""
    env = make_env(compose("sim"), num_envs=5)
    p = PolicyParams(min_std=0.01, max_std=0.4, init_std=[0.15, 0.1, 0.1, 0.05])
    actor = make_actor(10, env.action_low, env.action_high, p)
    td = env.reset()
    out = actor(td.clone())
    torch.testing.assert_close(out["scale"], torch.tensor([[0.15, 0.1, 0.1, 0.05]]).expand(5, 4), atol=2e-3, rtol=0)
    head = actor.module[0].module.net.head
    for bias, bound in ((50.0, 0.4), (-50.0, 0.01)):
        with torch.no_grad():
            head.weight[4:].zero_()
            head.bias[4:] = bias
        moved = actor(td.clone())
        torch.testing.assert_close(moved["scale"], torch.full((5, 4), bound))
        torch.testing.assert_close(moved["loc"], out["loc"])


@pytest.mark.parametrize("max_std", [0.15, 0.1])
def test_the_std_ceiling_must_be_above_the_initial_std(max_std):
    with pytest.raises(ConfigError) as info:
        PolicyParams(max_std=max_std, init_std=[0.15, 0.15, 0.05, 0.15]).validate()
    assert str(info.value) == f"policy.max_std: must be null or above every policy.init_std (0.15), got {max_std}"
    PolicyParams(max_std=0.151, init_std=[0.15, 0.15, 0.05, 0.15]).validate()


def test_error_scale_multiplies_exactly_the_error_inputs():
    """error_scale = s equals the unscaled net fed s x (feedback error, feedforward errors) and
    the other inputs unchanged (position, velocity, quaternion, d_hat)."""
    from datt.policies.networks import TrackingNet

    torch.manual_seed(0)
    scaled, plain = TrackingNet(10, 8, PolicyParams(error_scale=5.0)), TrackingNet(10, 8, PolicyParams())
    plain.load_state_dict(scaled.state_dict())
    state, ref, d_hat = torch.randn(4, 13), torch.randn(4, 10, 3), torch.randn(4, 3)
    by_hand = state.clone()
    by_hand[:, 10:] *= 5.0
    torch.testing.assert_close(scaled(state, ref, d_hat), plain(by_hand, 5.0 * ref, d_hat))
    assert not torch.allclose(scaled(state, ref, d_hat), plain(state, ref, d_hat))
