"""``env.obs.timing``: which state each step's observation and reward read, pinned against a
rollout built by hand from the simulator and the reference table."""

import pytest
import torch

from datt.envs.observations import build_observation
from datt.sim import Quadrotor
from datt.sim.frames import quat_yaw

STEPS = 6


def hand_rollout(env, actions):
    """States x_0..x_K of a bare simulator driven by ``actions`` from the env's start state."""
    sim = Quadrotor(env.n, env.params.quad, dt_s=env.dt_s, dtype=env.dtype)
    sim.reset(pos_m=env.sim.state.pos_m.clone())
    states = [(sim.state.pos_m.clone(), sim.state.vel_mps.clone(), sim.state.quat.clone())]
    for a in actions:
        sim.step(a)
        states.append((sim.state.pos_m.clone(), sim.state.vel_mps.clone(), sim.state.quat.clone()))
    return states


def reference_window(env, k):
    """``[H, N, 3]``: p_d(t_k + i Δ), read from the env's reference table."""
    return env.ref_table[:, k + env.ref_offsets].transpose(0, 1)


@pytest.mark.parametrize("timing", ["project", "authors"])
def test_each_step_pairs_the_documented_state_with_the_reference_at_the_new_time(make_tracking_env, timing):
    env = make_tracking_env(["traj=zigzag", "env.init_pos_range_m=0.3", f"env.obs.timing={timing}"], n=3)
    td = env.reset()
    gen = torch.Generator().manual_seed(1)
    # a command that changes every step: a constant one would hide an off-by-one in the pairing
    actions = [
        env.hover_action + torch.randn(3, 4, generator=gen) * torch.tensor([3.0, 2.0, 2.0, 0.5]) for _ in range(STEPS)
    ]
    states = hand_rollout(env, actions)
    for k, action in enumerate(actions):
        td["action"] = action
        out = env.step(td)["next"]
        read = states[k] if timing == "authors" else states[k + 1]  # observation and reward read this state
        window = reference_window(env, k + 1)  # the reference at the new time t_{k+1} under both
        state, ref = build_observation(*read, window)
        assert torch.allclose(out["state"], state, atol=1e-5), k
        assert torch.allclose(out["ref"], ref, atol=1e-5), k
        pos, vel, quat = read
        cost = (pos - window[0]).norm(dim=-1) + 0.5 * quat_yaw(quat).abs() + 0.1 * vel.norm(dim=-1).clamp_max(1.0)
        assert torch.allclose(out["reward"][:, 0], -cost, atol=1e-5), k
        # the metric is the true state after the step against the same-time reference, under both
        true_err = (states[k + 1][0] - window[0]).norm(dim=-1)
        assert torch.allclose(out["tracking_error_m"][:, 0], true_err, atol=1e-5), k
        td = out.exclude("reward", "done", "terminated", "truncated")


def test_an_unknown_timing_is_refused_in_one_line(make_tracking_env):
    from datt.errors import ConfigError

    with pytest.raises(ConfigError, match=r"env.obs.timing: unknown value 'late'; allowed: project, authors"):
        make_tracking_env(["env.obs.timing=late"], n=1)
