"""L1 estimator: convergence, stability, Brownian tracking, partial resets."""

import math

import pytest
import torch

from datt.adapt import L1Adaptation
from datt.configuration import compose
from datt.envs.factory import make_env


def run_env(overrides, steps, n=64, seed=0, action=None):
    env = make_env(compose("sim", ["adaptation=l1", *overrides]), num_envs=n, seed=seed)
    td = env.reset()
    d_hats, ds = [], []
    g = torch.Generator().manual_seed(1)
    for _ in range(steps):
        td["action"] = env.hover_action if action is None else action(env, g)
        td = env.step(td)["next"].exclude("reward", "done", "terminated", "truncated")
        d_hats.append(td["d_hat"].clone())
        ds.append(env.disturbance.current_mps2.clone())
    return env, torch.stack(d_hats, 1), torch.stack(ds, 1)


def wiggle(env, g):
    """Hover plus random thrust and rate commands: the estimator must not mistake them for d."""
    a = env.hover_action.clone()
    a[:, 0] += 3.0 * torch.randn(env.n, generator=g)
    a[:, 1:3] += 1.0 * torch.randn(env.n, 2, generator=g)
    return a


@pytest.mark.parametrize("tau", [0.1, 0.5, 2.0])
def test_constant_disturbance_within_5_percent_after_three_time_constants(tau):
    steps_3tau = round(3 * tau / 0.02)
    env, d_hat, d = run_env(
        ["disturbance=constant", f"adaptation.cutoff_tau_s={tau}", "env.safety_box_m=[1000,1000,1000]"],
        steps_3tau + 20,
        action=wiggle,
    )
    err = (d_hat[:, steps_3tau - 1 :] - d[:, steps_3tau - 1 :]).norm(dim=-1) / d[:, :1].norm(dim=-1)
    assert err.max() <= 0.05, err.max()
    # and not much earlier: it really is a filter with that time constant
    early = (d_hat[:, steps_3tau // 3] - d[:, 0]).norm(dim=-1) / d[:, 0].norm(dim=-1)
    assert early.min() > 0.25


def test_no_disturbance_gives_zero_estimate_despite_aggressive_commands():
    _, d_hat, _ = run_env(["disturbance=none", "env.safety_box_m=[1000,1000,1000]"], 100, action=wiggle)
    assert d_hat.abs().max() < 1e-3


def test_raw_previous_command_without_actuator_model_is_biased():
    _, d_hat, _ = run_env(
        ["disturbance=none", "adaptation.actuator_model=false", "env.safety_box_m=[1000,1000,1000]"], 100, action=wiggle
    )
    assert d_hat.abs().max() > 0.1  # the delay shows up as a fake disturbance


def test_follows_brownian_disturbance():
    _, d_hat, d = run_env(["disturbance=brownian", "env.safety_box_m=[1000,1000,1000]"], 500, n=128, action=wiggle)
    rmse = (d_hat[:, 50:] - d[:, 50:]).pow(2).mean().sqrt()
    assert rmse < 0.05, rmse  # d has std ~2 m/s^2
    zero_rmse = d[:, 50:].pow(2).mean().sqrt()
    assert rmse < 0.03 * zero_rmse


def test_estimator_is_stable_for_configured_a_s():
    est = L1Adaptation(a_s=-0.01, cutoff_tau_s=0.1)
    est.bind(1, 0.02, 9.81, "cpu", torch.float64)
    assert est.a_s < 0  # Hurwitz A_s = a_s I: eigenvalues a_s
    rho = torch.linalg.eigvals(est.error_dynamics()[0]).abs().max()
    assert rho < 1.0
    # the filtered-feedback loop (eq. 7a read literally) is stable but barely damped
    literal = L1Adaptation(a_s=-0.01, cutoff_tau_s=2.0, predictor_uses_filtered=True)
    literal.bind(1, 0.02, 9.81, "cpu", torch.float64)
    rho_literal = torch.linalg.eigvals(literal.error_dynamics()[0]).abs().max()
    assert rho < rho_literal < 1.0 and rho_literal > 0.99


@pytest.mark.parametrize("filtered", [False, True], ids=["sigma_feedback", "filtered_feedback"])
def test_error_dynamics_matrix_predicts_the_simulated_response(filtered):
    est = L1Adaptation(a_s=-0.5, cutoff_tau_s=0.2, predictor_uses_filtered=filtered)
    est.bind(1, 0.02, 9.81, "cpu", torch.float64)
    m, b = est.error_dynamics()
    x = torch.zeros(3, dtype=torch.float64)  # estimates start at 0; unit disturbance
    predicted = []
    for _ in range(30):
        x = m @ x + b
        predicted.append(x[2].item())
    _, d_hat, d = run_env(
        [
            "disturbance=constant",
            "adaptation.a_s=-0.5",
            "adaptation.cutoff_tau_s=0.2",
            f"adaptation.predictor_uses_filtered={str(filtered).lower()}",
            "env.dtype=float64",
            "env.safety_box_m=[1000,1000,1000]",
        ],
        30,
        n=2,
    )
    ratio = (d_hat[0, :, 0] / d[0, :, 0]).tolist()
    assert ratio == pytest.approx(predicted, abs=1e-9)


def test_partial_reset_restarts_only_selected_estimates():
    env, _, _ = run_env(["disturbance=constant"], 30, n=4)
    before = env.adaptation.d_hat.clone()
    td = env.reset(
        __import__("tensordict").TensorDict({"_reset": torch.tensor([[True], [False], [False], [True]])}, [4])
    )
    after = env.adaptation.d_hat
    assert torch.equal(after[1:3], before[1:3]) and after[[0, 3]].abs().max() == 0
    assert torch.equal(td["d_hat"][[0, 3]], after[[0, 3]])


@pytest.mark.parametrize("kwargs, key", [({"a_s": 0.1}, "a_s"), ({"cutoff_tau_s": -1}, "cutoff_tau_s")])
def test_bad_l1_parameters(kwargs, key):
    with pytest.raises(ValueError, match=f"adaptation.{key}"):
        L1Adaptation(**kwargs)


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"a_s": 0.0}, "adaptation.a_s: must be a finite number in [-1000, 0), got 0.0"),
        ({"cutoff_tau_s": -0.01}, "adaptation.cutoff_tau_s: must be a finite number in [0, 3600], got -0.01"),
        ({"k_thrust": 0.0}, "adaptation.k_thrust: must be a finite number in (0, 1], got 0.0"),
        ({"k_thrust": 1.5}, "adaptation.k_thrust: must be a finite number in (0, 1], got 1.5"),
        ({"latency_steps": -1}, "adaptation.latency_steps: must be an integer in [0, 100], got -1"),
    ],
    ids=["a_s", "cutoff", "k_zero", "k_above_one", "latency"],  # plain node ids (mutmut selects tests by id)
)
def test_l1_parameter_errors_are_exact(kwargs, message):
    with pytest.raises(ValueError) as info:
        L1Adaptation(**kwargs)
    assert str(info.value) == message


