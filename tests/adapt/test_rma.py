import csv
import logging
import time

import pytest
import torch
from omegaconf import OmegaConf
from tensordict import TensorDict

from datt.adapt.rma import ACCEL_SCALE, FEATURES, RmaAdaptation, RmaNet, load_rma
from datt.configuration import compose
from datt.envs.factory import make_env
from datt.errors import ConfigError
from datt.train.rma import train_rma


def tiny_rma_cfg(checkpoint, *extra):
    """``fit_rma.py`` for ``checkpoint``: two iterations on eight drones."""
    return compose("fit_rma", [f"base_checkpoint={checkpoint}", "rma.iterations=2", "rma.num_envs=8", *extra])


def test_network_shapes_and_paper_structure():
    net = RmaNet(50)
    convs = [m for m in net.conv if isinstance(m, torch.nn.Conv1d)]
    assert [(c.in_channels, c.out_channels, c.kernel_size[0]) for c in convs] == [(14, 64, 8), (64, 64, 8), (64, 64, 8)]
    linears = [m for m in net.head if isinstance(m, torch.nn.Linear)]
    assert [lin.out_features for lin in linears] == [32, 32, 3]
    assert net(torch.zeros(5, 50, FEATURES)).shape == (5, 3)
    with pytest.raises(ConfigError, match="history_len"):
        RmaNet(10)


def test_acceleration_input_is_the_velocity_difference():
    net = RmaNet(50, accel_dt_s=0.02)
    assert net.conv[0].in_channels == FEATURES + 3
    seen = {}
    net.conv[0].register_forward_pre_hook(lambda mod, args: seen.update(x=args[0]))
    history = torch.zeros(2, 50, FEATURES)
    accel = torch.tensor([1.0, -2.0, 3.0])
    history[:, :, :3] = torch.arange(50.0)[:, None] * 0.02 * accel  # v = a t
    assert net(history).shape == (2, 3)
    extra = seen["x"][:, FEATURES:]  # [B, 3, L]
    assert torch.allclose(extra[:, :, 1:], (accel * ACCEL_SCALE)[None, :, None].expand(2, 3, 49), atol=1e-4)
    assert extra[:, :, 0].abs().sum() == 0  # no difference before the first step
    with pytest.raises(ConfigError, match="dt"):
        RmaNet(50, accel_dt_s=0.0)


def test_history_buffer_across_partial_resets():
    env = make_env(compose("sim", ["disturbance=constant"]), num_envs=4)
    adapter = RmaAdaptation(net=RmaNet(50))
    env.adaptation = adapter
    adapter.bind(4, env.dt_s, 9.81, "cpu", torch.float32)
    td = env.reset()
    for _ in range(60):
        td["action"] = env.hover_action
        td = env.step(td)["next"].exclude("reward", "done", "terminated", "truncated")
        assert adapter.history.shape == (4, 50, FEATURES)
    assert adapter.history[:, 0].abs().sum() > 0  # full after 60 steps
    latest = adapter.history[:, -1].clone()
    assert torch.allclose(latest[:, :3], env.sim.state.vel_mps)
    env.reset(TensorDict({"_reset": torch.tensor([[False], [True], [False], [False]])}, [4]))
    assert torch.equal(adapter.history[0, -1], latest[0])
    start = adapter.history[1]
    # a fresh episode reads as hovering at the start state: every row the same, at rest, level
    assert torch.equal(start, start[:1].expand(50, -1))
    assert start[0, :3].abs().sum() == 0 and start[0, 3] == 1 and start[0, 10:].abs().sum() == 0
    td["action"] = env.hover_action
    env.step(td)
    assert torch.equal(adapter.history[1, :-1], start[1:]) and not torch.equal(adapter.history[1, -1], start[0])


def test_rma_training_loss_decreases(tmp_path, tiny_policy_checkpoint):
    cfg = compose(
        "fit_rma",
        [
            f"base_checkpoint={tiny_policy_checkpoint}",
            "disturbance=constant",
            "rma.iterations=150",
            "rma.num_envs=128",
            "rma.lr=3e-3",
            "rma.log_every=10",
        ],
    )
    result = train_rma(cfg, tmp_path)
    losses = [h["loss"] for h in result["history"]]
    assert sum(losses[-3:]) / 3 < 0.6 * sum(losses[:2]) / 2, losses
    net = load_rma(tmp_path / "rma.pt")
    assert isinstance(net, RmaNet) and net.accel_dt_s == pytest.approx(0.02)  # rma.accel_input default


def test_policy_checkpoint_is_not_an_rma_checkpoint(tiny_policy_checkpoint):
    with pytest.raises(ConfigError, match="holds no RMA adapter"):
        load_rma(tiny_policy_checkpoint)
    with pytest.raises(ConfigError, match="adaptation.checkpoint"):
        RmaAdaptation()


def test_bad_rma_lr_final_frac_is_one_line(tmp_path, tiny_policy_checkpoint):
    cfg = tiny_rma_cfg(tiny_policy_checkpoint, "rma.lr_final_frac=0")
    with pytest.raises(ConfigError, match=r"^rma.lr_final_frac: must be a finite number in \(0, 1\], got 0.0$"):
        train_rma(cfg, tmp_path)


