"""``env.obs.predict_latency``: the policy sees the state its next command will meet, pinned
against the same env without the prediction run that many steps further."""

import pytest
import torch

from datt.envs.prediction import roll_forward
from datt.errors import ConfigError
from datt.sim.quadrotor import CommandLatency, QuadrotorParams

DELAY = 3
BASE = ["traj=zigzag", "env.init_pos_range_m=0.3", "env.dtype=float64", f"env.quad.latency_steps={DELAY}"]
BASE += ["env.quad.k_rate=0.3"]  # k_rate apart from k_thrust: the prediction must use each for its own


def varied_actions(env, count, seed=1):
    """A command that changes every step: a constant one would hide which command acts when."""
    gen = torch.Generator().manual_seed(seed)
    scale = torch.tensor([3.0, 2.0, 2.0, 0.5], dtype=env.dtype)
    return [env.hover_action + torch.randn(env.n, 4, generator=gen, dtype=env.dtype) * scale for _ in range(count)]


def run(env, actions):
    td = env.reset()
    seen = []
    for action in actions:
        td["action"] = action
        out = env.step(td)["next"]
        seen.append(out)
        td = out.exclude("reward", "done", "terminated", "truncated")
    return seen


def test_the_predicted_observation_is_the_one_the_state_d_minus_1_steps_on_gives(make_tracking_env):
    # Until the first sent command acts the actuators hold the idle command, which is what the
    # prediction assumes: there it must be exact, state and reference window alike.
    predicted = make_tracking_env([*BASE, "env.obs.predict_latency=true"], n=3)
    plain = make_tracking_env(BASE, n=3)
    actions = varied_actions(plain, 2 * DELAY)
    with_prediction, without = run(predicted, actions), run(plain, actions)
    for k in range(DELAY - 1):  # observations after steps 1..d-1
        ahead = without[k + DELAY - 1]
        assert torch.allclose(with_prediction[k]["state"], ahead["state"], atol=1e-9), k
        assert torch.allclose(with_prediction[k]["ref"], ahead["ref"], atol=1e-9), k
        # the metric and the reward stay the true state's against the reference now
        assert torch.equal(with_prediction[k]["tracking_error_m"], without[k]["tracking_error_m"])
        assert torch.equal(with_prediction[k]["reward"], without[k]["reward"])
    # and the prediction moved the state: the test would pass on an env that ignores the option otherwise
    assert not torch.allclose(with_prediction[0]["state"], without[0]["state"], atol=1e-3)


def test_one_step_of_latency_predicts_nothing(make_tracking_env):
    overrides = ["traj=zigzag", "env.init_pos_range_m=0.3", "env.obs.action_history=2"]
    predicted = make_tracking_env([*overrides, "env.obs.predict_latency=true"], n=2)
    plain = make_tracking_env(overrides, n=2)
    actions = varied_actions(plain, 4)
    for a, b in zip(run(predicted, actions), run(plain, actions)):
        assert torch.equal(a["state"], b["state"]) and torch.equal(a["ref"], b["ref"])


def test_pending_lists_what_the_next_pushes_apply_for_each_drones_delay():
    n, top = 5, 4
    fill = torch.zeros(2)
    latency = CommandLatency(1, fill, n, max_steps=top)
    delays = torch.tensor([0, 1, 2, 3, 4])
    latency.set_delay(torch.arange(n), delays)
    gen = torch.Generator().manual_seed(0)
    for _ in range(6):
        latency.push(torch.randn(n, 2, generator=gen))
    commands, active, acting = latency.pending()
    assert commands.shape == (top - 1, n, 2)
    assert active.sum(0).tolist() == (delays - 1).clamp_min(0).tolist()
    last_sent = latency._ring[(latency._head - 1) % (top + 1)].clone()
    assert torch.equal(acting[0], last_sent[0])  # no delay: the last sent acts now
    for j in range(top - 1):
        applied = latency.push(torch.randn(n, 2, generator=gen))
        on = active[j]
        assert torch.equal(applied[on], commands[j][on]), j


def test_pending_under_an_assumed_delay_lists_what_that_delay_would_apply():
    """A predictor that takes drone 0's delay of 2 to be 3 rolls over one command that already
    acted; one that takes drone 1's delay of 3 to be 2 misses one."""
    n, top = 2, 4
    latency = CommandLatency(1, torch.zeros(1), n, max_steps=top)
    latency.set_delay(torch.arange(n), torch.tensor([2, 3]))
    for k in range(1, 7):  # command k sent at step k: the ring holds the last five
        latency.push(torch.full((n, 1), float(k)))
    commands, active, acting = latency.pending(torch.tensor([3, 2]))
    assert commands[:, 0, 0][active[:, 0]].tolist() == [4.0, 5.0]  # sent 3 and 2 steps before the next
    assert acting[0, 0].item() == 3.0
    assert commands[:, 1, 0][active[:, 1]].tolist() == [5.0]
    assert acting[1, 0].item() == 4.0
    true_commands, true_active, true_acting = latency.pending()
    assert true_commands[:, 0, 0][true_active[:, 0]].tolist() == [5.0] and true_acting[0, 0].item() == 4.0
    assert true_commands[:, 1, 0][true_active[:, 1]].tolist() == [4.0, 5.0] and true_acting[1, 0].item() == 3.0


