"""The DATT controller as one self-contained C99 source and header (for an onboard build).

What the generated code computes, per control step, all in ``float`` (single precision):

* ``datt_observe``: the policy's observation from the measured state (position, velocity,
  attitude quaternion w-x-y-z body-to-world, world frame), the H future reference points and the
  scaled command history, exactly as :func:`datt.envs.observations.build_observation` (the
  rotation written as ``quat_rotate_inverse`` is);
* ``datt_network``: the actor's network on that observation (the conv encoder as convolutions,
  the error gain folded into the first weights, only the four location outputs), and
  ``datt_act`` = observe + network + the TanhNormal's deterministic squash
  ``center + half tanh(loc)`` + the clamp to the action bounds: (thrust m/s², ωx, ωy, ωz rad/s);
* ``datt_l1_step``: one step of the L1 estimator (:func:`datt.adapt.l1.l1_step`, with its
  command-latency queue and actuator model), giving d̂ (world, m/s²);
* ``datt_scale_command``: a sent command in the history's units ([-1, 1] over the bounds);
* ``datt_self_test``: runs ``datt_act`` and ``datt_l1_step`` on an embedded golden input and
  compares with the outputs torch computed for it (a boot-time check of the build).

No heap, no globals written, no libm (tanh is written with the code's own exp, so glibc's and
newlib's last-place differences cannot enter); the weights are ``static const float`` (flash on
a microcontroller). The code does not depend on FMA contraction: it is meant to be built with
``-ffp-contract=off`` so that builds with the same flags on different machines give the same
bits.

The fixed C lives in real files, ``datt/export/c/datt_policy.h`` and ``datt_policy.c``; this module
writes only what differs per policy above them: the sizes and layout as ``#define``s, the weights,
the action bounds, the L1 constants and the golden case.
"""

from __future__ import annotations

import math
import re
import zlib
from dataclasses import dataclass, field
from importlib import resources

import numpy as np
import torch
from torch import nn

from datt.errors import ConfigError
from datt.policies.networks import InferenceNet

# the C self-test's bound on |C - torch| for the golden action (m/s^2, rad/s) and d-hat (m/s^2):
# both compute in float32, so only the order of the sums differs
GOLDEN_TOL = 1e-4


@dataclass
class L1Spec:
    """The L1 estimator's constants (:class:`datt.adapt.L1Adaptation` after ``bind``)."""

    dt_s: float
    gravity_mps2: float
    a_s: float
    law_gain: float
    alpha: float
    k_thrust: float  # 1 without the actuator model
    latency_steps: int  # 0 without the actuator model
    predictor_uses_filtered: bool


@dataclass
class PolicySpec:
    """Everything the generator needs: the network's layers, the observation layout, bounds."""

    horizon: int
    body_frame: bool
    feedback: bool
    action_history: int
    action_low: list[float]
    action_high: list[float]
    convs: list[tuple[np.ndarray, np.ndarray]]  # (W [C_out, C_in, K], b [C_out]), ReLU after each
    proj: tuple[np.ndarray, np.ndarray]  # (W [E, C H], b [E]), ReLU
    mlp: list[tuple[np.ndarray, np.ndarray]]  # (W [out, in], b [out]), ReLU after each
    head: tuple[np.ndarray, np.ndarray]  # (W [4, hidden], b [4])
    use_d_hat: bool = True
    dt_s: float = 0.02  # the control step (env.dt_s)
    ref_stride: int = 1  # control steps between two of the H reference points (env.ref_spacing_s / dt_s)
    l1: L1Spec | None = None
    golden: dict = field(default_factory=dict)

    @property
    def state_dim(self) -> int:
        return 13 + 4 * self.action_history

    @property
    def macs(self) -> int:
        """Multiply-accumulates of one network evaluation as the generated C does it (the
        zero-padding taps of the 'same' convolutions skipped)."""
        h, total = self.horizon, 0
        for w, _ in self.convs:
            c_out, c_in, k = w.shape
            pad = k // 2
            taps = sum(min(k, h - t + pad) - max(0, pad - t) for t in range(h))
            total += c_out * c_in * taps
        return int(total + self.proj[0].size + sum(w.size for w, _ in self.mlp) + self.head[0].size)


