"""TrackingEnv: specs, observations, reward, resets, reproducibility, config errors."""

import math

import pytest
import torch
from torchrl.envs.utils import check_env_specs

from datt.configuration import compose
from datt.envs.factory import make_env
from datt.errors import ConfigError
from datt.sim import Quadrotor
from datt.sim.frames import quat_from_euler, quat_rotate_inverse


@pytest.mark.parametrize(
    "overrides",
    [
        [],
        ["traj=star", "disturbance=brownian"],
        ["traj=mixed", "disturbance=wind", "adaptation=none"],
        ["traj=chained_poly", "disturbance=wind_plate", "horizon=1"],
        ["traj=fixed", "env.obs.body_frame=false", "env.obs.feedback=false", "horizon=20"],
        ["traj=polygon", "disturbance=constant", "env.dtype=float64", "env.quad.latency_steps=0"],
        ["traj=zigzag", "env.obs.action_history=3"],
        ["traj=zigzag", "env.obs.critic_ref_points=4", "env.obs.body_frame=false"],
        ["traj=zigzag", "env.obs.timing=authors", "env.obs.action_history=2"],
    ],
)
def test_check_env_specs(make_tracking_env, overrides):
    env = make_tracking_env(overrides, n=6)
    check_env_specs(env)
    td = env.rollout(20)
    assert td["next", "ref"].shape == (6, 20, env.horizon, 3)


def test_rollout_reproducible_with_seed(make_tracking_env):
    def run(seed):
        env = make_tracking_env(["disturbance=brownian", "env.obs.pos_noise_std_m=0.01"], n=4, seed=seed)
        torch.manual_seed(0)  # random actions come from the global RNG
        return env.rollout(30)

    a, b, c = run(1), run(1), run(2)
    assert torch.equal(a["next", "state"], b["next", "state"])
    assert not torch.equal(a["next", "state"], c["next", "state"])


def test_the_randomised_vehicles_come_from_the_envs_seed(make_tracking_env):
    """Domain randomisation draws from the env's generator: the same seed gives the same vehicles,
    whatever the global RNG did in between."""

    def vehicles(seed):
        env = make_tracking_env(["env.quad.mass_spread=0.05", "env.quad.latency_steps_max=3"], n=16, seed=seed)
        torch.rand(7)  # the global RNG moves between the two builds
        return env.sim.thrust_scale.clone(), env.sim.latency.delay.clone()

    (scale_a, delay_a), (scale_b, delay_b), (scale_c, _) = vehicles(3), vehicles(3), vehicles(4)
    assert torch.equal(scale_a, scale_b) and torch.equal(delay_a, delay_b)
    assert not torch.equal(scale_a, scale_c)


def test_drones_start_at_rest_at_independent_points_of_the_start_cube(make_tracking_env):
    """Each drone draws its own start, uniform in ±init_pos_range_m per axis (0.5 m here), drawn
    in the env's dtype (a float64 env's starts are not float32 numbers)."""
    env = make_tracking_env(["env.dtype=float64"], n=64)
    pos = env.sim.state.pos_m
    assert pos.abs().max() <= 0.5 and pos.abs().max() > 0.4
    assert len(torch.unique(pos[:, 0])) == 64 and torch.equal(
        env.sim.state.vel_mps, torch.zeros(64, 3, dtype=torch.float64)
    )
    assert not torch.equal(pos, pos.float().double())


@pytest.mark.parametrize("r", [0.5, 0.2])
def test_the_start_offsets_are_uniform_on_the_whole_cube(make_tracking_env, r):
    """U(−r, r) per axis, independently: both tails reached, mean 0 and variance r² / 3 (within
    ~6 standard errors over 4096 drones), half of the drones on each side of every axis."""
    env = make_tracking_env(["env.dtype=float64", f"env.init_pos_range_m={r}"], n=4096)
    start = env.sim.state.pos_m  # around the origin, where every reference starts
    n = start.shape[0]
    assert start.abs().max() <= r
    assert (start.min(0).values < -0.98 * r).all() and (start.max(0).values > 0.98 * r).all()
    assert start.mean(0).abs().max() < 6 * r / math.sqrt(3 * n)
    var = r * r / 3
    assert (start.var(0) - var).abs().max() < 6 * var * math.sqrt(0.8 / n)  # Var of s² for a uniform: 0.8 σ⁴ / n
    assert ((start > 0).double().mean(0) - 0.5).abs().max() < 6 * 0.5 / math.sqrt(n)
    corr = torch.corrcoef(start.T)
    assert (corr - torch.eye(3, dtype=corr.dtype)).abs().max() < 6 / math.sqrt(n)


def test_the_done_entries_are_binary_specs_of_one_flag_per_drone(make_tracking_env):
    from torchrl.data import Categorical

    env = make_tracking_env([], n=3)
    binary = Categorical(2, shape=(3, 1), dtype=torch.bool)
    assert {k: env.full_done_spec[k] for k in ("done", "terminated", "truncated")} == dict.fromkeys(
        ("done", "terminated", "truncated"), binary
    )


def hover_rollout(env, steps):
    td = env.reset()
    out = []
    for _ in range(steps):
        td["action"] = env.hover_action
        step, td = env.step_and_maybe_reset(td)
        out.append(step)
    return torch.stack(out, dim=1)


def direct_refs(env):
    """Reference points read straight from the table (what the ring buffer must reproduce)."""
    idx = env.step_idx[:, None] + env.ref_offsets
    return env.ref_table.gather(1, idx[..., None].expand(-1, -1, 3))


