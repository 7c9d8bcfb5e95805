"""MPPI: the update lowers the sampled cost against its initial mean; rollout model = simulator."""

import pytest
import torch

from datt.control.mppi import MppiController
from tests.control.test_pid import Point, env_at, quadratic_env


def test_rollout_model_matches_the_simulator():
    # A single sample with zero noise is the simulator itself: same state after the same commands,
    # including the command already in flight (latency) and the actuator delay.
    env = env_at([0.3, 0.0, 0.0], n=2)
    env.reset()
    ctrl = MppiController(num_samples=1, horizon_steps=6, noise_std=[0, 0, 0, 0], compile=False)
    ctrl.reset(env)
    env.sim.step(torch.tensor([[12.0, 1.0, 0.0, 0.0], [8.0, 0.0, -1.0, 0.5]]))  # leaves a command in flight
    seq = torch.tensor([[11.0, 0.5, 0.2, 0.0]]).expand(6, 4)
    u = seq.expand(2, 1, 6, 4).clone()
    cost = ctrl.rollout_cost(env, u, torch.zeros(2, 3))
    ref = env.ref_table[0, 1]
    positions = []
    for j in range(6):
        env.sim.step(seq[j].expand(2, 4))
        positions.append(env.sim.state.pos_m.clone())
    pos = torch.stack(positions, 1)  # [2, 6, 3]
    err = torch.linalg.vector_norm(pos - ref, dim=-1).sum(1)
    # cost = dt * (5 * Σ‖e‖ + 3 * Σ (1 - qw²)); check the position part dominates as computed
    assert cost.shape == (2, 1)
    assert (cost[:, 0] >= env.dt_s * 5 * err - 1e-5).all()
    ctrl_pos_only = MppiController(
        num_samples=1, horizon_steps=6, noise_std=[0, 0, 0, 0], att_weight=0.0, compile=False
    )
    env2 = env_at([0.3, 0.0, 0.0], n=2)
    env2.reset()
    ctrl_pos_only.reset(env2)
    env2.sim.step(torch.tensor([[12.0, 1.0, 0.0, 0.0], [8.0, 0.0, -1.0, 0.5]]))
    cost2 = ctrl_pos_only.rollout_cost(env2, u, torch.zeros(2, 3))
    torch.testing.assert_close(cost2[:, 0], env.dt_s * 5 * err, rtol=1e-5, atol=1e-6)


def test_update_reduces_cost_against_the_initial_mean():
    # Toy case: hover at the origin, reference 0.5 m away. The hover mean's cost is what MPPI
    # starts from; the weighted mean after one update must roll out cheaper.
    env = env_at([0.5, 0.0, 0.0], n=3)
    td = env.reset()
    ctrl = MppiController(num_samples=1024, horizon_steps=30, compile=False)
    ctrl.reset(env)
    zero_d = torch.zeros(3, 3)
    before = ctrl.rollout_cost(env, ctrl.mean.unsqueeze(1), zero_d)[:, 0]
    costs = []
    for _ in range(4):  # repeated updates from the same state (undoing the warm-start shift)
        ctrl.act(env, td)
        ctrl.mean = torch.cat((ctrl.mean[:, -1:], ctrl.mean[:, :-1]), dim=1)
        costs.append(ctrl.rollout_cost(env, ctrl.mean.unsqueeze(1), zero_d)[:, 0])
    assert (costs[0] < before - 0.01).all(), (before, costs[0])
    assert (costs[-1] < 0.95 * before).all(), (before, costs[-1])


def test_mppi_flies_to_a_step_target():
    env = env_at([0.4, -0.3, 0.2], n=2)
    from datt.eval.rollout import run_controller

    trace = run_controller(env, MppiController(num_samples=512, horizon_steps=40, compile=False), steps=120)
    assert (trace.crashed_at == 120).all()
    assert trace.err_m[:, 80:].max() < 0.05
    assert trace.err_m[:, 0].min() > 0.4