def test_the_assumed_delay_is_the_true_one_give_or_take_the_error_within_the_range(make_tracking_env):
    env = make_tracking_env(
        [
            "env.obs.predict_latency=true",
            "env.obs.predict_latency_error_steps=1",
            "env.quad.latency_steps=1",
            "env.quad.latency_steps_max=4",
        ],
        n=4000,
    )
    off = env.assumed_delay - env.sim.latency.delay
    assert off.abs().max().item() == 1 and env.assumed_delay.min().item() == 1 and env.assumed_delay.max().item() == 4
    # interior true delays (2, 3) draw -1, 0, +1 a third each; both tails and the mean
    inner = (env.sim.latency.delay >= 2) & (env.sim.latency.delay <= 3)
    for value in (-1, 0, 1):
        share = (off[inner] == value).float().mean().item()
        assert abs(share - 1 / 3) < 0.04, (value, share)
    assert abs(off[inner].float().mean().item()) < 0.05
    # redrawn at a reset
    before = env.assumed_delay.clone()
    env.reset()
    assert not torch.equal(before, env.assumed_delay)


def test_roll_forward_follows_the_nominal_model_and_skips_inactive_steps():
    quad = QuadrotorParams()
    pos, vel = torch.zeros(2, 3, dtype=torch.float64), torch.zeros(2, 3, dtype=torch.float64)
    quat = torch.tensor([[1.0, 0, 0, 0]] * 2, dtype=torch.float64)
    hover = torch.tensor([[quad.gravity_mps2, 0.0, 0.0, 0.0]] * 2, dtype=torch.float64)
    climb = hover.clone()
    climb[:, 0] += 2.0  # 2 m/s² more thrust for one step: the actuator passes k_thrust of it
    commands = torch.stack((climb, hover))
    active = torch.tensor([[True, False], [True, False]])
    d_hat = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]], dtype=torch.float64)
    gravity = torch.tensor([0.0, 0.0, -quad.gravity_mps2], dtype=torch.float64)
    p, v, q = roll_forward(pos, vel, quat, hover, commands, active, d_hat, gravity, quad, 0.02)
    a1 = 2.0 * quad.k_thrust  # the first step's excess acceleration
    a2 = 2.0 * quad.k_thrust * (1 - quad.k_thrust)  # the second: the actuator relaxes back
    assert v[0, 2].item() == pytest.approx((a1 + a2) * 0.02, abs=1e-12)
    assert p[0, 2].item() == pytest.approx(0.5 * a1 * 0.02**2 + a1 * 0.02 * 0.02 + 0.5 * a2 * 0.02**2, abs=1e-12)
    assert torch.equal(p[1], pos[1]) and torch.equal(v[1], vel[1]) and torch.equal(q[1], quat[1])
    # d-hat acts as a world-frame acceleration over both steps
    p, v, _ = roll_forward(pos, vel, quat, hover, torch.stack((hover, hover)), active, d_hat + 1.0, gravity, quad, 0.02)
    assert torch.allclose(v[0], torch.full((3,), 0.04, dtype=torch.float64), atol=1e-12)


def test_the_prediction_needs_the_project_timing(make_tracking_env):
    with pytest.raises(ConfigError, match=r"env.obs.predict_latency: true needs env.obs.timing=project"):
        make_tracking_env(["env.obs.predict_latency=true", "env.obs.timing=authors"], n=1)


def test_a_reference_lead_reads_the_window_that_many_steps_ahead(make_tracking_env):
    env = make_tracking_env(["traj=zigzag", "env.init_pos_range_m=0.3", "env.dtype=float64"], n=2)
    env.reset()
    for _ in range(3):
        env.advance_reference()
    now = env.observe()
    env.set_reference_lead(4)
    ahead = env.observe()
    later = make_tracking_env(["traj=zigzag", "env.init_pos_range_m=0.3", "env.dtype=float64"], n=2)
    later.reset()
    for _ in range(7):
        later.advance_reference()
    later.set_state(env.sim.state.pos_m, env.sim.state.vel_mps, env.sim.state.quat)
    assert torch.allclose(ahead["ref"], later.observe()["ref"], atol=1e-12)
    assert not torch.allclose(ahead["ref"], now["ref"], atol=1e-3)
    # the metric stays the reference now
    assert torch.equal(ahead["tracking_error_m"], now["tracking_error_m"])
    env.set_reference_lead(0)
    assert torch.equal(env.observe()["ref"], now["ref"])
    with pytest.raises(ValueError, match=r"reference lead: must be a finite number >= 0 steps, got -1"):
        env.set_reference_lead(-1)