def test_observation_layout_body_frame(make_tracking_env):
    env = make_tracking_env(["traj=zigzag"], n=5)
    env.reset()
    # put the drones in known attitudes and states
    yaw = torch.tensor([0.0, 0.5, -1.0, 2.0, 3.0])
    env.sim.state.quat = quat_from_euler(torch.full((5,), 0.1), torch.full((5,), -0.2), yaw)
    env.sim.state.vel_mps = torch.randn(5, 3)
    obs = env.observe()
    s = env.sim.state
    refs = direct_refs(env)  # [N, H, 3]
    q = s.quat
    assert torch.allclose(obs["state"][:, 0:3], quat_rotate_inverse(q, s.pos_m), atol=1e-6)
    assert torch.allclose(obs["state"][:, 3:6], quat_rotate_inverse(q, s.vel_mps), atol=1e-6)
    assert torch.equal(obs["state"][:, 6:10], q)
    assert torch.allclose(obs["state"][:, 10:13], quat_rotate_inverse(q, s.pos_m - refs[:, 0]), atol=1e-6)
    expect_ref = quat_rotate_inverse(q[:, None], s.pos_m[:, None] - refs)
    assert torch.allclose(obs["ref"], expect_ref, atol=1e-6)
    # the points are spaced by ref_spacing_s = 3 steps
    assert env.ref_offsets.tolist() == [3 * i for i in range(10)]


def test_ablations_change_exactly_their_inputs(make_tracking_env):
    """As the authors' trajectory_fbff.py: no body frame = world-frame p, v and feedback error,
    and the raw future reference positions as the feedforward input; no feedback = the absolute
    position leaves the state (zeroed), the feedback error stays."""
    base, world, nofb = (
        make_tracking_env(o, n=4) for o in ([], ["env.obs.body_frame=false"], ["env.obs.feedback=false"])
    )
    q = quat_from_euler(torch.full((4,), 0.3), torch.full((4,), 0.2), torch.full((4,), 1.0))
    for env in (base, world, nofb):
        env.reset()
        env.sim.state.quat = q.clone()
        env.sim.state.vel_mps = torch.ones(4, 3)
    ob, ow, on = (e._observe()[0] for e in (base, world, nofb))
    s = world.sim.state
    refs = direct_refs(world)
    assert torch.allclose(ow["state"][:, :3], s.pos_m) and torch.allclose(ow["state"][:, 3:6], s.vel_mps)
    assert torch.allclose(ow["state"][:, 10:13], s.pos_m - refs[:, 0])  # world-frame feedback error
    assert torch.allclose(ow["ref"], refs)  # where the reference goes: positions, not errors
    assert not torch.allclose(ow["ref"], s.pos_m[:, None] - refs)
    assert torch.equal(ow["state"][:, 6:10], ob["state"][:, 6:10])  # quaternion untouched
    assert torch.equal(on["state"][:, :3], torch.zeros(4, 3))
    assert not torch.equal(ob["state"][:, :3], torch.zeros(4, 3))
    assert torch.equal(on["state"][:, 3:], ob["state"][:, 3:]) and torch.equal(on["ref"], ob["ref"])
    assert torch.equal(on["d_hat"], ob["d_hat"])


def test_action_history_holds_the_last_commands_scaled_and_restarts_at_hover(make_tracking_env):
    """``obs.action_history=2`` appends the last two applied (clamped) commands, scaled to
    [-1, 1] by the bounds, oldest first; the paper's 13 entries are unchanged; a reset drone's
    history reads hover."""
    env, plain = make_tracking_env(["env.obs.action_history=2"], n=3), make_tracking_env([], n=3)
    assert env.state_dim == 21 and env.observation_spec["state"].shape == (3, 21)
    td, td_plain = env.reset(), plain.reset()
    hover = (env.hover_action[0] - (env.action_high + env.action_low) / 2) / ((env.action_high - env.action_low) / 2)
    assert torch.allclose(td["state"][:, 13:], hover.repeat(2).expand(3, 8))
    assert hover[0] < 0 and torch.all(hover[1:] == 0)  # hover thrust g sits below the middle of [g - 9.8, g + 30]
    a1 = torch.tensor([[12.0, 1.0, -2.0, 0.5]]).expand(3, 4)
    a2 = torch.tensor([[100.0, -50.0, 4.0, 0.0]]).expand(3, 4)  # thrust and wx beyond the bounds
    for a in (a1, a2):
        td["action"], td_plain["action"] = a, a
        td, td_plain = env.step(td)["next"], plain.step(td_plain)["next"]
    torch.testing.assert_close(td["state"][:, :13], td_plain["state"])
    half = (env.action_high - env.action_low) / 2
    expected_a1 = (a1 - (env.action_high + env.action_low) / 2) / half
    torch.testing.assert_close(td["state"][:, 13:17], expected_a1)
    torch.testing.assert_close(td["state"][:, 17:], torch.tensor([[1.0, -1.0, 0.2, 0.0]]).expand(3, 4))
    td["_reset"] = torch.tensor([[True], [False], [False]])
    out = env.reset(td)
    assert torch.allclose(out["state"][0, 13:], hover.repeat(2))
    torch.testing.assert_close(env.cmd_history[1:, 1], torch.tensor([[1.0, -1.0, 0.2, 0.0]]).expand(2, 4))