def test_adapter_written_before_the_acceleration_input_still_loads(tmp_path):
    from datt.checkpoint import save_checkpoint

    old = RmaNet(50)  # the paper's 14-channel network, saved without "accel_dt_s"
    save_checkpoint(tmp_path / "old_rma.pt", {"rma": old.state_dict(), "history_len": 50})
    net = load_rma(tmp_path / "old_rma.pt")
    assert net.accel_dt_s is None and net.conv[0].in_channels == FEATURES
    history = torch.randn(3, 50, FEATURES)
    assert torch.equal(net(history), old(history))


def test_authors_inputs_are_the_body_frame_base_observation_and_the_command():
    """``rma.inputs=authors`` (their train_rma.py): R^T p, R^T v, q, then the command with g
    taken off the thrust; its acceleration channel differentiates the body-frame velocity."""
    from types import SimpleNamespace

    from datt.adapt.rma import step_features
    from datt.sim.frames import quat_from_euler, quat_rotate_inverse

    quat = quat_from_euler(torch.tensor([0.2, -0.1]), torch.tensor([0.3, 0.0]), torch.tensor([1.0, -2.0]))
    state = SimpleNamespace(
        pos_m=torch.tensor([[1.0, 2.0, 0.5], [-0.3, 0.1, 0.0]]),
        vel_mps=torch.tensor([[0.5, -1.0, 0.2], [1.0, 0.0, 0.0]]),
        quat=quat,
        rate_radps=torch.ones(2, 3),
    )
    cmd = torch.tensor([[12.0, 0.1, -0.2, 0.3], [9.81, 0.0, 0.0, 0.0]])
    got = step_features(state, cmd, 9.81, "authors")
    torch.testing.assert_close(got[:, 0:3], quat_rotate_inverse(quat, state.pos_m))
    torch.testing.assert_close(got[:, 3:6], quat_rotate_inverse(quat, state.vel_mps))
    torch.testing.assert_close(got[:, 6:10], quat)
    torch.testing.assert_close(got[:, 10:], cmd - torch.tensor([9.81, 0.0, 0.0, 0.0]))
    project = step_features(state, cmd, 9.81)
    torch.testing.assert_close(project[:, :3], state.vel_mps)  # the default layout is unchanged
    torch.testing.assert_close(project[:, 7:10], state.rate_radps)
    net = RmaNet(50, accel_dt_s=0.02, inputs="authors")
    seen = {}
    net.conv[0].register_forward_pre_hook(lambda mod, args: seen.update(x=args[0]))
    history = torch.zeros(1, 50, FEATURES)
    history[:, :, 3:6] = torch.arange(50.0)[:, None] * 0.02 * torch.tensor([1.0, -2.0, 3.0])
    net(history)
    torch.testing.assert_close(
        seen["x"][0, FEATURES:, 1:], (torch.tensor([1.0, -2.0, 3.0]) * ACCEL_SCALE)[:, None].expand(3, 49)
    )


def test_rma_inputs_layout_is_saved_with_the_adapter(tmp_path, tiny_policy_checkpoint):
    train_rma(tiny_rma_cfg(tiny_policy_checkpoint, "rma.inputs=authors", "rma.accel_input=false"), tmp_path)
    net = load_rma(tmp_path / "rma.pt")
    assert net.inputs == "authors" and net.accel_dt_s is None
    bad = compose("fit_rma", [f"base_checkpoint={tiny_policy_checkpoint}", "rma.inputs=world"])
    with pytest.raises(ConfigError, match=r"^rma.inputs: unknown value 'world'; allowed: project, authors$"):
        train_rma(bad, tmp_path)


