"""Export a trained policy for other runtimes: TorchScript, ONNX, and C99 for a microcontroller
(:mod:`datt.export.c_code`). ``datt export checkpoint=... format=c|torchscript|onnx``."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from omegaconf import DictConfig

from datt.adapt.l1 import L1Adaptation
from datt.configuration import instantiate_option
from datt.control.datt import DattController
from datt.control.factory import build_controller, require_current_state_timing
from datt.envs.factory import make_env
from datt.errors import ConfigError
from datt.export.c_code import L1Spec, PolicySpec, generate, l1_spec, policy_spec
from datt.runs import atomic_write

__all__ = [
    "FORMATS",
    "check_export_options",
    "Recording",
    "record_rollout",
    "export_spec",
    "generate",
    "PolicySpec",
    "L1Spec",
    "reference_action",
]


@dataclass
class Recording:
    """Per step ``k`` and drone ``n`` of a rollout: the controller's inputs and outputs.
    ``pos_m, vel_mps [K, N, 3]``, ``quat [K, N, 4]``, ``ref_m [K, N, H, 3]`` (world),
    ``d_hat [K, N, 3]``, ``cmd_hist [K, N, 4k]`` (scaled), ``action [K, N, 4]``; the L1 replay
    sequence is ``action[k]`` sent at step k with the state measured after it, ``vel_after [K, N, 3]``,
    ``quat_after [K, N, 4]`` and ``d_hat_after [K, N, 3]`` the estimate after that update."""

    pos_m: torch.Tensor
    vel_mps: torch.Tensor
    quat: torch.Tensor
    ref_m: torch.Tensor
    d_hat: torch.Tensor
    cmd_hist: torch.Tensor
    action: torch.Tensor
    vel_after: torch.Tensor
    quat_after: torch.Tensor
    d_hat_after: torch.Tensor


@torch.no_grad()
def record_rollout(cfg: DictConfig, controller: DattController, num_envs: int, steps: int, seed: int = 0) -> Recording:
    """Fly ``controller`` in the env of ``cfg`` (its ``traj``, ``disturbance``, ``adaptation``)
    for ``steps`` steps and record what it read and sent each step."""
    env = make_env(cfg, num_envs=num_envs, seed=seed)
    td = env.reset()
    controller.reset(env)
    rows: dict[str, list[torch.Tensor]] = {k: [] for k in Recording.__dataclass_fields__}
    for _ in range(steps):
        inputs = env.control_input()
        for key in ("pos_m", "vel_mps", "quat", "d_hat"):
            rows[key].append(inputs[key].clone())
        rows["ref_m"].append(inputs["ref_window_m"].clone())
        rows["cmd_hist"].append(inputs["cmd_history"].flatten(1).clone())
        action = controller.act(env, td)
        rows["action"].append(action.clone())
        td["action"] = action
        td = env.step(td)["next"].exclude("reward", "done", "terminated", "truncated")
        rows["vel_after"].append(env.sim.state.vel_mps.clone())
        rows["quat_after"].append(env.sim.state.quat.clone())
        rows["d_hat_after"].append(env.adaptation.d_hat.clone())
    return Recording(**{k: torch.stack(v) for k, v in rows.items()})


@torch.no_grad()
def reference_action(controller: DattController, obs, rec_slice: dict) -> torch.Tensor:
    """Torch's action for recorded inputs (``pos_m, vel_mps, quat [B, 3|4]``, ``ref_m [B, H, 3]``,
    ``d_hat [B, 3]``, ``cmd_hist [B, 4k]``): :func:`build_observation` + the network + the squash,
    the plain (unfrozen) path every other runtime is compared with."""
    from datt.envs.observations import build_observation

    state, ref = build_observation(
        rec_slice["pos_m"],
        rec_slice["vel_mps"],
        rec_slice["quat"],
        rec_slice["ref_m"].transpose(0, 1),
        obs.body_frame,
        obs.feedback,
    )
    state = torch.cat((state, rec_slice["cmd_hist"]), -1)
    loc = controller.net(state, ref, rec_slice["d_hat"])[..., :4]
    return (controller.center + controller.half * torch.tanh(loc)).clamp(
        controller.center - controller.half, controller.center + controller.half
    )


def export_spec(cfg: DictConfig, golden_steps: int = 40) -> tuple[PolicySpec, DattController, DictConfig]:
    """The C export's spec for ``cfg.checkpoint`` with the L1 estimator of ``cfg.adaptation``
    (must be an L1 option) and a golden case recorded from a flight on ``cfg.traj``."""
    controller, merged, _ = build_controller(cfg)
    require_current_state_timing(merged, "the exported app")
    # onboard the app answers the newest estimate within its own tick: nothing in flight to predict
    merged.env.obs.predict_latency = False
    if not isinstance(controller, DattController):
        raise ConfigError("controller: the export needs a DATT policy (datt, datt_l1, datt_rma)")
    l1 = instantiate_option(merged, "adaptation")
    if not isinstance(l1, L1Adaptation):
        raise ConfigError("adaptation: the C export runs the L1 estimator onboard; allowed: l1, l1_paper")
    env = make_env(merged, num_envs=1, seed=0)
    net = controller.net
    spec = policy_spec(net, env.horizon, env.params.obs, env.action_low, env.action_high)
    spec.l1 = l1_spec(l1, env.dt_s, env.params.quad.gravity_mps2)
    spec.dt_s, spec.ref_stride = float(env.dt_s), int(env.ref_offsets[1]) if env.horizon > 1 else 1
    rec = record_rollout(merged, DattController(controller.actor, frozen=False), num_envs=1, steps=golden_steps)
    k = golden_steps - 1  # the last step: the reference is well under way
    one = {name: getattr(rec, name)[k] for name in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_hist")}
    action = reference_action(controller, env.params.obs, one)[0]
    spec.golden = {
        "pos": one["pos_m"][0],
        "vel": one["vel_mps"][0],
        "quat": one["quat"][0],
        "ref": one["ref_m"][0],
        "d_hat": one["d_hat"][0],
        "cmd_hist": one["cmd_hist"][0],
        "action": action,
        # the L1 sequence: reset to the state after step 0, then step 1..K-1
        "l1_cmd": rec.action[:, 0],
        "l1_vel": rec.vel_after[:, 0],
        "l1_quat": rec.quat_after[:, 0],
        "l1_d_hat": replay_l1(
            l1, env.dt_s, env.params.quad.gravity_mps2, rec.action[:, 0], rec.vel_after[:, 0], rec.quat_after[:, 0]
        )[-1],
    }
    return spec, controller, merged


def replay_l1(
    l1: L1Adaptation, dt_s: float, gravity_mps2: float, cmd: torch.Tensor, vel: torch.Tensor, quat: torch.Tensor
) -> torch.Tensor:
    """The project's L1 over a recorded sequence (``cmd [K, 4]``, ``vel [K, 3]``, ``quat [K, 4]``):
    reset to (vel[0], quat[0]), then one update per later step; returns d̂ after each ``[K, 3]``
    (row 0: the reset's zero)."""
    from types import SimpleNamespace

    l1.bind(1, dt_s, gravity_mps2, "cpu", torch.float32)
    state = SimpleNamespace(vel_mps=vel[:1].float(), quat=quat[:1].float())
    l1.reset(torch.arange(1), None, state)
    out = [l1.d_hat.clone()[0]]
    for k in range(1, len(cmd)):
        state = SimpleNamespace(vel_mps=vel[k : k + 1].float(), quat=quat[k : k + 1].float())
        out.append(l1.update(state, cmd[k : k + 1].float())[0].clone())
    return torch.stack(out)


def write_c(spec: PolicySpec, out_dir, prefix: str = "datt") -> tuple:
    """Write ``<prefix>_policy.h`` and ``<prefix>_policy.c`` into ``out_dir``; returns both paths."""
    from pathlib import Path

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    header, source = generate(spec, prefix)
    paths = (out / f"{prefix}_policy.h", out / f"{prefix}_policy.c")
    for path, text in zip(paths, (header, source)):
        with atomic_write(path) as f:
            f.write(text)
    return paths


class ObservePolicyModule(torch.nn.Module):
    """The policy as one function of the measured state, for TorchScript and ONNX: ``(pos_m,
    vel_mps [N, 3], quat [N, 4], ref_m [N, H, 3], d_hat [N, 3], cmd_history [N, 4k]) -> action
    [N, 4]`` (world frame inputs, the scaled command history; the C export's ``datt_act``)."""

    def __init__(self, controller: DattController, horizon: int, obs) -> None:
        super().__init__()
        from datt.control.datt import ObservePolicy

        self.horizon, self.history = int(horizon), int(obs.action_history)
        self.inner = ObservePolicy(
            controller.net, horizon, controller.center, controller.half, bool(obs.body_frame), bool(obs.feedback)
        )

    def forward(self, pos_m, vel_mps, quat, ref_m, d_hat, cmd_history):
        return self.inner(pos_m, vel_mps, quat, ref_m.transpose(0, 1), d_hat, cmd_history)

    def example_inputs(self, n: int = 1) -> tuple[torch.Tensor, ...]:
        quat = torch.zeros(n, 4)
        quat[:, 0] = 1.0
        return (
            torch.zeros(n, 3),
            torch.zeros(n, 3),
            quat,
            torch.zeros(n, self.horizon, 3),
            torch.zeros(n, 3),
            torch.zeros(n, 4 * self.history),
        )


FORMATS = ("c", "app", "torchscript", "onnx")


def check_export_options(cfg: DictConfig) -> None:
    """``format`` and ``prefix`` of ``conf/export.yaml`` (what ``datt export`` writes, and the names in it)."""
    fmt = str(cfg.format)
    if fmt not in FORMATS:
        raise ConfigError(f"format: unknown value {fmt!r}; allowed: {', '.join(FORMATS)}")
    prefix = str(cfg.prefix)
    if not prefix.isidentifier():
        raise ConfigError(f"prefix: must be a C identifier, got {prefix!r}")
    if fmt == "app" and prefix != "datt":
        raise ConfigError(f"prefix: format=app uses the prefix datt (its sources call datt_*), got {prefix!r}")