@pytest.mark.parametrize("body_frame", [True, False])
def test_critic_ref_is_the_reference_beyond_the_window(make_tracking_env, body_frame):
    """``obs.critic_ref_points=K``: ``critic_ref`` holds R^T (p − p_d(t + kΔc)), k = 1..K, from
    the true state (raw p_d(t + kΔc) without the body frame), through steps, partial resets and
    the end of the episode's table; the policy's keys are the plain env's."""
    over = ["traj=zigzag", "env.episode_steps=60", "disturbance=constant", f"env.obs.body_frame={body_frame}"]
    env = make_tracking_env([*over, "env.obs.critic_ref_points=6", "env.obs.critic_ref_spacing_s=0.3"], n=5)
    plain = make_tracking_env(over, n=5)
    assert env.observation_spec["critic_ref"].shape == (5, 6, 3)
    assert set(env.observation_spec.keys()) - set(plain.observation_spec.keys()) == {"critic_ref"}
    assert env.table_len == 60 + 6 * 15 + 1  # reaches p_d(t + 1.8 s) at the last step
    td = env.reset()
    gen = torch.Generator().manual_seed(1)
    for k in range(140):  # beyond two episodes: truncations and resets on the way
        td["action"] = env.hover_action + 2.0 * torch.randn(5, 4, generator=gen) * torch.tensor([1.0, 0.3, 0.3, 0.1])
        td = env.step(td)["next"]
        s = env.sim.state
        steps = (env.step_idx.unsqueeze(1) + torch.arange(1, 7) * 15).clamp_max(env.table_len - 1)
        points = env.ref_table[torch.arange(5).unsqueeze(1), steps]  # [N, K, 3]
        expected = quat_rotate_inverse(s.quat.unsqueeze(1), s.pos_m.unsqueeze(1) - points) if body_frame else points
        torch.testing.assert_close(td["critic_ref"], expected)
        assert not torch.equal(td["critic_ref"][:, 0], td["critic_ref"][:, -1])
        done = td["done"].reshape(-1) | (torch.arange(5) == k % 5) & (k % 23 == 7)
        if done.any():
            td["_reset"] = done.unsqueeze(-1)
            td = env.reset(td)
            torch.testing.assert_close(td["critic_ref"][done], env._critic_ref()[done])


def test_ring_buffer_matches_table_through_steps_and_partial_resets(make_tracking_env):
    env = make_tracking_env(["traj=zigzag", "env.episode_steps=40", "disturbance=constant"], n=6)
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    for k in range(130):
        td["action"] = env.hover_action
        if k % 17 == 5:  # force a partial reset of random drones
            td["_reset"] = torch.rand(6, 1, generator=gen) < 0.4
            td = env.reset(td)
        _, td = env.step_and_maybe_reset(td)
        w = env.ref_window.index_select(0, (env._head + env.ref_offsets) % env.window).transpose(0, 1)
        assert torch.equal(w, direct_refs(env)), k


def test_ring_buffer_matches_table_up_to_the_last_step_of_an_episode(make_tracking_env):
    """Without the automatic reset the final, truncated step is observed too: its window reads
    the table's last row (the table is exactly episode_steps + window rows long)."""
    env = make_tracking_env(["traj=zigzag", "env.episode_steps=30"], n=3)
    td = env.reset()
    assert env.table_len == 30 + env.window
    for k in range(30):
        td["action"] = env.hover_action
        td = env.step(td)["next"]
        w = env.ref_window.index_select(0, (env._head + env.ref_offsets) % env.window).transpose(0, 1)
        assert torch.equal(w, direct_refs(env)), k
    assert td["truncated"].all() and torch.equal(w[:, -1], env.ref_table[:, -1])


def _hover_at(env, pos_m):
    """Reset, place every drone level and at rest at ``pos_m [N, 3]``, hover one step."""
    td = env.reset()
    env.sim.state.pos_m = pos_m.clone()
    env.sim.state.vel_mps = torch.zeros_like(pos_m)
    td["action"] = env.hover_action
    return env.step(td)["next"]


def test_a_drone_on_the_face_of_the_safety_box_is_still_inside(make_tracking_env):
    """Leaving the box means |p| > half-extent: at exactly the face (x = 3 m, the lateral position
    unchanged by a level hover step) the drone flies on; 1 mm further out it is terminated."""
    env = make_tracking_env(["env.safety_box_m=[3.0,3.0,2.0]", "env.init_pos_range_m=0"], n=2)
    pos = torch.tensor([[3.0, 0.0, 0.0], [3.001, 0.0, 0.0]])
    out = _hover_at(env, pos)
    assert env.sim.state.pos_m[0, 0].item() == 3.0
    assert out["terminated"][:, 0].tolist() == [False, True]


def test_the_tracking_error_limit_adds_to_the_box(make_tracking_env):
    """With ``max_tracking_error_m`` set, leaving the box still terminates (the two conditions are
    or-ed), an error above the limit terminates inside the box, and an error of exactly the limit
    does not. The reference is the origin (a zigzag of range 0), so the errors are exact."""
    env = make_tracking_env(
        [
            "traj=zigzag",
            "traj.range_m=0",
            "env.safety_box_m=[1.0,3.0,2.0]",
            "env.init_pos_range_m=0",
            "env.max_tracking_error_m=2.5",
        ],
        n=4,
    )
    pos = torch.tensor([[1.2, 0.0, 0.0], [0.0, 2.5, 0.0], [0.0, 2.6, 0.0], [0.5, 0.0, 0.0]])
    out = _hover_at(env, pos)
    assert env.reference_now_m().abs().max() == 0
    assert (env.sim.state.pos_m - pos).abs()[:, :2].max() == 0  # a level hover step moves no drone sideways
    assert out["terminated"][:, 0].tolist() == [True, False, True, False]


def test_a_non_finite_state_ends_the_episode_with_exactly_the_crash_penalty(make_tracking_env):
    """A drone whose position is NaN or infinite has a NaN or infinite cost; its step is
    terminated with reward −crash_penalty exactly (the cost counts as 0, so neither NaN nor ±inf
    reaches GAE), while a finite drone's reward is its cost."""
    env = make_tracking_env(["env.init_pos_range_m=0"], n=3)
    pos = torch.tensor([[float("nan"), 0.0, 0.0], [float("inf"), 0.0, 0.0], [0.0, 0.0, 0.0]])
    out = _hover_at(env, pos)
    penalty = env.params.reward.crash_penalty
    assert out["terminated"][:, 0].tolist() == [True, True, False]
    assert out["reward"][:2, 0].tolist() == [-penalty, -penalty]
    assert torch.isfinite(out["reward"]).all() and -1.0 < out["reward"][2, 0] < 0