def test_fit_rma_takes_the_env_from_the_policy_and_refuses_env_overrides(tmp_path):
    """The adapter is fitted on the policy's own env (its checkpoint's config): fit_rma.py has no
    env settings, so an ``env.*`` override is refused in one line instead of being ignored."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    out = subprocess.run(
        [sys.executable, str(root / "fit_rma.py"), "env.safety_box_m=[100,100,100]", f"hydra.run.dir={tmp_path}"],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=tmp_path,
    )
    assert out.returncode == 2 and out.stderr.startswith("error: env.safety_box_m"), out.stderr[-1000:]
    assert len(out.stderr.strip().splitlines()) == 1


def test_fit_rma_flies_the_frozen_policy_under_its_own_disturbance_and_references(tiny_policy_checkpoint):
    """The adapter is fitted on the policy's env with the fit's disturbance and references (not
    the training run's), the policy's weights frozen, the env eager, the drones seeded by ``seed``."""
    from datt.configuration import structured
    from datt.refs import Polygon
    from datt.sim import ConstantForce
    from datt.train.rma import RmaParams, _setup

    def setup(seed, *extra):
        cfg = tiny_rma_cfg(tiny_policy_checkpoint, "disturbance=constant", "traj=star", f"seed={seed}", *extra)
        return _setup(cfg, structured(RmaParams, cfg.rma, "rma"))

    env, adapter, controller, base = setup(3, "rma.history_len=40")
    assert adapter.net.history_len == 40 and adapter.net.accel_dt_s == env.dt_s  # rma.accel_input: true
    assert setup(3, "rma.accel_input=false")[1].net.accel_dt_s is None
    assert type(env.disturbance) is ConstantForce and isinstance(env.traj, Polygon)  # Brownian is a ConstantForce
    assert env.n == 8 and env.adaptation is adapter and "actor" in base
    assert not env.params.compile
    assert not any(p.requires_grad for p in controller.actor.parameters())
    assert env.generator.initial_seed() == 3 and setup(4)[0].generator.initial_seed() == 4


@pytest.mark.parametrize(
    "value, message",
    [
        ("''", r"^base_checkpoint: fit_rma.py needs the policy checkpoint to adapt \(base_checkpoint=\.\.\.\)$"),
        ("/nonexistent/policy.pt", r"^base_checkpoint: "),
    ],
)
def test_fit_rma_without_a_policy_is_one_line_naming_base_checkpoint(tmp_path, value, message):
    cfg = compose("fit_rma", [f"base_checkpoint={value}", "rma.iterations=1", "rma.num_envs=8"])
    with pytest.raises(ConfigError, match=message):
        train_rma(cfg, tmp_path)


def test_the_fit_s_loss_is_the_squared_error_summed_over_axes_and_averaged_over_drones():
    from datt.train.rma import adapter_loss

    pred = torch.tensor([[1.0, 2.0, 0.0], [0.0, 1.0, 0.0]])
    true = torch.tensor([[0.0, 0.0, 0.0], [0.0, 3.0, 1.0]])
    assert adapter_loss(pred, true).item() == pytest.approx(((1 + 4) + (4 + 1)) / 2)


def test_the_fit_runs_its_iterations_once_each_with_the_lr_decayed_linearly(
    tmp_path, tiny_policy_checkpoint, caplog, monkeypatch
):
    """``rma.iterations`` steps, numbered from 1, each logged at ``log_every=1``; after step k the
    lr is ``lr * (1 - (1 - lr_final_frac) * k / iterations)``, ending at ``lr * lr_final_frac``.
    Its progress lines (on a clock that stands still): the first iteration and the last."""
    from types import SimpleNamespace

    import datt.progress

    monkeypatch.setattr(datt.progress, "time", SimpleNamespace(monotonic=lambda: 0.0))
    caplog.set_level(logging.INFO)
    cfg = tiny_rma_cfg(tiny_policy_checkpoint, "rma.iterations=4", "rma.log_every=1", "rma.lr=1e-3")
    OmegaConf.update(cfg, "rma.lr_final_frac", 0.1)
    start = time.perf_counter()
    result = train_rma(cfg, tmp_path, progress=True)
    rows = result["history"]
    assert 0 < result["wall_s"] <= time.perf_counter() - start
    assert [r["iteration"] for r in rows] == [1, 2, 3, 4]
    assert [r["lr"] for r in rows] == pytest.approx([1e-3 * (1 - 0.9 * k / 4) for k in (1, 2, 3, 4)])
    with open(tmp_path / "rma_metrics.csv", newline="") as f:
        assert [int(r["step"]) for r in csv.DictReader(f)] == [1, 2, 3, 4]  # the iteration
    printed = [r.getMessage() for r in caplog.records if r.name == "datt.progress"]
    assert printed == [
        f"fit_rma: {r['iteration']} / 4 iterations ({25 * r['iteration']:.1f} %), "
        f"loss {r['loss']:.4f} (m/s²)², err {r['tracking_error_m']:.3f} m"
        for r in (rows[0], rows[-1])
    ]
    saved = torch.load(tmp_path / "rma.pt", weights_only=True)
    policy = torch.load(tiny_policy_checkpoint, weights_only=True)
    assert saved["base_checkpoint"] == str(tiny_policy_checkpoint) and saved["frames"] == policy["frames"]
    assert OmegaConf.to_container(OmegaConf.create(saved["config_yaml"])) == OmegaConf.to_container(cfg, resolve=True)


def test_fit_rma_evaluates_under_the_disturbance_it_fitted_under(tiny_policy_checkpoint, tmp_path):
    """``fit_rma.py disturbance=constant_authors`` (the authors' Table 4 setting) fits and then
    evaluates every d̂ source under that disturbance, and records the node it flew."""
    from datt.tasks.rma import run_rma

    extra = ["disturbance=constant_authors", "bank@eval.bank=paper_figure", "eval.plots=false"]
    metrics = run_rma(tiny_rma_cfg(tiny_policy_checkpoint, *extra), tmp_path)
    assert set(metrics["conditions"]) == {"d_hat=0", "l1", "rma", "privileged"}
    for cond in metrics["conditions"].values():
        assert cond["disturbance"] == {"_target_": "datt.sim.ConstantForce", "max_mps2": 1.0}
        assert set(cond["groups"]) == {"zigzag", "chained_poly"}