@pytest.mark.parametrize("kwargs", [{"cutoff_tau_s": 0.0}, {"k_thrust": 1.0}, {"latency_steps": 0}, {"a_s": -5.0}])
def test_l1_parameter_edges_are_allowed(kwargs):
    L1Adaptation(**kwargs)  # no filter, an instant actuator, no latency, a fast predictor


def test_a_bare_l1_has_the_simulators_actuator_and_the_configs_defaults():
    """``adaptation=l1`` takes k_thrust and latency_steps from ``env.quad``: the Python defaults
    are the simulator's own, so ``L1Adaptation()`` in a notebook models the same actuator."""
    import inspect

    from datt.sim.quadrotor import QuadrotorParams

    params = inspect.signature(L1Adaptation).parameters
    assert params["k_thrust"].default == QuadrotorParams().k_thrust
    assert params["latency_steps"].default == QuadrotorParams().latency_steps
    # what a bare L1Adaptation() holds: the simulator's actuator, and conf/adaptation/l1.yaml's
    # tuned 0.1 s filter, raw estimate in the predictor (as the authors), actuator model on
    bare, cfg = L1Adaptation(), compose("sim", ["adaptation=l1"]).adaptation
    assert (bare.k_thrust, bare.latency_steps) == (QuadrotorParams().k_thrust, QuadrotorParams().latency_steps)
    for key in ("a_s", "cutoff_tau_s", "predictor_uses_filtered", "actuator_model"):
        assert getattr(bare, key) == cfg[key], key
    assert (bare.cutoff_tau_s, bare.predictor_uses_filtered, bare.actuator_model) == (0.1, False, True)


