"""RMA baseline (paper §5.1): d̂ regressed from the last 50 (state, action) pairs.

After a reset the history is filled with the starting state and the hover command.

Network (paper): 3 Conv1d layers of 64 channels, kernel 8 (first with stride 2, as the authors),
ReLU, then fully connected 32 -> 32 -> 3 with ReLU between. Input per step, 14 values, each scaled
by a fixed constant so all are O(1); two layouts (``rma.inputs``):

* ``project`` (default): world velocity (3), attitude quaternion (4), body rates (3), command
  (thrust − g, body rates) (4): what the disturbance acts on, in the frame it lives in.
* ``authors``: the authors' ``train_rma.py`` inputs, the policy's base observation and its
  action: R^T p (3), R^T v (3), quaternion (4), command (thrust − g, body rates) (4).

``accel_dt_s`` (``rma.accel_input``, default on; not in the paper): the network also reads the
finite-difference acceleration of the velocity channel, ``(v_t − v_{t−1}) / dt`` (3 more input
channels, computed inside ``forward`` from the same history, so buffers and deploy are unchanged).
The disturbance is the acceleration the commands do not explain; left to the first conv layer,
that difference of O(1) velocities 20 ms apart is a ~2 % signal per m/s² of disturbance, and the
adapter's d̂ error stayed near 0.5 m/s² RMS (with it: ~0.35).

Training (:func:`datt.train.rma.train_rma`): the frozen DATT policy flies with the adapter's *own* predictions as
d̂ (so the adapter sees the state distribution it will face), and every step one Adam step
regresses the adapter's output to the true d over all N drones (batched over thousands of drones,
``rma.iterations`` steps, lr decayed linearly to ``rma.lr * rma.lr_final_frac``; paper: 10000
iterations of one 500-step rollout).
"""

from __future__ import annotations

from pathlib import Path

import torch
from torch import Tensor, nn

from datt.adapt.base import Adaptation
from datt.checkpoint import load_checkpoint
from datt.errors import ConfigError
from datt.paths import resolve_path
from datt.sim.frames import quat_rotate_inverse

FEATURES = 14
_COMMAND_SCALE = [0.1] + [0.2] * 3  # thrust offset from g (m/s²), body rates (rad/s)
# per layout: the scale of each feature, and where its velocity channel is (for the acceleration input)
INPUT_LAYOUTS = {
    "project": (torch.tensor([0.5] * 3 + [1.0] * 4 + [0.2] * 3 + _COMMAND_SCALE), slice(0, 3)),
    "authors": (torch.tensor([0.5] * 3 + [0.5] * 3 + [1.0] * 4 + _COMMAND_SCALE), slice(3, 6)),
}
ACCEL_SCALE = 0.1  # accelerations (m/s²) are O(10) in zigzag corners


def check_inputs(inputs: str, key: str = "rma.inputs") -> str:
    if inputs not in INPUT_LAYOUTS:
        raise ConfigError(f"{key}: unknown value {inputs!r}; allowed: {', '.join(INPUT_LAYOUTS)}")
    return inputs


class RmaNet(nn.Module):
    """``history [B, L, 14] -> d̂ [B, 3]`` (L = history length, default 50)."""

    def __init__(
        self,
        history_len: int = 50,
        channels: int = 64,
        kernel: int = 8,
        hidden: int = 32,
        accel_dt_s: float | None = None,
        inputs: str = "project",
    ) -> None:
        super().__init__()
        self.inputs = check_inputs(inputs)
        if history_len < 2 * kernel + 2 * (kernel - 1):
            raise ConfigError(
                f"adaptation.history_len: must be >= {4 * kernel - 2} for kernel {kernel}, got {history_len}"
            )
        if accel_dt_s is not None and not accel_dt_s > 0:
            raise ConfigError(f"env.dt_s: the RMA acceleration input needs dt > 0, got {accel_dt_s}")
        self.accel_dt_s = accel_dt_s
        channels_in = FEATURES + (3 if accel_dt_s is not None else 0)
        self.conv = nn.Sequential(
            nn.Conv1d(channels_in, channels, kernel, stride=2),
            nn.ReLU(),
            nn.Conv1d(channels, channels, kernel),
            nn.ReLU(),
            nn.Conv1d(channels, channels, kernel),
            nn.ReLU(),
        )
        with torch.no_grad():
            flat = self.conv(torch.zeros(1, channels_in, history_len)).numel()
        self.head = nn.Sequential(
            nn.Linear(flat, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, 3)
        )
        self.history_len = history_len
        scale, self._velocity = INPUT_LAYOUTS[self.inputs]
        self.register_buffer("scale", scale.clone())

    def forward(self, history: Tensor) -> Tensor:
        x = history * self.scale  # [B, L, 14]
        if self.accel_dt_s is not None:
            vel = history[..., self._velocity]
            accel = torch.cat((torch.zeros_like(vel[:, :1]), vel.diff(dim=1)), dim=1) / self.accel_dt_s
            x = torch.cat((x, accel * ACCEL_SCALE), dim=-1)  # [B, L, 17]
        return self.head(self.conv(x.transpose(1, 2)).flatten(1))