def policy_spec(net: nn.Module, horizon: int, obs, low: torch.Tensor, high: torch.Tensor) -> PolicySpec:
    """The spec of a trained :class:`~datt.policies.networks.TrackingNet` (``obs``: its
    :class:`~datt.envs.params.ObsParams` layout; ``low``/``high``: the action bounds)."""
    if net.encoder.kind != "conv":
        raise ConfigError(
            f"export: policy.encoder={net.encoder.kind!r} is not supported by the C export; allowed: conv"
        )
    inf = InferenceNet(net, horizon, 4, dense_encoder=False)  # error gain folded into the weights

    def arr(t: torch.Tensor) -> np.ndarray:
        return t.detach().to(torch.float32).cpu().numpy().copy()

    convs = [(arr(m.weight), arr(m.bias)) for m in inf.encoder if isinstance(m, nn.Conv1d)]
    for m in inf.encoder:
        if isinstance(m, nn.Conv1d) and (
            m.stride[0] != 1 or m.dilation[0] != 1 or m.padding[0] != m.kernel_size[0] // 2
        ):
            raise ConfigError("export: only stride-1, 'same'-padded convolutions are supported")
    proj = inf.proj[0]
    mlp = [(arr(m.weight), arr(m.bias)) for m in inf.mlp if isinstance(m, nn.Linear)]
    return PolicySpec(
        horizon=int(horizon),
        body_frame=bool(obs.body_frame),
        feedback=bool(obs.feedback),
        action_history=int(obs.action_history),
        action_low=[float(x) for x in low],
        action_high=[float(x) for x in high],
        convs=convs,
        proj=(arr(proj.weight), arr(proj.bias)),
        mlp=mlp,
        head=(arr(inf.head.weight), arr(inf.head.bias)),
        use_d_hat=bool(net.use_d_hat),
    )


def l1_spec(l1, dt_s: float, gravity_mps2: float) -> L1Spec:
    """The constants of an :class:`~datt.adapt.L1Adaptation` (bound or not) at ``dt_s``."""
    e = math.exp(l1.a_s * dt_s)
    model = bool(l1.actuator_model)
    return L1Spec(
        dt_s=float(dt_s),
        gravity_mps2=float(gravity_mps2),
        a_s=float(l1.a_s),
        law_gain=-l1.a_s * e / (e - 1.0),
        alpha=math.exp(-dt_s / l1.cutoff_tau_s) if l1.cutoff_tau_s > 0 else 0.0,
        k_thrust=float(l1.k_thrust) if model else 1.0,
        latency_steps=int(l1.latency_steps) if model else 0,
        predictor_uses_filtered=bool(l1.predictor_uses_filtered),
    )


# -- C text ------------------------------------------------------------------------------------


def _f(x: float) -> str:
    """A float32 literal that reads back to the same float32 (9 significant digits)."""
    x = float(np.float32(x))
    if math.isinf(x) or math.isnan(x):
        raise ConfigError(f"export: non-finite value {x} in the policy")
    text = f"{x:.9g}"
    if "e" not in text and "." not in text:
        text += ".0"
    return text + "f"


def _array(name: str, values: np.ndarray | list[float], per_line: int = 8) -> str:
    if isinstance(values, torch.Tensor):
        values = values.detach().cpu().numpy()
    flat = np.asarray(values, dtype=np.float32).reshape(-1)
    if flat.size == 0:
        return f"static const float {name}[1] = {{0.0f}};\n"
    lines = [", ".join(_f(v) for v in flat[i : i + per_line]) for i in range(0, flat.size, per_line)]
    body = ",\n    ".join(lines)
    return f"static const float {name}[{flat.size}] = {{\n    {body}\n}};\n"