def test_zero_cutoff_means_no_filter():
    """cutoff_tau_s = 0: d-hat is the raw estimate sigma-hat at every step."""
    from types import SimpleNamespace

    est = L1Adaptation(cutoff_tau_s=0.0)
    est.bind(2, 0.02, 9.81, "cpu", torch.float32)
    est.reset(torch.arange(2))
    g = torch.Generator().manual_seed(0)
    for _ in range(5):
        state = SimpleNamespace(vel_mps=torch.randn(2, 3, generator=g), quat=torch.tensor([[1.0, 0, 0, 0]] * 2))
        est.update(state, torch.tensor([[9.81, 0, 0, 0]] * 2) + torch.randn(2, 4, generator=g))
        assert torch.equal(est.d_hat, est.sigma_hat) and est.d_hat.abs().max() > 0


def test_compile_before_bind_and_its_options(monkeypatch):
    """compile() may come before bind() (the kernel is chosen when the batch size is known), and
    its options reach torch.compile."""
    import datt.adapt.l1 as l1_module
    from datt.adapt.l1 import COMPILE_MIN_BATCH, l1_step

    seen = {}

    def fake_compile(fn, **kwargs):
        seen.update(kwargs)
        return lambda *args: fn(*args)

    monkeypatch.setattr("datt.compile.compile_or_eager", fake_compile)
    est = L1Adaptation().compile(backend="eager", mode="reduce-overhead")
    assert seen == {"backend": "eager", "mode": "reduce-overhead"} and est._step is l1_step
    est.bind(COMPILE_MIN_BATCH, 0.02, 9.81, "cpu", torch.float32)
    assert est._step is not l1_step and l1_module.COMPILE_MIN_BATCH == COMPILE_MIN_BATCH


def test_law_gain_matches_eq_7b():
    est = L1Adaptation(a_s=-0.01)
    est.bind(1, 0.02, 9.81, "cpu", torch.float32)
    e = math.exp(-0.01 * 0.02)
    assert est.law_gain == pytest.approx(-(1 / (e - 1)) * -0.01 * e)
    assert est.law_gain == pytest.approx(-50.0, rel=1e-3)


def test_compiled_kernel_only_for_large_batches_and_same_estimates():
    """compile() keeps the eager kernel below COMPILE_MIN_BATCH drones (cheaper at batch 1) and
    uses the compiled one above; both give the same estimates."""
    from types import SimpleNamespace

    from datt.adapt.l1 import COMPILE_MIN_BATCH, l1_step

    n = COMPILE_MIN_BATCH
    g = torch.Generator().manual_seed(0)
    vel = torch.randn(20, n, 3, generator=g)
    cmd = torch.randn(20, n, 4, generator=g) + torch.tensor([9.81, 0, 0, 0])
    quat = torch.tensor([[1.0, 0, 0, 0]]).expand(n, 4)
    small, big, eager = L1Adaptation(), L1Adaptation(), L1Adaptation()
    small.bind(1, 0.02, 9.81, "cpu", torch.float32)
    small.compile(backend="eager")
    assert small._step is l1_step
    for est in (big, eager):
        est.bind(n, 0.02, 9.81, "cpu", torch.float32)
    big.compile(backend="eager")
    assert big._step is not l1_step and eager._step is l1_step
    for k in range(20):
        state = SimpleNamespace(vel_mps=vel[k], quat=quat)
        torch.testing.assert_close(big.update(state, cmd[k]), eager.update(state, cmd[k]))
    assert big.d_hat.abs().max() > 0.1