def test_staggered_first_episodes_are_uniform_over_one_to_the_episode_length(make_tracking_env):
    """``stagger_episodes``: at the next full reset each drone's first episode gets a length drawn
    from U{1, ..., episode_steps} with the env's generator (the global RNG plays no part); later
    resets give the full length again."""

    def lengths(global_seed):
        env = make_tracking_env(["env.episode_steps=4"], n=4000, seed=7)
        torch.manual_seed(global_seed)
        env.stagger_episodes()
        env.reset()
        return env, env.episode_len.clone()

    env, first = lengths(0)
    counts = torch.bincount(first, minlength=6).tolist()
    assert counts[0] == 0 and counts[5] == 0 and all(850 < c < 1150 for c in counts[1:5]), counts
    assert torch.equal(first, lengths(1)[1])
    env.reset()
    assert (env.episode_len == 4).all()


def test_a_partial_reset_computes_only_the_reset_drones(make_tracking_env):
    """``_reset`` with a ``_reset`` mask observes only those drones (TorchRL keeps the previous
    observation of the others): their rows equal a full observation, the other rows are zero."""
    env = make_tracking_env(["traj=zigzag"], n=4)
    td = env.reset()
    for _ in range(5):
        td["action"] = env.hover_action
        td = env.step(td)["next"]
    mask = torch.tensor([[False], [True], [False], [True]])
    out = env._reset(td.clone().set("_reset", mask))
    full = env.observe()
    for key in ("state", "ref"):
        assert torch.equal(out[key][[1, 3]], full[key][[1, 3]]), key
        assert out[key][[0, 2]].abs().max() == 0, key


def test_a_bare_tracking_env_has_the_papers_horizon_and_seed_zero():
    """``TrackingEnv(n, family)`` in a notebook: H = 10 and the references of seed 0."""
    from datt.envs.tracking import TrackingEnv
    from datt.refs import Zigzag

    bare = TrackingEnv(3, Zigzag())
    seeded = TrackingEnv(3, Zigzag(), horizon=10, seed=0)
    unseeded = TrackingEnv(3, Zigzag(), seed=None)  # None means 0 too
    assert bare.horizon == 10 and bare.reset()["ref"].shape[-2:] == (10, 3)
    seeded.reset()
    unseeded.reset()
    assert torch.equal(bare.ref_table, seeded.ref_table) and torch.equal(bare.ref_table, unseeded.ref_table)


def test_tracking_env_arguments_reach_the_simulator_and_are_checked():
    from datt.envs.params import EnvParams
    from datt.envs.tracking import TrackingEnv
    from datt.errors import ConfigError
    from datt.refs import Zigzag

    env = TrackingEnv(2, Zigzag(), params=EnvParams(dt_s=0.01))
    assert env.dt_s == env.sim.dt_s == 0.01
    with pytest.raises(ConfigError) as info:
        TrackingEnv(0, Zigzag())
    assert str(info.value) == "num_envs: must be >= 1, got 0"


def test_the_reference_table_is_the_family_at_exact_multiples_of_dt(make_tracking_env):
    """Row k of the table is p_d(k dt) with k dt computed in float64 (the star: deterministic)."""
    from hydra.utils import instantiate

    env = make_tracking_env(["traj=star", "env.dtype=float64"], n=2)
    env.reset()
    t_s = torch.arange(env.table_len, dtype=torch.float64) * env.dt_s
    want = instantiate(compose("sim", ["traj=star"]).traj).sample(1, t_s, torch.Generator())[0]
    assert env.ref_table.dtype == torch.float64 and torch.equal(env.ref_table[1], want)


def test_a_float64_env_keeps_every_tensor_in_float64(make_tracking_env):
    """No silent float32 rounding in a float64 env: action bounds and spec, command history,
    safety box and the observation all carry the env's dtype."""
    env = make_tracking_env(["env.dtype=float64", "env.obs.action_history=2"], n=2)
    td = env.reset()
    td["action"] = env.hover_action
    out = env.step(td)["next"]
    tensors = {
        "action_low": env.action_low,
        "action_high": env.action_high,
        "action_spec": env.action_spec,
        "cmd_history": env.cmd_history,
        "box_m": env.box_m,
        "state": out["state"],
        "ref": out["ref"],
    }
    assert {k: v.dtype for k, v in tensors.items()} == dict.fromkeys(tensors, torch.float64)


def test_a_float64_envs_action_bounds_are_the_configs_numbers_exactly(make_tracking_env):
    """g + thrust offsets and the rate bounds, computed in float64 (no float32 rounding on the way)."""
    env = make_tracking_env(["env.dtype=float64", "env.rate_bounds_radps=[20.1,19.9,2.1]"], n=2)
    p = env.params
    g, (lo_t, hi_t) = p.quad.gravity_mps2, p.thrust_offset_bounds_mps2
    assert env.action_low.tolist() == [g + lo_t, -20.1, -19.9, -2.1]
    assert env.action_high.tolist() == [g + hi_t, 20.1, 19.9, 2.1]


def test_partial_reset_only_resets_done_drones(make_tracking_env):
    env = make_tracking_env(["disturbance=brownian"], n=5)
    td = env.reset()
    for _ in range(15):
        td["action"] = env.hover_action
        _, td = env.step_and_maybe_reset(td)
    pos = env.sim.state.pos_m.clone()
    table = env.ref_table.clone()
    d = env.disturbance.current_mps2.clone()
    state_obs = td["state"].clone()
    mask = torch.tensor([True, False, True, False, False]).unsqueeze(-1)
    td["_reset"] = mask
    out = env.reset(td)
    keep = ~mask.squeeze(-1)
    assert env.step_idx.tolist() == [0, 15, 0, 15, 15]
    assert torch.equal(env.sim.state.pos_m[keep], pos[keep])
    assert torch.equal(env.ref_table[keep], table[keep]) and not torch.equal(env.ref_table[~keep], table[~keep])
    assert torch.equal(env.disturbance.current_mps2[keep], d[keep])
    assert not torch.equal(env.disturbance.current_mps2[~keep], d[~keep])
    assert torch.equal(out["state"][keep], state_obs[keep])
    assert not torch.equal(out["state"][~keep], state_obs[~keep])
    assert env.sim.state.pos_m[~keep].abs().max() <= env.params.init_pos_range_m
    assert env.sim.state.vel_mps[~keep].abs().max() == 0