def policy_id(spec: PolicySpec) -> int:
    """CRC-32 of everything the generated step computes with (weights, bounds, layout, L1
    constants): the same policy and estimator give the same id, any change another."""
    crc = 0
    arrays = [w for layer in (*spec.convs, spec.proj, *spec.mlp, spec.head) for w in layer]
    for a in arrays:
        crc = zlib.crc32(np.ascontiguousarray(a, dtype=np.float32).tobytes(), crc)
    layout = (spec.horizon, spec.body_frame, spec.feedback, spec.action_history, spec.use_d_hat, spec.ref_stride)
    numbers = [*spec.action_low, *spec.action_high, spec.dt_s]
    if spec.l1 is not None:
        l1 = spec.l1
        numbers += [l1.dt_s, l1.gravity_mps2, l1.a_s, l1.law_gain, l1.alpha, l1.k_thrust, l1.latency_steps]
        layout += (l1.predictor_uses_filtered,)
    crc = zlib.crc32(np.array(numbers, dtype=np.float32).tobytes(), crc)
    return zlib.crc32(repr(layout).encode(), crc)


def _template(name: str, prefix: str) -> str:
    """A fixed C file of ``datt.export`` (``c/``), with ``datt_`` / ``DATT_`` renamed to ``prefix``."""
    text = (resources.files("datt.export") / "c" / name).read_text()
    if prefix != "datt":
        text = re.sub(r"\bdatt_", f"{prefix}_", text)
        text = re.sub(r"\bDATT_", f"{prefix.upper()}_", text)
    return text


def _defines(values: dict[str, object]) -> str:
    return "".join(f"#define {name} {value}\n" for name, value in values.items())


def generate(spec: PolicySpec, prefix: str = "datt") -> tuple[str, str]:
    """``(header, source)`` of the C99 controller for ``spec`` (functions prefixed ``prefix``): the
    fixed C of ``c/datt_policy.h`` and ``c/datt_policy.c`` under the sizes, #defines, weights and
    golden case of this policy."""
    if spec.l1 is None:
        raise ConfigError("export: the C export needs the L1 constants (spec.l1)")
    if not spec.golden:
        raise ConfigError("export: the C export needs a golden input/output pair (spec.golden)")
    if any(w.shape[2] != spec.convs[0][0].shape[2] for w, _ in spec.convs):
        raise ConfigError("export: every conv layer must have the same kernel size")
    return _header(spec, prefix), _source(spec, prefix)


def _header(spec: PolicySpec, prefix: str) -> str:
    up = prefix.upper()
    defines = {
        f"{up}_HORIZON": f"{spec.horizon}  /* future reference points, {up}_REF_STRIDE steps apart, the first now */",
        f"{up}_REF_STRIDE": spec.ref_stride,
        f"{up}_DT_S": f"{_f(spec.dt_s)}  /* the control step, s */",
        f"{up}_GRAVITY_MPS2": _f(spec.l1.gravity_mps2),
        f"{up}_POLICY_ID": f"0x{policy_id(spec):08x}u  /* CRC-32 of weights, bounds, constants */",
        f"{up}_HISTORY": f"{spec.action_history}  /* commands in the history (0: none) */",
        f"{up}_STATE_DIM": spec.state_dim,
        f"{up}_L1_LATENCY": f"{spec.l1.latency_steps}  /* commands in flight in the L1 model */",
    }
    return (
        "/* Generated by datt (datt.export.c_code): the DATT policy and its L1 estimator. Do not edit. */\n"
        f"#ifndef {up}_POLICY_H\n#define {up}_POLICY_H\n\n"
        + _defines(defines)
        + "\n"
        + _template("datt_policy.h", prefix)
        + "\n#endif\n"
    )