def test_l1_mppi_uses_the_estimate_in_its_model():
    env = env_at([0.0, 0.0, 0.0], n=1)
    td = env.reset()
    ctrl = MppiController(num_samples=64, horizon_steps=10, noise_std=[0, 0, 0, 0], use_d_hat=True, compile=False)
    ctrl.reset(env)
    assert ctrl.name == "l1_mppi"
    td["d_hat"] = torch.tensor([[0.0, 0.0, -3.0]])
    u = ctrl.mean.unsqueeze(1)
    assert ctrl.rollout_cost(env, u, td["d_hat"]) > ctrl.rollout_cost(env, u, torch.zeros(1, 3))


def test_bad_parameters_fail_clearly():

    with pytest.raises(ValueError, match="controller.num_samples"):
        MppiController(num_samples=0)
    with pytest.raises(ValueError, match="controller.noise_std"):
        MppiController(noise_std=[1.0, 2.0])
    assert Point  # the shared helper stays importable


def test_the_rollout_cost_pairs_step_j_with_the_reference_at_t_plus_j_plus_one():
    """On a moving reference (p_d = ½ a t²) and from a later step of the episode, the cost of one
    noiseless sample is dt Σ_j w_p ‖p_j − p_d(t + (j + 1) dt)‖ over the simulator's own rollout."""

    env = quadratic_env([0.2, 0.0, 0.0], [1.0, 0.0, -0.5], n=2)
    td = env.reset()
    for _ in range(7):
        td = env.step(td.set("action", env.hover_action.expand(2, 4).clone()))["next"]
    ctrl = MppiController(num_samples=1, horizon_steps=5, noise_std=[0, 0, 0, 0], att_weight=0.0, compile=False)
    ctrl.reset(env)
    seq = torch.tensor([[10.5, 0.3, -0.2, 0.0], [9.0, 0.0, 0.4, 0.1], [11.0, -0.5, 0.0, 0.0]] + [[9.81, 0, 0, 0]] * 2)
    u = seq.to(env.dtype).expand(2, 1, 5, 4).clone()
    cost = ctrl.rollout_cost(env, u, torch.zeros(2, 3, dtype=env.dtype))[:, 0]
    k = int(env.step_idx[0])
    errs = []
    for j in range(5):
        env.sim.step(u[:, 0, j])
        errs.append(torch.linalg.vector_norm(env.sim.state.pos_m - env.ref_table[:, k + j + 1], dim=-1))
    torch.testing.assert_close(cost, env.dt_s * 5.0 * torch.stack(errs, 1).sum(1))


def test_the_python_defaults_are_the_options_and_the_names_say_which_controller():
    from omegaconf import OmegaConf

    from datt.configuration import conf_dir

    node = OmegaConf.to_container(OmegaConf.load(conf_dir() / "controller" / "mppi.yaml"))
    ctrl = MppiController()
    assert (ctrl.num_samples, ctrl.horizon, ctrl.temperature) == (
        node["num_samples"],
        node["horizon_steps"],
        node["temperature"],
    )
    assert ctrl.noise_std.tolist() == pytest.approx(node["noise_std"]) and ctrl.seed == node["seed"]
    assert (ctrl.pos_weight, ctrl.att_weight, ctrl.use_d_hat) == (node["pos_weight"], node["att_weight"], False)
    assert ctrl.name == node["name"] == "mppi" and MppiController(use_d_hat=True).name == "l1_mppi"


def _windy_env(n=2):
    from datt.configuration import compose
    from datt.envs.factory import make_env

    cfg = compose("sim", ["env.init_pos_range_m=0", "disturbance=constant", "adaptation=privileged"])
    return make_env(cfg, num_envs=n, traj=Point([0.0, 0.0, 0.0]))


def _first_action(env, **kwargs):
    td = env.reset()
    ctrl = MppiController(num_samples=256, horizon_steps=15, compile=False, **kwargs)
    ctrl.reset(env)
    return ctrl.act(env, td)