def test_reset_restarts_the_estimator_at_the_measured_state():
    """A reset drone's predictor starts at its measured velocity and attitude (or at rest and
    level without a state); σ̂, d̂ and the thrust estimate restart; other drones keep theirs."""
    from datt.sim.frames import quat_from_euler
    from datt.sim.quadrotor import QuadState

    est = L1Adaptation(a_s=-0.5, cutoff_tau_s=0.2)
    est.bind(3, 0.02, 9.81, "cpu", torch.float64)
    for name in ("v_hat", "sigma_hat", "d_hat", "prev_vel"):
        getattr(est, name).fill_(0.7)
    est.prev_quat[:] = torch.tensor([0.0, 1.0, 0.0, 0.0], dtype=torch.float64)
    est.thrust_est.fill_(3.0)
    est.thrust_queue.fill_(3.0)
    vel = torch.tensor([[1.0, 2.0, 3.0]] * 3, dtype=torch.float64)
    quat = quat_from_euler(*(torch.full((3,), a, dtype=torch.float64) for a in (0.1, 0.2, 0.3)))
    z = torch.zeros(3, 3, dtype=torch.float64)
    state = QuadState(pos_m=z, vel_mps=vel, quat=quat, rate_radps=z, thrust_mps2=torch.zeros(3, dtype=torch.float64))
    est.reset(torch.tensor([0]), None, state)
    est.reset(torch.tensor([1]))
    assert est.v_hat[0].tolist() == [1.0, 2.0, 3.0] and est.prev_vel[0].tolist() == [1.0, 2.0, 3.0]
    assert torch.equal(est.prev_quat[0], quat[0])
    assert est.v_hat[1].tolist() == [0.0, 0.0, 0.0] and est.prev_vel[1].tolist() == [0.0, 0.0, 0.0]
    assert est.prev_quat[1].tolist() == [1.0, 0.0, 0.0, 0.0] and est.prev_quat.dtype == torch.float64
    for i in (0, 1):
        assert est.sigma_hat[i].abs().max() == 0 and est.d_hat[i].abs().max() == 0
        assert est.thrust_est[i] == 9.81 and (est.thrust_queue[:, i] == 9.81).all()
    assert est.v_hat[2].tolist() == [0.7] * 3 and est.d_hat[2].tolist() == [0.7] * 3  # untouched
    assert est.prev_quat[2].tolist() == [0.0, 1.0, 0.0, 0.0] and est.thrust_est[2] == 3.0


def _one_update(actuator_model, thrust_cmd_mps2=12.0):
    """One update from rest, level, with measured velocity 0 after the step."""
    from types import SimpleNamespace

    est = L1Adaptation(a_s=-0.01, cutoff_tau_s=0.1, actuator_model=actuator_model, k_thrust=0.4, latency_steps=1)
    est.bind(1, 0.02, 9.81, "cpu", torch.float64)
    est.reset(torch.tensor([0]))
    state = SimpleNamespace(
        vel_mps=torch.zeros(1, 3, dtype=torch.float64), quat=torch.tensor([[1.0, 0.0, 0.0, 0.0]], dtype=torch.float64)
    )
    est.update(state, torch.tensor([[thrust_cmd_mps2, 0.0, 0.0, 0.0]], dtype=torch.float64))
    return est


def test_raw_command_mode_predicts_with_the_command_sent_at_the_start_of_the_step():
    """``actuator_model=false`` (the authors'): v̂_z after one step = dt (T_cmd − g); the nominal
    model (latency 1) still has hover thrust acting, so v̂ stays 0."""
    raw = _one_update(actuator_model=False)
    assert raw.v_hat[0, 2].item() == pytest.approx(0.02 * (12.0 - 9.81), rel=1e-12)
    assert raw.sigma_hat[0, 2].item() == pytest.approx(raw.law_gain * raw.v_hat[0, 2].item(), rel=1e-12)
    modelled = _one_update(actuator_model=True)
    assert modelled.v_hat.abs().max().item() < 1e-12


def test_l1_paper_is_the_authors_estimator():
    """α = 0.99 per 20 ms step, a_s = −0.01, raw estimate fed back, raw commands."""
    from datt.configuration import compose, instantiate_option

    est = instantiate_option(compose("sim", ["adaptation=l1_paper"]), "adaptation")
    est.bind(1, 0.02, 9.81, "cpu", torch.float64)
    assert est.alpha == pytest.approx(0.99, abs=1e-6)
    assert (est.a_s, est.predictor_uses_filtered, est.actuator_model) == (-0.01, False, False)