def test_truncation_after_exactly_episode_steps(make_tracking_env):
    env = make_tracking_env(["env.episode_steps=25"], n=3)
    data = hover_rollout(env, 60)
    trunc = data["next", "truncated"][0, :, 0]
    assert trunc.nonzero().squeeze(-1).tolist() == [24, 49]
    assert not data["next", "terminated"].any()


def test_termination_when_leaving_safety_box(make_tracking_env):
    env = make_tracking_env(["env.safety_box_m=[3.0,3.0,0.5]", "env.init_pos_range_m=0"], n=2)
    td = env.reset()
    steps = 0
    while True:
        td["action"] = env.hover_action
        td["action"][0, 0] = 0.0  # drone 0 falls, drone 1 hovers
        step, td = env.step_and_maybe_reset(td)
        steps += 1
        if step["next", "terminated"].any():
            break
    assert step["next", "terminated"][:, 0].tolist() == [True, False]
    # the step at which a standalone sim with the same command first drops below -0.5 m
    quad = Quadrotor(1)
    expect = next(k for k in range(1, 100) if quad.step(torch.zeros(1, 4)).pos_m[0, 2] < -0.5)
    assert steps == expect and 16 < expect < 22  # free fall alone would take 16 steps
    crash_reward = step["next", "reward"][0, 0].item()
    assert crash_reward < -env.params.reward.crash_penalty + 1e-3
    assert env.step_idx[0] == 0  # was reset; drone 1 kept going
    assert env.step_idx[1] == steps


def test_reward_matches_hand_computed_value(make_tracking_env):
    env = make_tracking_env(["traj=fixed", "env.init_pos_range_m=0", "env.quad.latency_steps=0"], n=1)
    td = env.reset()
    td["action"] = env.hover_action
    step = env.step(td)
    s = env.sim.state
    ref = direct_refs(env)[0, 0]
    err = (s.pos_m[0] - ref).norm().item()
    speed = min(s.vel_mps[0].norm().item(), 1.0)
    assert step["next", "reward"].item() == pytest.approx(-(err + 0.5 * 0.0 + 0.1 * speed), abs=1e-6)
    assert step["next", "tracking_error_m"].item() == pytest.approx(err, abs=1e-6)
    # a yawed drone pays 0.5 |yaw| (wrapped)
    env.sim.state.quat = quat_from_euler(torch.zeros(1), torch.zeros(1), torch.tensor([-3.0]))
    td = step["next"].clone()
    td["action"] = torch.tensor([[9.81, 0.0, 0.0, 0.0]])
    step = env.step(td)
    s = env.sim.state
    err = (s.pos_m[0] - direct_refs(env)[0, 0]).norm().item()
    speed = min(s.vel_mps[0].norm().item(), 1.0)
    assert step["next", "reward"].item() == pytest.approx(-(err + 0.5 * 3.0 + 0.1 * speed), abs=1e-5)


def test_the_rate_change_cost_is_the_body_rate_commands_step_to_step_change(make_tracking_env):
    """``reward.rate_change`` = w adds w ‖ω_cmd(t) − ω_cmd(t − 1)‖ to the cost: two envs that differ
    only in w fly the same commands (a rate step at one instant, a command beyond the bounds, a
    repeat) and their rewards differ by exactly that; the first step after a reset is measured
    against hover's zero rates, the thrust's change costs nothing."""
    base = ["traj=fixed", "env.init_pos_range_m=0", "env.quad.latency_steps=0"]
    plain = make_tracking_env(base, n=2)
    smooth = make_tracking_env([*base, "env.reward.rate_change=0.5"], n=2)
    low, high = plain.action_low[1:].tolist(), plain.action_high[1:].tolist()
    commands = [
        [[9.81, 0.0, 0.0, 0.0], [12.0, 1.0, -2.0, 2.0]],  # drone 1: a step from hover at t = 0
        [[9.81, 0.0, 0.0, 0.0], [12.0, 1.0, -2.0, 2.0]],  # held: no change
        [[5.0, 0.0, 3.0, 0.0], [9.81, 1.0, -1000.0, 1.0]],  # a step in pitch; a pitch rate beyond the bound
    ]
    applied = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    tds = [plain.reset(), smooth.reset()]
    for cmd in commands:
        action = torch.tensor(cmd)
        expected = []
        for i in range(2):
            now = [min(max(float(c), lo), hi) for c, lo, hi in zip(cmd[i][1:], low, high)]
            expected.append(0.5 * math.dist(now, applied[i]))
            applied[i] = now
        steps = []
        for env, td in zip((plain, smooth), tds):
            td["action"] = action.clone()
            steps.append(env.step(td))
        diff = (steps[0]["next", "reward"] - steps[1]["next", "reward"])[:, 0]
        assert diff.tolist() == pytest.approx(expected, abs=1e-5)
        tds = [s["next"].clone() for s in steps]
    assert expected[1] > 0 and applied[1][1] == low[1] > -1000  # the clipped pitch rate was charged as sent
    for env in (plain, smooth):  # a reset measures the next step against hover again
        env.reset()
    action = torch.tensor([[9.81, 0.0, 0.0, 1.0]] * 2)
    rewards = []
    for env in (plain, smooth):
        td = env.reset()
        td["action"] = action.clone()
        rewards.append(env.step(td)["next", "reward"][:, 0])
    assert (rewards[0] - rewards[1]).tolist() == pytest.approx([0.5, 0.5], abs=1e-5)


