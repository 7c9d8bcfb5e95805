"""DATT actor and critic (paper appendix B) as TorchRL modules.

Both read the env's observation keys ``state [*, S]`` (S = 13, plus 4 per command of
``env.obs.action_history``), ``ref [*, H, 3]`` and ``d_hat [*, 3]``:

    h  = encoder(ref)                         feedforward embedding (conv1d over the H points)
    x  = [state, h, d_hat]
    actor:  MLP(x) -> (loc, scale) -> TanhNormal over the action bounds
    critic: MLP(x) -> V

The paper's encoder: 3 Conv1d layers, 16 filters, kernel 3, ReLU, then a linear projection to
32 dims. We pad the convolutions ("same" length) so every horizon H >= 1 works, including the
H = 1 ablation. ``encoder=mlp`` (two linear layers over the flattened points) and ``none``
(flattened points straight into the MLP) are alternatives. ``encoder=authors`` is the encoder
the authors trained with (``learning/utils/feedforward_feature_extractor.py``, KevinHuang8/DATT
42ddfc8): Conv1d(3 → 8, k 3), ReLU, Conv1d(8 → 8, k 3), unpadded, flattened, so its width
grows with H, 8 (H − 4) features; for H < 5 their convolutions do not fit the sequence and the
only configuration their code can run is ``conv_extractor=False`` (``learning/train_policy.py``
lines 177-180, SB3's flatten extractor): the raw points go to the MLP, as ``none``.
MLPs: 3 x 64 ReLU (paper).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field
from typing import Any

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torch.nn import functional as F
from torchrl.modules import ProbabilisticActor, TanhNormal, ValueOperator

from datt.configuration import POSITIVE_WEIGHT, Range, check_ranges, ranged
from datt.envs.observations import FEEDBACK, STATE_DIM
from datt.envs.tracking import action_center_half
from datt.errors import ConfigError

OBS_KEYS = ["state", "ref", "d_hat"]
ENCODERS = ("conv", "mlp", "none", "authors")
WIDTH = Range(1, 1 << 16, integer=True)  # layer widths and channel counts
INIT_STD = Range(0.0, 10.0, low_open=True, length=4)  # thrust, wx, wy, wz
AUTHORS_MIN_HORIZON = 5  # two unpadded k-3 convolutions need 5 points for one output


@dataclass
class PolicyParams:
    """``conf/policy/datt.yaml``."""

    encoder: str = ranged("conv", Range(choices=ENCODERS))
    conv_channels: int = ranged(16, WIDTH)
    conv_layers: int = ranged(3, Range(1, 64, integer=True))
    kernel_size: int = ranged(3, Range(1, 99, integer=True))  # and odd
    embed_dim: int = ranged(32, WIDTH)
    hidden: list[int] = ranged([64, 64, 64], WIDTH)
    use_d_hat: bool = True
    # Pre-tanh std of the initial policy per action (thrust, wx, wy, wz). Rates need a small one:
    # rate noise integrates into an attitude random walk (0.15 x 20 rad/s tips drones over
    # within ~1 s, so every early episode crashes); 0.05 ≈ 1 rad/s, the SB3 default std.
    # A single number applies to all four.
    init_std: Any = field(default_factory=lambda: [0.15, 0.15, 0.15, 0.15])
    # Floor of the pre-tanh std, every action: scale = softplus(head + b) + min_std (tensordict's
    # biased softplus, b = inv_softplus(1 − min_std)). 0.01 is tensordict's default, so checkpoints
    # without this key keep their function. Without an entropy bonus PPO shrinks the std as far as
    # it helps the return, down to this floor (docs/training.md).
    min_std: float = ranged(0.01, Range(0.0, 10.0, low_open=True))  # and below every init_std
    # Ceiling of the pre-tanh std, every action; null = none (the mapping above). With a ceiling
    # the std is min_std + (max_std − min_std) · sigmoid(head), bounded on both sides. Without
    # one, training at γ = 0.95 let the yaw-rate and thrust std grow without bound in some
    # states (bang-bang noise: crashes, slower steps; docs/training.md).
    max_std: float | None = ranged(None, Range(0.0, 10.0, low_open=True, optional=True))  # and above every init_std
    # Fixed gain on the tracking-error inputs (feedback and feedforward, metres) before the net.
    # Tracking errors are O(0.01-0.1 m) while the other inputs are O(1): unscaled, a 2 cm error
    # moves the first layer by ~1e-3, and PPO (Adam steps of ~lr per weight) takes a long time to
    # grow the large input weights a precise controller needs. 1 = the paper's raw inputs (and
    # what checkpoints without this key were trained with).
    error_scale: float = ranged(1.0, POSITIVE_WEIGHT)

    def validate(self) -> None:
        """Rules across fields (each field's own range is declared with it, :func:`ranged`)."""
        check_ranges(self, "policy")
        if self.kernel_size % 2 == 0:
            raise ConfigError(f"policy.kernel_size: must be odd and >= 1, got {self.kernel_size}")
        if isinstance(self.init_std, (int, float)):
            self.init_std = [float(self.init_std)] * 4
        if not isinstance(self.init_std, (list, tuple)):
            raise ConfigError(f"policy.init_std: must be four values > 0 (thrust, wx, wy, wz), got {self.init_std!r}")
        INIT_STD.check(list(self.init_std), "policy.init_std")
        self.init_std = [float(s) for s in self.init_std]
        lowest = min(self.init_std)
        if not 0 < self.min_std < lowest:
            raise ConfigError(
                f"policy.min_std: must be > 0 and below every policy.init_std ({lowest}), got {self.min_std}"
            )
        highest = max(self.init_std)
        if self.max_std is not None and not float(self.max_std) > highest:
            raise ConfigError(
                f"policy.max_std: must be null or above every policy.init_std ({highest}), got {self.max_std}"
            )


class RefEncoder(nn.Module):
    """``ref [*, H, 3] -> [*, embed_dim]`` (``none``: flattened, ``[*, 3H]``)."""

    def __init__(self, horizon: int, p: PolicyParams) -> None:
        super().__init__()
        self.kind = p.encoder
        if p.encoder == "conv":
            layers: list[nn.Module] = []
            ch = 3
            for _ in range(p.conv_layers):
                layers += [nn.Conv1d(ch, p.conv_channels, p.kernel_size, padding=p.kernel_size // 2), nn.ReLU()]
                ch = p.conv_channels
            self.conv = nn.Sequential(*layers)
            self.proj = nn.Linear(p.conv_channels * horizon, p.embed_dim)
            self.out_dim = p.embed_dim
        elif p.encoder == "mlp":
            self.net = nn.Sequential(nn.Linear(3 * horizon, 64), nn.ReLU(), nn.Linear(64, p.embed_dim))
            self.out_dim = p.embed_dim
        elif p.encoder == "authors" and horizon >= AUTHORS_MIN_HORIZON:
            # no activation after the second conv: the MLP's first linear layer follows, as theirs
            self.conv = nn.Sequential(nn.Conv1d(3, 8, 3), nn.ReLU(), nn.Conv1d(8, 8, 3))
            self.out_dim = 8 * (horizon - 4)
        else:  # none, and the authors' flatten extractor for H < 5
            self.kind = "none"
            self.out_dim = 3 * horizon

    def forward(self, ref: torch.Tensor) -> torch.Tensor:
        lead = ref.shape[:-2]
        flat = ref.reshape(-1, *ref.shape[-2:])  # [B, H, 3]
        if self.kind == "conv":
            h = flat.transpose(1, 2).unsqueeze(2)  # [B, 3, 1, H]
            for layer in self.conv:
                if isinstance(layer, nn.Conv1d):
                    # The same Conv1d weights applied as a 1 x k conv2d: on CPU oneDNN's 2-D path
                    # is 1.4-2.4x faster forward+backward than its 1-D one at these sizes.
                    h = F.conv2d(h, layer.weight.unsqueeze(2), layer.bias, padding=(0, layer.padding[0]))
                else:
                    h = layer(h)
            out = torch.relu(self.proj(h.flatten(1)))  # h [B, C, 1, H]: same C-major order as [B, C, H]
        elif self.kind == "authors":
            out = self.conv(flat.transpose(1, 2)).flatten(1)  # [B, 8, H - 4], channel-major as theirs
        elif self.kind == "mlp":
            out = torch.relu(self.net(flat.flatten(1)))
        else:
            out = flat.flatten(1)
        return out.reshape(*lead, -1)


class TrackingNet(nn.Module):
    """``(state, ref, d_hat[, critic_ref]) -> [*, out_dim]`` : encoder + MLP. ``critic_points``
    K > 0: the MLP also reads ``critic_ref [*, K, 3]`` flattened (the asymmetric critic)."""

    def __init__(
        self, horizon: int, out_dim: int, p: PolicyParams, state_dim: int = STATE_DIM, critic_points: int = 0
    ) -> None:
        super().__init__()
        self.use_d_hat = p.use_d_hat
        self.error_scale = float(p.error_scale)
        self.state_dim = state_dim
        state_scale = torch.ones(state_dim)
        state_scale[FEEDBACK] = self.error_scale  # the feedback error R^T (p − p_d(t))
        self.register_buffer("state_scale", state_scale, persistent=False)
        self.encoder = RefEncoder(horizon, p)
        self.critic_points = critic_points
        dims = [state_dim + self.encoder.out_dim + (3 if p.use_d_hat else 0) + 3 * critic_points, *p.hidden]
        layers: list[nn.Module] = []
        for a, b in zip(dims[:-1], dims[1:]):
            layers += [nn.Linear(a, b), nn.ReLU()]
        self.mlp = nn.Sequential(*layers)
        self.head = nn.Linear(dims[-1], out_dim)

    def forward(
        self, state: torch.Tensor, ref: torch.Tensor, d_hat: torch.Tensor, critic_ref: torch.Tensor | None = None
    ) -> torch.Tensor:
        if self.error_scale != 1.0:
            state, ref = state * self.state_scale, ref * self.error_scale
        parts = [state, self.encoder(ref)] + ([d_hat] if self.use_d_hat else [])
        if self.critic_points:
            parts.append(critic_ref.flatten(-2))
        return self.head(self.mlp(torch.cat(parts, dim=-1)))


def make_actor(
    horizon: int, action_low: torch.Tensor, action_high: torch.Tensor, p: PolicyParams, state_dim: int = STATE_DIM
) -> ProbabilisticActor:
    """TanhNormal policy over ``[low, high]``; initial mean = hover (thrust g, zero rates).
    ``state_dim``: width of the env's ``state`` (``env.state_dim``)."""
    p.validate()
    net = TrackingNet(horizon, 8, p, state_dim)
    low, high = action_low.float(), action_high.float()
    center, half = action_center_half(low, high)
    hover = torch.zeros(4)
    hover[0] = float(low[0] + 9.8)  # bounds are g + [-9.8, 30]: g ≈ low + 9.8
    with torch.no_grad():
        net.head.weight.mul_(0.01)
        net.head.bias.zero_()
        net.head.bias[:4] = torch.atanh(((hover - center) / half).clamp(-0.99, 0.99))
        if p.max_std is None:
            # scale = softplus(x + b) + min_std with softplus(b) = 1 − min_std; this bias (b's
            # shift left out) starts the std at init_std + ~min_std (tensordict's mapping)
            net.head.bias[4:] = torch.tensor([_inv_softplus(s) - _inv_softplus(1.0) for s in p.init_std])
        else:  # the std starts at init_std exactly
            share = torch.tensor([(s - p.min_std) / (p.max_std - p.min_std) for s in p.init_std])
            net.head.bias[4:] = torch.logit(share)
    if p.max_std is None:
        extractor = NormalParamExtractor(scale_mapping=f"biased_softplus_1.0_{p.min_std}", scale_lb=p.min_std)
    else:
        extractor = BoundedNormalParams(p.min_std, float(p.max_std))
    module = nn.Sequential(net, extractor)
    td_module = TensorDictModule(_Args(module), in_keys=OBS_KEYS, out_keys=["loc", "scale"])
    return ProbabilisticActor(
        td_module,
        in_keys=["loc", "scale"],
        distribution_class=TanhNormal,
        distribution_kwargs={"low": low, "high": high},
        return_log_prob=True,
    )


class BoundedNormalParams(nn.Module):
    """``[*, 2A] -> (loc [*, A], scale [*, A])`` with scale = lo + (hi − lo) · sigmoid(x):
    a std bounded on both sides (``policy.max_std``)."""

    def __init__(self, lo: float, hi: float) -> None:
        super().__init__()
        self.lo, self.span = lo, hi - lo

    def forward(self, tensor: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc, raw = tensor.chunk(2, -1)
        return loc, self.lo + self.span * torch.sigmoid(raw)


def make_critic(horizon: int, p: PolicyParams, state_dim: int = STATE_DIM, critic_points: int = 0) -> ValueOperator:
    """V(s) over the policy's inputs; with ``critic_points`` K > 0 also over the env's
    ``critic_ref [*, K, 3]`` (``env.obs.critic_ref_points``)."""
    p.validate()
    in_keys = OBS_KEYS + (["critic_ref"] if critic_points else [])
    return ValueOperator(TrackingNet(horizon, 1, p, state_dim, critic_points), in_keys=in_keys)


class InferenceNet(nn.Module):
    """A trained :class:`TrackingNet` rewritten for fast inference, same function.

    ``(state [N, 13], ref [N, H, 3], d_hat [N, 3]) -> [N, out]``: the head keeps only the first
    ``out`` rows and the error gain is folded into the weights. With ``dense_encoder`` each
    Conv1d over the fixed H points becomes the equivalent dense layer (the first one reading the
    H-major layout directly, no transpose): at batch 1 the cost is per-op dispatch, not arithmetic,
    and this halves the op count; at large batches the dense layers do ~3x the conv's arithmetic,
    so callers keep the convs there. Copies the weights: rebuild it after the net changes.
    """

    def __init__(self, net: TrackingNet, horizon: int, out: int, dense_encoder: bool = True) -> None:
        super().__init__()
        enc, self.use_d_hat, self.kind = net.encoder, net.use_d_hat, net.encoder.kind
        scale = net.error_scale
        layers: list[nn.Module] = []
        if self.kind == "conv" and dense_encoder:
            self.kind = "dense"
            convs = [m for m in enc.conv if isinstance(m, nn.Conv1d)]
            for i, conv in enumerate(convs):
                weight, bias = _dense_conv1d(conv, horizon)
                if i == 0:  # H-major input index -> channel-major column of the conv's matrix; error gain
                    weight = weight[:, torch.arange(3 * horizon).reshape(3, horizon).T.reshape(-1)] * scale
                layers += [_linear(weight, bias), nn.ReLU()]
        elif self.kind in ("conv", "authors"):
            self.kind = "conv"
            layers += list(copy.deepcopy(enc.conv))
            with torch.no_grad():
                layers[0].weight.mul_(scale)
        elif self.kind == "mlp":
            layers += [copy.deepcopy(enc.net), nn.ReLU()]
            with torch.no_grad():
                layers[0][0].weight.mul_(scale)
        self.encoder = nn.Sequential(*layers)
        self.proj = nn.Sequential(copy.deepcopy(enc.proj), nn.ReLU()) if enc.kind == "conv" else nn.Identity()
        self.mlp = copy.deepcopy(net.mlp)
        # the first layer's feedback columns take the error gain, and with encoder "none" also the
        # columns of the raw error points, which follow the state
        with torch.no_grad():
            self.mlp[0].weight[:, FEEDBACK].mul_(scale)
            if self.kind == "none":
                self.mlp[0].weight[:, net.state_dim : net.state_dim + 3 * horizon].mul_(scale)
        self.head = _linear(net.head.weight.detach()[:out], net.head.bias.detach()[:out])

    def forward(self, state: torch.Tensor, ref: torch.Tensor, d_hat: torch.Tensor) -> torch.Tensor:
        if self.kind == "conv":
            emb = self.proj(self.encoder(ref.transpose(1, 2)).flatten(1))
        else:
            emb = self.proj(self.encoder(ref.reshape(ref.shape[0], -1)))
        parts = [state, emb] + ([d_hat] if self.use_d_hat else [])
        return self.head(self.mlp(torch.cat(parts, dim=-1)))


def _dense_conv1d(conv: nn.Conv1d, length: int) -> tuple[torch.Tensor, torch.Tensor]:
    """``conv`` over inputs of ``length`` as ``(W [C_out L', C_in L], b)`` on channel-major flattening."""
    size = conv.in_channels * length
    basis = torch.eye(size, dtype=conv.weight.dtype).reshape(size, conv.in_channels, length)
    with torch.no_grad():
        out = conv._conv_forward(basis, conv.weight, None)  # [size, C_out, L']
    return out.reshape(size, -1).T.contiguous(), conv.bias.detach().repeat_interleave(out.shape[-1])


def _linear(weight: torch.Tensor, bias: torch.Tensor) -> nn.Linear:
    layer = nn.Linear(weight.shape[1], weight.shape[0], dtype=weight.dtype)
    with torch.no_grad():
        layer.weight.copy_(weight)
        layer.bias.copy_(bias)
    return layer


class _Args(nn.Module):
    """Feed the first module several positional inputs, the rest one output (Sequential takes one)."""

    def __init__(self, seq: nn.Sequential) -> None:
        super().__init__()
        self.net, self.post = seq[0], seq[1]

    def forward(self, *inputs: torch.Tensor):
        return self.post(self.net(*inputs))


def _inv_softplus(y: float) -> float:
    return math.log(math.expm1(y))


def widen_command_history(state_dict: dict, old_history: int, new_history: int) -> dict:
    """A policy's (actor's or critic's) weights for ``new_history`` commands of history, from
    weights trained with ``old_history <= new_history``: the first layer of every
    :class:`TrackingNet` gains zero columns for the older commands the old policy never saw, so the
    widened network computes exactly the old function until training changes it.

    Layout of the MLP's input (``TrackingNet.forward``): ``[state 13, commands oldest..newest
    (4 each), ref embedding, d_hat]``; the old commands are the newest, so the new columns go
    right after the 13 state entries."""
    if not 0 <= old_history <= new_history:
        raise ValueError(f"widen_command_history: need 0 <= old ({old_history}) <= new ({new_history})")
    extra = 4 * (new_history - old_history)
    out = dict(state_dict)
    for key, weight in state_dict.items():
        if key.endswith("mlp.0.weight") and extra:
            zeros = weight.new_zeros(weight.shape[0], extra)
            out[key] = torch.cat((weight[:, :STATE_DIM], zeros, weight[:, STATE_DIM:]), dim=1)
    return out