def step_features(state, cmd: Tensor, gravity_mps2: float, inputs: str = "project") -> Tensor:
    """``[N, 14]`` features of one step (unscaled) in the ``inputs`` layout."""
    c = cmd.clone()
    c[:, 0] -= gravity_mps2
    if inputs == "authors":
        body = quat_rotate_inverse(state.quat.unsqueeze(0), torch.stack((state.pos_m, state.vel_mps)))
        return torch.cat((body[0], body[1], state.quat, c), dim=-1)
    return torch.cat((state.vel_mps, state.quat, state.rate_radps, c), dim=-1)


class RmaAdaptation(Adaptation):
    """d̂ from an :class:`RmaNet` over a rolling history buffer ``[N, L, 14]`` (zeros after reset).

    ``checkpoint``: an RMA checkpoint written by ``fit_rma.py`` (or pass ``net``)."""

    def __init__(self, checkpoint: str | None = None, net: RmaNet | None = None) -> None:
        if net is None:
            if checkpoint is None:
                raise ConfigError(
                    "adaptation.checkpoint: RMA needs a trained adapter (python fit_rma.py base_checkpoint=<policy>)"
                )
            net = load_rma(checkpoint)
        self.net = net.eval()
        self.history_len = net.history_len

    def bind(self, n: int, dt_s: float, gravity_mps2: float, device, dtype) -> None:
        super().bind(n, dt_s, gravity_mps2, device, dtype)
        self.net.to(device)  # the adapter runs beside the env's drones (env.device)
        self.history = torch.zeros(n, self.history_len, FEATURES, device=device, dtype=dtype)

    def reset(self, idx: Tensor, true_d_mps2: Tensor | None = None, state=None) -> None:
        """New episode: the history reads as if the drone had been hovering where it starts
        (zeros would be a state the adapter never sees in flight)."""
        super().reset(idx, true_d_mps2, state)
        if state is None:
            self.history[idx] = 0.0
            return
        hover = torch.zeros(self.n, 4, dtype=self.history.dtype, device=self.history.device)
        hover[:, 0] = self.gravity_mps2
        features = step_features(state, hover, self.gravity_mps2, self.net.inputs)
        self.history[idx] = features[idx].unsqueeze(1).to(self.history.dtype)

    def update(self, state, cmd: Tensor, true_d_mps2: Tensor | None = None) -> Tensor:
        new = step_features(state, cmd, self.gravity_mps2, self.net.inputs).to(self.history.dtype)
        self.history = torch.cat((self.history[:, 1:], new.unsqueeze(1)), dim=1)
        with torch.no_grad():
            self.d_hat = self.net(self.history.float()).to(self.history.dtype)
        return self.d_hat


# -- checkpoints ---------------------------------------------------------------------------
def load_rma(path: str | Path) -> RmaNet:
    """The adapter network of an RMA checkpoint (written by ``fit_rma.py``)."""
    p = resolve_path(path)
    data = load_checkpoint(p, key="adaptation.checkpoint")
    if "rma" not in data:
        raise ConfigError(f"adaptation.checkpoint: {str(p)!r} holds no RMA adapter (a policy checkpoint?)")
    accel_dt_s = data.get("accel_dt_s")  # absent in adapters written before the acceleration input
    inputs = str(data.get("inputs", "project"))  # absent in adapters written before the layouts
    net = RmaNet(int(data["history_len"]), accel_dt_s=None if accel_dt_s is None else float(accel_dt_s), inputs=inputs)
    net.load_state_dict(data["rma"])
    return net