def test_actions_are_clipped_to_bounds(make_tracking_env):
    env = make_tracking_env(["env.quad.latency_steps=0", "env.quad.k_rate=1.0"], n=1)
    td = env.reset()
    td["action"] = torch.tensor([[1000.0, 1000.0, -1000.0, 1000.0]])
    env.step(td)
    assert env.sim.state.rate_radps[0].tolist() == pytest.approx([20.0, -20.0, 2.0])
    assert env.action_spec.space.high[0].tolist() == pytest.approx([9.81 + 30.0, 20.0, 20.0, 2.0])


def test_d_hat_privileged_and_none(make_tracking_env):
    priv = make_tracking_env(["disturbance=brownian"], n=4)
    zero = make_tracking_env(["disturbance=brownian", "adaptation=none"], n=4)
    for env in (priv, zero):
        data = hover_rollout(env, 5)
        d = env.disturbance.current_mps2
        if env is priv:
            assert torch.equal(data["next", "d_hat"][:, -1], d) and d.abs().max() > 0
        else:
            assert data["next", "d_hat"].abs().max() == 0


def test_disturbance_moves_the_drone(make_tracking_env):
    calm = hover_rollout(make_tracking_env(["env.init_pos_range_m=0"], n=64), 50)
    windy = hover_rollout(make_tracking_env(["env.init_pos_range_m=0", "disturbance=constant"], n=64), 50)
    assert calm["next", "tracking_error_m"][:, -1].max() < windy["next", "tracking_error_m"][:, -1].mean()


@pytest.mark.parametrize(
    "overrides, message",
    [
        (
            ["traj=spiral"],
            "traj: unknown option 'spiral'; allowed: chained_poly, csv, fixed, mixed, mixed_authors, poly, "
            "poly_authors, polygon, star, train_mix, train_mix_fast, zigzag, zigzag_fast, zigzag_iid",
        ),
        (
            ["disturbance=storm"],
            "disturbance: unknown option 'storm'; allowed: brownian, constant, constant_authors, none, plate, wind, "
            "wind_plate",
        ),
        (["horizon=-2"], "horizon: must be an integer in [1, 1000]"),
        (["horizon=0"], "horizon: must be an integer in [1, 1000]"),
        (["horizon=ten"], "horizon: must be an integer in [1, 1000]"),
        (["env.dt_s=-0.02"], "env.dt_s: must be a finite number in (0, 1]"),
        (["env.dt_s=fast"], "env.dt_s: Value 'fast'"),
        (["env.ref_spacing_s=0.05"], "env.ref_spacing_s: must be a whole multiple of env.dt_s"),
        (["env.dtype=float16"], "env.dtype: unknown value 'float16'; allowed: float32, float64"),
        (["env.obs.action_history=-1"], "env.obs.action_history: must be an integer in [0, 100]"),
        (["env.obs.critic_ref_points=-1"], "env.obs.critic_ref_points: must be an integer in [0, 1000]"),
        (["env.obs.critic_ref_spacing_s=0.05"], "env.obs.critic_ref_spacing_s: must be a whole multiple of env.dt_s"),
        (["env.obs.critic_ref_spacing_s=0"], "env.obs.critic_ref_spacing_s: must be a finite number in (0, 10]"),
        (["env.quad.k_thrust=2"], "env.quad.k_thrust: must be a finite number in (0, 1]"),
        (["env.safety_box_m=[1,1]"], "env.safety_box_m"),
        (["env.colour=red"], "env.colour: no such key"),
        (["traj=csv"], "traj.path"),
        (["traj=zigzag", "traj.seg_min_s=2.0"], "traj.seg_min_s/seg_max_s"),
    ],
)
def test_bad_config_gives_one_line_error_naming_the_key(overrides, message):
    with pytest.raises(ConfigError) as info:
        make_env(compose("sim", overrides), num_envs=2)
    text = str(info.value)
    assert message in text and "\n" not in text, text


@pytest.mark.slow
def test_compiled_kernels_match_eager(make_tracking_env):
    eager = make_tracking_env(["disturbance=brownian"], n=64)
    compiled = make_tracking_env(["disturbance=brownian"], n=64).compile_kernels()
    a, b = hover_rollout(eager, 40), hover_rollout(compiled, 40)
    for key in ("state", "ref", "reward"):
        assert torch.allclose(a["next", key], b["next", key], atol=1e-4), key


def test_compile_kernels_wires_every_kernel(make_tracking_env):
    """``compile_kernels`` swaps in the compiled integrator, observation/reward kernel and L1
    update (the ``eager`` backend: the wiring, without the 30 s of inductor) and the rollout is
    unchanged; ``repr`` names the parts."""
    overrides = ["disturbance=brownian", "adaptation=l1"]
    eager = make_tracking_env(overrides, n=8)
    compiled = make_tracking_env(overrides, n=8)
    assert compiled.compile_kernels(backend="eager") is compiled
    assert compiled._observe_kernel.__name__ == "compiled_observe_and_cost"
    from datt.sim.quadrotor import integrate

    assert eager.sim._integrate is integrate and compiled.sim._integrate is not integrate  # sim=True by default
    assert eager.adaptation._compiled is None and compiled.adaptation._compiled is not None
    a, b = hover_rollout(eager, 20), hover_rollout(compiled, 20)
    for key in ("state", "ref", "reward"):
        assert torch.equal(a["next", key], b["next", key]), key
    assert repr(eager) == (
        "TrackingEnv(num_envs=8, horizon=10, traj=Zigzag, disturbance=Brownian, adaptation=L1Adaptation)"
    )
    assert eager.ref_lookahead_s() == pytest.approx(9 * 0.06)  # H = 10 points 0.06 s apart, the first at t


def test_reward_velocity_term_is_capped():
    """At 3 m/s (cap 1 m/s), on the reference and level: cost = vel * 1, not vel * 3."""
    from datt.envs.observations import observe_and_cost
    from datt.envs.params import ObsParams, RewardParams

    pos = torch.zeros(1, 3)
    vel = torch.tensor([[3.0, 0.0, 0.0]])
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]])
    future = torch.zeros(2, 1, 3)
    reward = RewardParams(pos=1.0, yaw=0.5, vel=0.1, vel_cap_mps=1.0)
    _, _, err, cost = observe_and_cost(pos, vel, quat, pos, vel, quat, future, ObsParams(), reward)
    assert err.item() == 0.0 and cost.item() == pytest.approx(0.1)