def test_act_samples_from_its_own_seeded_generator_and_leaves_the_global_rng_alone():
    env = _windy_env()
    torch.manual_seed(123)
    first = _first_action(env, seed=4)
    after = torch.rand(3)
    torch.manual_seed(123)
    assert torch.equal(after, torch.rand(3))  # act drew nothing from the global generator
    assert torch.equal(_first_action(env, seed=4), first)
    assert not torch.equal(_first_action(env, seed=5), first)


def test_l1_mppi_acts_on_the_envs_estimate_and_plain_mppi_ignores_it():
    """Same seed, same samples: with d̂ ≠ 0 (privileged, a constant wind) the rollouts of L1-MPPI
    differ from MPPI's, so the chosen command differs; plain MPPI equals MPPI on a calm env."""
    windy = _windy_env()
    assert windy.adaptation.d_hat.abs().max() > 0.1
    plain, l1 = _first_action(windy, use_d_hat=False), _first_action(windy, use_d_hat=True)
    assert not torch.allclose(plain, l1)
    calm = env_at([0.0, 0.0, 0.0], n=2)
    assert torch.equal(_first_action(calm, use_d_hat=False), plain)


def test_the_rollout_model_clips_commands_at_the_vehicles_ceiling_as_the_simulator_does():
    """Commands beyond the actuator limits (thrust above max_thrust_mps2, rates above the cap)
    roll out as the simulator flies them: clipped, not as asked."""
    env = env_at([0.0, 0.0, 0.0], n=1, overrides=["env.quad.latency_steps=0"])
    env.reset()
    ctrl = MppiController(num_samples=1, horizon_steps=8, noise_std=[0, 0, 0, 0], att_weight=0.0, compile=False)
    ctrl.reset(env)
    seq = torch.tensor([[60.0, 0.0, 0.0, 0.0]] * 4 + [[30.0, 40.0, -40.0, 5.0]] * 4)
    assert seq[0, 0] > env.sim.params.max_thrust_mps2
    cost = ctrl.rollout_cost(env, seq.expand(1, 1, 8, 4).clone(), torch.zeros(1, 3))
    errs = []
    for j in range(8):
        env.sim.step(seq[j].expand(1, 4))
        errs.append(torch.linalg.vector_norm(env.sim.state.pos_m - env.ref_table[:, 1 + j], dim=-1))
    torch.testing.assert_close(cost[:, 0], env.dt_s * 5.0 * torch.stack(errs, 1).sum(1))


@pytest.mark.slow  # torch.compile of the rollout step: tens of seconds on a CPU
def test_the_compiled_rollout_costs_what_the_eager_one_does():
    """``compile=True`` (the option's default) runs the same model step through torch.compile:
    identical costs for the same sampled sequences."""
    env = quadratic_env([0.2, 0.0, 0.0], [1.0, 0.0, -0.5], n=2)
    env.reset()
    u = (9.81 + torch.randn(2, 16, 10, 4, generator=torch.Generator().manual_seed(0))).to(env.dtype)
    d = torch.zeros(2, 3, dtype=env.dtype)
    costs = []
    for compiled in (False, True):
        ctrl = MppiController(num_samples=16, horizon_steps=10, compile=compiled)
        ctrl.reset(env)
        costs.append(ctrl.rollout_cost(env, u, d))
    torch.testing.assert_close(costs[1], costs[0])


def test_the_mppi_option_holds_the_constructor_s_defaults():
    """``controller=mppi`` and ``MppiController()`` in a notebook are the same controller."""
    import inspect

    from omegaconf import OmegaConf

    from datt.configuration import compose

    node = OmegaConf.to_container(compose("eval", ["controller=mppi"]).controller, resolve=True)
    params = inspect.signature(MppiController).parameters
    compared = [key for key in node if key in params]
    assert set(compared) == set(params)  # the option sets every argument
    for key in compared:
        default = params[key].default
        assert (list(default) if isinstance(default, tuple) else default) == node[key], key
