"""Observation noise (env.obs.*_noise_*) and the simulator's domain randomisation inside the env."""

import pytest
import torch

from datt.envs import TrackingEnv
from datt.envs.params import EnvParams, ObsParams
from datt.errors import ConfigError
from datt.refs import Zigzag
from datt.sim import QuadrotorParams


def _env(obs: ObsParams, seed=0) -> TrackingEnv:
    return TrackingEnv(2000, Zigzag(), params=EnvParams(obs=obs), seed=seed)


@pytest.mark.parametrize(
    "key, cols, std", [("vel_noise_std_mps", slice(3, 6), 0.05), ("pos_noise_std_m", slice(0, 3), 0.02)]
)
def test_observation_noise_has_its_std_and_leaves_the_reward_alone(key, cols, std):
    clean, noisy = _env(ObsParams()), _env(ObsParams(**{key: std}))
    a, b = clean.reset(), noisy.reset()
    diff = b["state"][:, cols] - a["state"][:, cols]  # at rest and level: body = world frame
    assert diff.std().item() == pytest.approx(std, rel=0.05) and diff.mean().abs() < 0.005
    ra = clean.step(a.set("action", clean.hover_action))["next", "reward"]
    rb = noisy.step(b.set("action", clean.hover_action))["next", "reward"]
    assert torch.equal(ra, rb)


def test_attitude_noise_turns_the_observed_quaternion_by_the_set_angle():
    std = 0.02
    a, b = _env(ObsParams()).reset(), _env(ObsParams(att_noise_std_rad=std)).reset()
    qa, qb = a["state"][:, 6:10], b["state"][:, 6:10]
    angle = 2 * torch.acos((qa * qb).sum(-1).abs().clamp(max=1.0))
    # the angle of a 3-D Gaussian rotation vector: mean std * sqrt(8 / pi)
    assert angle.mean().item() == pytest.approx(std * (8 / torch.pi) ** 0.5, rel=0.05)


@pytest.mark.parametrize("key", ["vel_noise_std_mps", "att_noise_std_rad"])
def test_negative_observation_noise_names_the_key(key):
    with pytest.raises(ConfigError, match=f"env.obs.{key}"):
        EnvParams(obs=ObsParams(**{key: -0.1})).validate()


def test_env_redraws_the_vehicle_of_each_drone_it_resets():
    quad = QuadrotorParams(mass_spread=0.1, latency_steps_max=3, rate_model="mixed")
    env = TrackingEnv(64, Zigzag(), params=EnvParams(quad=quad), seed=0)
    first = env.sim.thrust_scale.clone()
    td = env.reset()  # every drone
    scale, delay = env.sim.thrust_scale.clone(), env.sim.latency.delay.clone()
    assert not torch.equal(scale, first)
    assert scale.std() > 0.02 and len(delay.unique()) == 3
    td.set("_reset", torch.arange(64).unsqueeze(-1) < 8)
    env.reset(td)
    assert not torch.equal(env.sim.thrust_scale[:8], scale[:8])
    assert torch.equal(env.sim.thrust_scale[8:], scale[8:])


@pytest.mark.parametrize("dtype", ["float32", "float64"])
def test_measurement_adds_its_own_draws_in_order_and_draws_nothing_when_off(dtype):
    """``_measure``: pos + σp·n1, vel + σv·n2, quat turned by σa·n3, with n1..n3 the env generator's
    next draws in that order, in the env's dtype; with every noise off it returns the true tensors
    and leaves the generator alone (the nominal random stream and the seeded banks stay as they are)."""
    from datt.sim.frames import quat_exp_rotvec, quat_mul, quat_normalize

    noisy = TrackingEnv(8, Zigzag(), params=EnvParams(dtype=dtype, obs=ObsParams(
        pos_noise_std_m=0.02, vel_noise_std_mps=0.05, att_noise_std_rad=0.01)), seed=3)  # fmt: skip
    s = noisy.sim.state
    pos, vel, quat = s.pos_m + 0.3, s.vel_mps - 0.2, s.quat
    replay = torch.Generator().manual_seed(0)
    replay.set_state(noisy.generator.get_state())
    mp, mv, mq = noisy._measure(pos, vel, quat)
    torch.testing.assert_close(mp, pos + 0.02 * torch.randn(pos.shape, generator=replay, dtype=noisy.dtype))
    torch.testing.assert_close(mv, vel + 0.05 * torch.randn(vel.shape, generator=replay, dtype=noisy.dtype))
    turn = quat_exp_rotvec(0.01 * torch.randn(vel.shape, generator=replay, dtype=noisy.dtype))
    torch.testing.assert_close(mq, quat_normalize(quat_mul(quat, turn)))
    assert mp.dtype == mv.dtype == mq.dtype == noisy.dtype

    clean = TrackingEnv(8, Zigzag(), params=EnvParams(dtype=dtype), seed=3)
    before = clean.generator.get_state()
    out = clean._measure(pos, vel, quat)
    assert all(a is b for a, b in zip(out, (pos, vel, quat)))
    assert torch.equal(clean.generator.get_state(), before)