def _source(spec: PolicySpec, prefix: str) -> str:
    h = spec.horizon
    # the two scratch buffers hold a conv layer's [C][H] output or an MLP layer's output
    width = max([3 * h, *(w.shape[0] * h for w, _ in spec.convs), *(w.shape[0] for w, _ in spec.mlp)])
    layout = {
        "H": h,
        "KERNEL": spec.convs[0][0].shape[2],
        "WIDTH": f"{width}  /* floats in each scratch buffer */",
        "N_CONV": len(spec.convs),
        "CHANNELS": spec.convs[-1][0].shape[0],
        "EMBED": spec.proj[0].shape[0],
        "N_MLP": len(spec.mlp),
        "MLP_IN": spec.mlp[0][0].shape[1],
        "BODY_FRAME": int(spec.body_frame),
        "FEEDBACK": int(spec.feedback),
        "USE_D_HAT": int(spec.use_d_hat),
    }
    low = np.array(spec.action_low, dtype=np.float32)
    high = np.array(spec.action_high, dtype=np.float32)
    return "".join(
        [
            "/* Generated by datt (datt.export.c_code). Do not edit: regenerate with `datt export`. */\n",
            f'#include "{prefix}_policy.h"\n#include <stddef.h>\n#include <stdint.h>\n\n',
            _defines(layout),
            "\n",
            _weights(spec),
            _array("act_low", low),
            _array("act_high", high),
            _array("act_center", (high + low) / 2),
            _array("act_half", (high - low) / 2),
            "\n",
            _l1_defines(spec.l1),
            _golden(spec),
            "\n",
            _template("datt_policy.c", prefix),
        ]
    )


def _weights(spec: PolicySpec) -> str:
    """Every layer's weights and biases, and the layer tables the fixed C loops over."""
    parts = []
    for i, (w, b) in enumerate(spec.convs):
        parts += [_array(f"conv{i}_w", w), _array(f"conv{i}_b", b)]
    parts += [_array("proj_w", spec.proj[0]), _array("proj_b", spec.proj[1])]
    for i, (w, b) in enumerate(spec.mlp):
        parts += [_array(f"mlp{i}_w", w), _array(f"mlp{i}_b", b)]
    parts += [_array("head_w", spec.head[0]), _array("head_b", spec.head[1])]
    convs, mlps = range(len(spec.convs)), range(len(spec.mlp))
    parts += [
        _table("conv_w", [f"conv{i}_w" for i in convs]),
        _table("conv_b", [f"conv{i}_b" for i in convs]),
        _table("conv_out", [w.shape[0] for w, _ in spec.convs], "int"),
        _table("mlp_w", [f"mlp{i}_w" for i in mlps]),
        _table("mlp_b", [f"mlp{i}_b" for i in mlps]),
        _table("mlp_out", [w.shape[0] for w, _ in spec.mlp], "int"),
    ]
    return "".join(parts)


def _table(name: str, items: list, kind: str = "float *const") -> str:
    """A layer table: the weight arrays of every layer, or their sizes."""
    return f"static const {kind} {name}[{len(items)}] = {{{', '.join(str(i) for i in items)}}};\n"


def _l1_defines(l1: L1Spec) -> str:
    return (
        f"/* L1 constants: dt {l1.dt_s} s, a_s {l1.a_s} 1/s, filter alpha {l1.alpha:.9g}, actuator k {l1.k_thrust} */\n"
        + _defines(
            {
                "L1_DT": _f(l1.dt_s),
                "L1_A_S": _f(l1.a_s),
                "L1_LAW_GAIN": _f(l1.law_gain),
                "L1_ALPHA": _f(l1.alpha),
                "L1_K_THRUST": _f(l1.k_thrust),
                "L1_GRAVITY": _f(l1.gravity_mps2),
                "L1_PREDICTOR_USES_FILTERED": int(l1.predictor_uses_filtered),
            }
        )
    )


def _golden(spec: PolicySpec) -> str:
    """The golden case the C self-test replays: one action and an L1 sequence, with torch's results."""
    g = spec.golden
    names = ["pos", "vel", "quat", "ref", "d_hat", "cmd_hist", "action", "l1_cmd", "l1_vel", "l1_quat", "l1_d_hat"]
    return "".join(_array(f"golden_{name}", g[name]) for name in names) + (
        "/* tolerances: the action (m/s^2, rad/s) and d-hat (m/s^2) against torch's float32 results */\n"
        + _defines({"ACTION_TOL": _f(GOLDEN_TOL), "D_HAT_TOL": _f(GOLDEN_TOL), "GOLDEN_L1_STEPS": len(g["l1_cmd"])})
    )