def test_reward_velocity_term_is_per_drone():
    """Two drones, one at rest and one at 0.5 m/s: each pays for its own speed only."""
    from datt.envs.observations import observe_and_cost
    from datt.envs.params import ObsParams, RewardParams

    pos = torch.zeros(2, 3)
    vel = torch.tensor([[0.0, 0.0, 0.0], [0.3, 0.4, 0.0]])
    quat = torch.tensor([[1.0, 0.0, 0.0, 0.0]]).repeat(2, 1)
    reward = RewardParams(pos=1.0, yaw=0.5, vel=0.1, vel_cap_mps=1.0)
    _, _, _, cost = observe_and_cost(pos, vel, quat, pos, vel, quat, torch.zeros(2, 2, 3), ObsParams(), reward)
    assert cost.shape == (2, 1) and cost[:, 0].tolist() == pytest.approx([0.0, 0.05])


def test_commands_above_the_thrust_ceiling_reach_history_and_l1_as_the_ceiling(make_tracking_env):
    """With ``quad.max_thrust_mps2`` = 12 (a vehicle's ceiling), asking 30 m/s² is the same step
    as asking 12 for the simulator, the command history and L1's d̂ (which would otherwise read
    the 18 m/s² never delivered as a disturbance and run away)."""
    over = ["env.quad.max_thrust_mps2=12.0", "env.obs.action_history=2", "adaptation=l1", "env.init_pos_range_m=0"]
    outs = []
    for thrust in (30.0, 12.0):
        env = make_tracking_env(over, n=2)
        td = env.reset()
        td["action"] = torch.tensor([[thrust, 0.0, 0.0, 0.0]] * 2)
        env.step(td)
        outs.append((env.cmd_history.clone(), env.adaptation.d_hat.clone(), env.sim.state.vel_mps.clone()))
    for a, b in zip(*outs):
        assert torch.equal(a, b)
    assert env.command_high[0].item() == 12.0 and env.action_high[0].item() == pytest.approx(9.81 + 30.0)


def test_behind_a_trimmed_map_each_drone_is_clamped_at_its_own_ceiling(make_tracking_env):
    """``env.quad.thrust_map_trimmed``: every drone's map clips at its own ceiling
    (``max_thrust_mps2 · gain / mass``) or at ``max_thrust_mps2``, the lower (as deploy's flight
    model, whose ceiling the trim can only lower): a full-thrust request reaches the command
    history and L1 as that, per drone, and a request under every ceiling passes unchanged;
    check_env_specs holds."""
    over = [
        "env.quad.max_thrust_mps2=12.0",
        "env.quad.mass_spread=0.1",
        "env.quad.thrust_gain_spread=0.1",
        "env.quad.thrust_map_trimmed=true",
        "env.obs.action_history=2",
        "adaptation=l1",
        "env.init_pos_range_m=0",
    ]
    env = make_tracking_env(over, n=64)
    check_env_specs(env)
    td = env.reset()
    ceiling = env.sim.command_ceiling_mps2.clone()
    assert ceiling.shape == (64,) and ceiling.min() < 11.0 and ceiling.max() > 13.5
    td["action"] = torch.tensor([[30.0, 0.0, 0.0, 0.0]] * 64)
    env.step(td)
    clipped = torch.stack([ceiling.clamp(max=12.0)] + [torch.zeros(64)] * 3, -1)
    torch.testing.assert_close(env.cmd_history[:, -1, 0], env.scaled_command(clipped)[:, 0])
    td["action"] = torch.tensor([[9.5, 0.0, 0.0, 0.0]] * 64)
    env.step(td)
    want = env.scaled_command(torch.tensor([[9.5, 0.0, 0.0, 0.0]]))[0, 0]
    assert torch.allclose(env.cmd_history[:, -1, 0], want.expand(64))


def test_observation_defaults_are_the_papers_input():
    """``build_observation`` without the ablation flags is the body-frame input with feedback."""
    from datt.envs.observations import build_observation

    g = torch.Generator().manual_seed(3)
    pos, vel, ref = torch.randn(4, 3, generator=g), torch.randn(4, 3, generator=g), torch.randn(5, 4, 3, generator=g)
    quat = torch.nn.functional.normalize(torch.randn(4, 4, generator=g), dim=-1)
    default = build_observation(pos, vel, quat, ref)
    for got, want in zip(default, build_observation(pos, vel, quat, ref, True, True)):
        assert torch.equal(got, want)
    assert not torch.equal(default[0], build_observation(pos, vel, quat, ref, False, True)[0])
    assert not torch.equal(default[0], build_observation(pos, vel, quat, ref, True, False)[0])


def test_tracking_error_is_read_from_the_reference_table(make_tracking_env):
    """``tracking_error_m`` at step k equals ‖p_k − ref_table[k]‖, the table read directly."""
    env = make_tracking_env(n=3)
    td = env.reset()
    table = env.ref_table.clone()
    for k in range(1, 6):
        td["action"] = env.hover_action
        out = env.step(td)["next"]
        expect = torch.linalg.vector_norm(env.sim.state.pos_m - table[:, k], dim=-1)
        assert torch.allclose(out["tracking_error_m"][:, 0], expect, atol=1e-6), k
        td = out


def test_control_input_is_the_state_reference_and_commands(make_tracking_env):
    env = make_tracking_env(["env.quad.latency_steps=2", "env.obs.action_history=3", "adaptation=l1"], n=3)
    hover_rollout(env, 3)
    ci = env.control_input()
    s = env.sim.state
    assert ci.batch_size == torch.Size([3]) and ci.device == env.device
    for key, value in (
        ("pos_m", s.pos_m),
        ("vel_mps", s.vel_mps),
        ("quat", s.quat),
        ("rate_radps", s.rate_radps),
        ("thrust_mps2", s.thrust_mps2),
        ("d_hat", env.adaptation.d_hat),
        ("step", env.step_idx),
        ("cmd_history", env.cmd_history),
    ):
        assert torch.equal(ci[key], value), key
    assert ci["cmd_in_flight"].shape == (3, 2, 4)
    assert torch.equal(ci["cmd_in_flight"], env.sim.latency.in_flight().transpose(0, 1))
    assert ci["ref_window_m"].shape == (3, env.horizon, 3)
    assert torch.equal(ci["ref_window_m"][:, 0], env.reference_now_m())
    assert ci["ref_ahead_m"].shape == (3, 0, 3)  # nothing ahead unless asked


def test_reference_ahead_reads_the_table_and_holds_its_end(make_tracking_env):
    env = make_tracking_env(["traj=zigzag"], n=2)
    env.reset()
    env.step_idx[:] = torch.tensor([5, env.table_len - 3])
    ahead = env.control_input(ahead_steps=4)["ref_ahead_m"]
    assert ahead.shape == (2, 4, 3)
    assert torch.equal(ahead[0], env.ref_table[0, 6:10])  # p_d(t + k dt), k = 1..4
    last = env.table_len - 1
    assert torch.equal(ahead[1], env.ref_table[1, [last - 1, last, last, last]])
    one = env.control_input(ahead_steps=1)["ref_ahead_m"]
    assert one.shape == (2, 1, 3) and torch.equal(one[0, 0], env.ref_table[0, 6])


def test_set_state_keeps_the_envs_precision(make_tracking_env):
    env = make_tracking_env(["env.dtype=float64"], n=1)
    env.reset()
    env.set_state([0.1, 0.2, 0.3], [0.4, 0.5, 0.6], [0.1, 0.7, 0.7, 0.1])
    s = env.sim.state
    assert s.pos_m.dtype == torch.float64
    assert s.pos_m.tolist() == [[0.1, 0.2, 0.3]] and s.vel_mps.tolist() == [[0.4, 0.5, 0.6]]
    assert s.quat.tolist() == [[0.1, 0.7, 0.7, 0.1]]


def test_set_seed_makes_resets_reproducible(make_tracking_env):
    a, b = make_tracking_env(["traj=zigzag"], n=4), make_tracking_env(["traj=zigzag"], n=4)
    a.set_seed(7)
    b.set_seed(7)
    assert torch.equal(a.reset()["state"], b.reset()["state"]) and torch.equal(a.ref_table, b.ref_table)
    b.set_seed(8)
    b.reset()
    assert not torch.equal(a.ref_table, b.ref_table)
    a._set_seed(None)  # None means seed 0
    b._set_seed(0)
    a.reset()
    b.reset()
    assert torch.equal(a.ref_table, b.ref_table)


def test_a_partial_reset_restarts_the_adaptation_of_the_reset_drones_only():
    """L1 mid-episode under a Brownian disturbance: resetting drones 0 and 2 zeroes their estimate
    and restarts their filter from the state they restart in; the other drones keep theirs."""
    env = make_env(compose("sim", ["disturbance=brownian", "adaptation=l1"]), num_envs=4, seed=0)
    td = env.reset()
    for _ in range(30):
        td["action"] = env.hover_action
        _, td = env.step_and_maybe_reset(td)
    l1 = env.adaptation
    before = {k: getattr(l1, k).clone() for k in ("d_hat", "sigma_hat", "v_hat")}
    assert before["d_hat"].abs().sum(-1).min() > 0  # every drone has an estimate to lose
    td["_reset"] = torch.tensor([[True], [False], [True], [False]])
    env.reset(td)
    reset, kept = torch.tensor([0, 2]), torch.tensor([1, 3])
    assert torch.equal(l1.d_hat[reset], torch.zeros(2, 3)) and torch.equal(l1.sigma_hat[reset], torch.zeros(2, 3))
    assert torch.equal(l1.v_hat[reset], env.sim.state.vel_mps[reset])
    for key, value in before.items():
        assert torch.equal(getattr(l1, key)[kept], value[kept]), key


def test_a_reset_starts_the_rma_history_from_the_state_the_drone_restarts_in():
    """RMA's history after a reset reads as a hover where the drone restarts (unit quaternion,
    hover thrust), not zeros: the env hands the adaptation the new state."""
    from datt.adapt.rma import RmaAdaptation, RmaNet
    from datt.envs import TrackingEnv
    from datt.refs import Zigzag

    env = TrackingEnv(3, Zigzag(), adaptation=RmaAdaptation(net=RmaNet(50)), seed=0)
    td = env.reset()
    td["_reset"] = torch.tensor([[False], [True], [False]])
    env.reset(td)
    history = env.adaptation.history[1]  # [L, 14]: vel, quat, rates, thrust - g, rates commanded
    assert torch.equal(history[:, 3], torch.ones(50)) and history[:, [0, 1, 2, 4, 5, 6]].abs().max() == 0


def test_a_replaced_reference_is_read_from_the_current_step_on():
    """``replace_reference``: the table and the policy's window are the new table's from each
    drone's current step (deployment slows a reference this way); a wrong shape is refused."""
    env = make_env(compose("train", ["env.compile=false"]), num_envs=2, seed=0)
    env.reset()
    for _ in range(3):
        env.advance_reference()
    new = torch.randn_like(env.ref_table)
    env.replace_reference(new)
    assert torch.equal(env.ref_table, new)
    future = env._ref_future()  # [H, N, 3] at t + i Δ
    expected = new[:, 3 + env.ref_offsets].transpose(0, 1)
    assert torch.equal(future, expected)
    torch.testing.assert_close(env.reference_now_m(), new[:, 3])
    with pytest.raises(ValueError, match="replace_reference"):
        env.replace_reference(new[:, :-1])
