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
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from datt.errors import ConfigError
from datt.policies.networks import InferenceNet


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
        numbers += [l1.dt_s, l1.gravity_mps2, l1.a_s, l1.alpha, l1.k_thrust, l1.latency_steps]
        layout += (l1.predictor_uses_filtered,)
    crc = zlib.crc32(np.array(numbers, dtype=np.float32).tobytes(), crc)
    return zlib.crc32(repr(layout).encode(), crc)


def generate(spec: PolicySpec, prefix: str = "datt") -> tuple[str, str]:
    """``(header, source)`` of the C99 controller for ``spec`` (functions prefixed ``prefix``)."""
    if spec.l1 is None:
        raise ConfigError("export: the C export needs the L1 constants (spec.l1)")
    if not spec.golden:
        raise ConfigError("export: the C export needs a golden input/output pair (spec.golden)")
    p, up = prefix, prefix.upper()
    h, k = spec.horizon, spec.action_history
    c_in = [3] + [w.shape[0] for w, _ in spec.convs[:-1]]
    channels = spec.convs[-1][0].shape[0]
    embed = spec.proj[0].shape[0]
    mlp_in = spec.mlp[0][0].shape[1]
    # the two scratch buffers hold a conv layer's [C][H] output or an MLP layer's output
    width = max([3 * h, *(w.shape[0] * h for w, _ in spec.convs), *(w.shape[0] for w, _ in spec.mlp)])
    lat = spec.l1.latency_steps
    kernel = spec.convs[0][0].shape[2]
    if any(w.shape[2] != kernel for w, _ in spec.convs):
        raise ConfigError("export: every conv layer must have the same kernel size")
    header = f"""/* Generated by datt (datt.export.c_code): the DATT policy and its L1 estimator. Do not edit. */
#ifndef {up}_POLICY_H
#define {up}_POLICY_H

#define {up}_HORIZON {h}            /* future reference points, {up}_REF_STRIDE steps apart, the first now */
#define {up}_REF_STRIDE {spec.ref_stride}
#define {up}_DT_S {_f(spec.dt_s)}         /* the control step, s */
#define {up}_GRAVITY_MPS2 {_f(spec.l1.gravity_mps2)}
#define {up}_POLICY_ID 0x{policy_id(spec):08x}u /* CRC-32 of weights, bounds, constants (c_code.policy_id) */
#define {up}_HISTORY {k}            /* commands in the history (0: none) */
#define {up}_STATE_DIM {spec.state_dim}
#define {up}_L1_LATENCY {lat}        /* thrust commands in flight in the L1 actuator model */

typedef struct {{
    float v_hat[3];        /* predicted velocity, world, m/s */
    float sigma_hat[3];    /* unfiltered estimate, m/s^2 */
    float d_hat[3];        /* filtered disturbance estimate, world, m/s^2 (the policy's input) */
    float prev_vel[3];
    float prev_quat[4];
    float thrust_est;      /* modelled actuator thrust, m/s^2 */
    float thrust_queue[{lat} + 1]; /* thrust commands in flight, oldest first ({lat} used) */
}} {p}_l1_state;

/* Observation (state and feedforward) from the measured state and the reference window.
   pos, vel: world m, m/s; quat: w, x, y, z body-to-world; ref: {h} future points (world, m), x y z
   each, [{h} * 3]; state: [{up}_STATE_DIM]; feedforward: [{h} * 3];
   cmd_hist: the last {k} commands scaled by {p}_scale_command, oldest first (may be NULL if 0). */
void {p}_observe(const float pos[3], const float vel[3], const float quat[4], const float *ref,
                 const float *cmd_hist, float *state, float *feedforward);
/* The network's four action locations (before the squash). */
void {p}_network(const float *state, const float *feedforward, const float d_hat[3], float loc[4]);
/* The action (thrust m/s^2, body rates rad/s) for one control step. */
void {p}_act(const float pos[3], const float vel[3], const float quat[4], const float *ref,
             const float d_hat[3], const float *cmd_hist, float action[4]);
/* A sent command in the history's units: (cmd - center) / half over the action bounds. */
void {p}_scale_command(const float cmd[4], float scaled[4]);
/* L1: reset to a measured state, then one step per control step with the command sent at the
   start of the step and the state measured after it. */
void {p}_l1_reset({p}_l1_state *s, const float vel[3], const float quat[4]);
void {p}_l1_step({p}_l1_state *s, const float cmd[4], const float vel[3], const float quat[4]);
/* Runs the embedded golden case; returns 0 when the action and d-hat agree with torch's within
   the tolerances below, else 1. max_err (may be NULL): the largest difference seen. */
int {p}_self_test(float *max_err);

#endif
"""
    parts = [
        "/* Generated by datt (datt.export.c_code). Do not edit: regenerate with `datt export`. */\n",
        f'#include "{p}_policy.h"\n#include <stddef.h>\n#include <stdint.h>\n\n',
        f"#define H {h}\n#define WIDTH {width} /* floats in each scratch buffer */\n\n",
    ]
    for i, (w, b) in enumerate(spec.convs):
        parts += [_array(f"conv{i}_w", w), _array(f"conv{i}_b", b)]
    parts += [_array("proj_w", spec.proj[0]), _array("proj_b", spec.proj[1])]
    for i, (w, b) in enumerate(spec.mlp):
        parts += [_array(f"mlp{i}_w", w), _array(f"mlp{i}_b", b)]
    parts += [_array("head_w", spec.head[0]), _array("head_b", spec.head[1])]
    low = np.array(spec.action_low, dtype=np.float32)
    high = np.array(spec.action_high, dtype=np.float32)
    center, half = (high + low) / 2, (high - low) / 2
    parts += [
        _array("act_low", low),
        _array("act_high", high),
        _array("act_center", center),
        _array("act_half", half),
        "\n",
        _helpers(kernel),
        _observe_c(p, spec),
        _network_c(p, spec, c_in, channels, embed, mlp_in),
        _act_c(p, spec),
        _l1_c(p, spec.l1),
        _self_test_c(p, spec),
    ]
    return header, "".join(parts)


def _helpers(k: int) -> str:
    taps = "\n".join(f"                    acc += wr[{j}] * xr[{j - k // 2}];" for j in range(k))
    conv = f"""/* 'same'-padded stride-1 conv1d + ReLU, kernel {k}: x [c_in][H] -> y [c_out][H], w [c_out][c_in][{k}];
   taps outside [0, H) are skipped (zero padding), the rest summed in (ci, j) order. Positions
   with every tap inside run the taps unrolled. */
static void conv1d_relu(const float *w, const float *b, const float *x, float *y, int c_out, int c_in) {{
    int o, t, ci, j;
    for (o = 0; o < c_out; o++) {{
        for (t = 0; t < H; t++) {{
            int lo = t < {k // 2} ? {k // 2} - t : 0;
            int hi = t + {k - k // 2} > H ? H - t + {k // 2} : {k};
            float acc = b[o];
            for (ci = 0; ci < c_in; ci++) {{
                const float *wr = w + (o * c_in + ci) * {k};
                const float *xr = x + ci * H + t; /* the input under the centre tap */
                if (lo == 0 && hi == {k}) {{
{taps}
                }} else {{
                    for (j = lo; j < hi; j++) {{
                        acc += wr[j] * xr[j - {k // 2}];
                    }}
                }}
            }}
            y[o * H + t] = relu(acc);
        }}
    }}
}}

"""
    return (
        """static float relu(float x) { return x > 0.0f ? x : 0.0f; }

/* exp(x) for x in [0, 88] (Cephes expf: x = n ln2 + r, |r| <= ln2 / 2, a degree-6 polynomial
   for exp(r), 2^n through the exponent bits): the code's own, so that every platform computes
   the same bits (libm's expf differs between glibc and newlib in the last place). */
static float exp_pos(float x) {
    union { float f; uint32_t i; } scale;
    float r, z, y;
    int32_t n;
    if (x > 88.0f) x = 88.0f;
    n = (int32_t)(x * 1.44269504088896341f + 0.5f);
    r = x - (float)n * 0.693359375f;
    r = r - (float)n * -2.12194440e-4f;
    z = r * r;
    y = ((((1.9875691500e-4f * r + 1.3981999507e-3f) * r + 8.3334519073e-3f) * r + 4.1665795894e-2f) * r
         + 1.6666665459e-1f) * r + 5.0000001201e-1f;
    y = y * z + r + 1.0f;
    scale.i = (uint32_t)(n + 127) << 23;
    return y * scale.f;
}

static float tanh_f(float x) {
    /* 1 - 2 / (exp(2|x|) + 1), odd */
    float a = x < 0.0f ? -x : x;
    float t = 1.0f - 2.0f / (exp_pos(2.0f * a) + 1.0f);
    return x < 0.0f ? -t : t;
}

/* y = W x + b (W row-major [n_out][n_in]), then ReLU if use_relu. One accumulator, summed in
   index order (the order fixes the bits); unrolled by 4 for fewer loop instructions. */
static void linear(const float *w, const float *b, const float *x, float *y, int n_out, int n_in, int use_relu) {
    int o, i;
    for (o = 0; o < n_out; o++) {
        const float *row = w + o * n_in;
        float acc = b[o];
        for (i = 0; i + 4 <= n_in; i += 4) {
            acc += row[i] * x[i];
            acc += row[i + 1] * x[i + 1];
            acc += row[i + 2] * x[i + 2];
            acc += row[i + 3] * x[i + 3];
        }
        for (; i < n_in; i++) {
            acc += row[i] * x[i];
        }
        y[o] = use_relu ? relu(acc) : acc;
    }
}

"""
        + conv
        + """/* world -> body: R(q)^T v = v - w t + u x t, t = 2 u x v (as datt.sim.frames.quat_rotate_inverse) */
static void rotate_inverse(const float q[4], const float v[3], float out[3]) {
    float t[3], c[3];
    t[0] = 2.0f * (q[2] * v[2] - q[3] * v[1]);
    t[1] = 2.0f * (q[3] * v[0] - q[1] * v[2]);
    t[2] = 2.0f * (q[1] * v[1] - q[2] * v[0]);
    c[0] = q[2] * t[2] - q[3] * t[1];
    c[1] = q[3] * t[0] - q[1] * t[2];
    c[2] = q[1] * t[1] - q[2] * t[0];
    out[0] = v[0] - q[0] * t[0] + c[0];
    out[1] = v[1] - q[0] * t[1] + c[1];
    out[2] = v[2] - q[0] * t[2] + c[2];
}

"""
    )


def _observe_c(p: str, spec: PolicySpec) -> str:
    k = spec.action_history
    rotate = "rotate_inverse(quat, v, out)" if spec.body_frame else "out[0] = v[0]; out[1] = v[1]; out[2] = v[2]"
    lines = [
        f"void {p}_observe(const float pos[3], const float vel[3], const float quat[4], const float *ref,",
        "                 const float *cmd_hist, float *state, float *feedforward) {",
        "    int i, j;",
        "    float v[3], out[3];",
        "    /* position and velocity */",
        "    for (j = 0; j < 3; j++) v[j] = pos[j];",
        f"    {rotate};",
        f"    for (j = 0; j < 3; j++) state[j] = {'out[j]' if spec.feedback else '0.0f'};",
        "    for (j = 0; j < 3; j++) v[j] = vel[j];",
        f"    {rotate};",
        "    for (j = 0; j < 3; j++) state[3 + j] = out[j];",
        "    for (j = 0; j < 4; j++) state[6 + j] = quat[j];",
        "    /* feedback error (i = 0) and the feedforward points */",
        "    for (i = 0; i < H; i++) {",
        "        for (j = 0; j < 3; j++) v[j] = pos[j] - ref[3 * i + j];",
        f"        {rotate};",
        "        if (i == 0) {",
        "            for (j = 0; j < 3; j++) state[10 + j] = out[j];",
        "        }",
        "        for (j = 0; j < 3; j++) feedforward[3 * i + j] = "
        + ("out[j];" if spec.body_frame else "ref[3 * i + j]; /* raw future positions (no body frame) */"),
        "    }",
    ]
    if k:
        lines.append(f"    for (j = 0; j < {4 * k}; j++) state[13 + j] = cmd_hist[j];")
    else:
        lines.append("    (void)cmd_hist;")
    lines += ["}", "", ""]
    return "\n".join(lines)


def _network_c(p: str, spec: PolicySpec, c_in: list[int], channels: int, embed: int, mlp_in: int) -> str:
    s = spec.state_dim
    lines = [
        f"void {p}_network(const float *state, const float *feedforward, const float d_hat[3], float loc[4]) {{",
        "    float a[WIDTH], b[WIDTH];",
        f"    float x[{mlp_in}];",
        "    int i, j;",
        "    /* channel-major input of the encoder: a[c * H + t] = feedforward[t][c] */",
        "    for (i = 0; i < H; i++) for (j = 0; j < 3; j++) a[j * H + i] = feedforward[3 * i + j];",
    ]
    src, dst = "a", "b"
    for i, (w, _) in enumerate(spec.convs):
        lines.append(f"    conv1d_relu(conv{i}_w, conv{i}_b, {src}, {dst}, {w.shape[0]}, {c_in[i]});")
        src, dst = dst, src
    lines += [
        f"    for (j = 0; j < {s}; j++) x[j] = state[j];",
        f"    linear(proj_w, proj_b, {src}, x + {s}, {embed}, {channels} * H, 1);",
    ]
    if spec.use_d_hat:
        lines.append(f"    for (j = 0; j < 3; j++) x[{s + embed} + j] = d_hat[j];")
    else:
        lines.append("    (void)d_hat;")
    cur, n_in = "x", mlp_in
    bufs = ["a", "b"]
    for i, (w, _) in enumerate(spec.mlp):
        out = bufs[i % 2]
        lines.append(f"    linear(mlp{i}_w, mlp{i}_b, {cur}, {out}, {w.shape[0]}, {n_in}, 1);")
        cur, n_in = out, w.shape[0]
    lines += [f"    linear(head_w, head_b, {cur}, loc, 4, {n_in}, 0);", "}", "", ""]
    return "\n".join(lines)


def _act_c(p: str, spec: PolicySpec) -> str:
    return f"""void {p}_act(const float pos[3], const float vel[3], const float quat[4], const float *ref,
             const float d_hat[3], const float *cmd_hist, float action[4]) {{
    float state[{spec.state_dim}], feedforward[3 * H], loc[4];
    int j;
    {p}_observe(pos, vel, quat, ref, cmd_hist, state, feedforward);
    {p}_network(state, feedforward, d_hat, loc);
    for (j = 0; j < 4; j++) {{
        float u = act_center[j] + act_half[j] * tanh_f(loc[j]);
        action[j] = u < act_low[j] ? act_low[j] : (u > act_high[j] ? act_high[j] : u);
    }}
}}

void {p}_scale_command(const float cmd[4], float scaled[4]) {{
    int j;
    for (j = 0; j < 4; j++) scaled[j] = (cmd[j] - act_center[j]) / act_half[j];
}}

"""


def _l1_c(p: str, l1: L1Spec) -> str:
    lat = l1.latency_steps
    fb = "s->d_hat" if l1.predictor_uses_filtered else "s->sigma_hat"
    return f"""/* L1 constants: dt {l1.dt_s} s, a_s {l1.a_s} 1/s, filter alpha {l1.alpha:.9g},
   actuator k {l1.k_thrust} */
#define L1_DT {_f(l1.dt_s)}
#define L1_A_S {_f(l1.a_s)}
#define L1_LAW_GAIN {_f(l1.law_gain)}
#define L1_ALPHA {_f(l1.alpha)}
#define L1_K_THRUST {_f(l1.k_thrust)}
#define L1_GRAVITY {_f(l1.gravity_mps2)}

void {p}_l1_reset({p}_l1_state *s, const float vel[3], const float quat[4]) {{
    int j;
    for (j = 0; j < 3; j++) {{
        s->v_hat[j] = vel[j];
        s->sigma_hat[j] = 0.0f;
        s->d_hat[j] = 0.0f;
        s->prev_vel[j] = vel[j];
    }}
    for (j = 0; j < 4; j++) s->prev_quat[j] = quat[j];
    s->thrust_est = L1_GRAVITY;
    for (j = 0; j < {lat} + 1; j++) s->thrust_queue[j] = L1_GRAVITY;
}}

static float lerp_f(float a, float b, float w) {{
    /* as torch.lerp: a + w (b - a) for w < 0.5, else b - (b - a)(1 - w) */
    return w < 0.5f ? a + w * (b - a) : b - (b - a) * (1.0f - w);
}}

void {p}_l1_step({p}_l1_state *s, const float cmd[4], const float vel[3], const float quat[4]) {{
    const float *q = s->prev_quat;
    float acting, thrust, body_z[3], f[3], fb[3];
    int j;
    /* the oldest thrust command in flight acts now; this step's command joins the queue */
    acting = {"s->thrust_queue[0]" if lat else "cmd[0]"};
    for (j = 0; j + 1 < {lat}; j++) s->thrust_queue[j] = s->thrust_queue[j + 1];
    {f"s->thrust_queue[{lat - 1}] = cmd[0];" if lat else "(void)s->thrust_queue;"}
    thrust = lerp_f(s->thrust_est, acting, L1_K_THRUST);
    body_z[0] = 2.0f * (q[1] * q[3] + q[0] * q[2]);
    body_z[1] = 2.0f * (q[2] * q[3] - q[0] * q[1]);
    body_z[2] = 1.0f - 2.0f * (q[1] * q[1] + q[2] * q[2]);
    for (j = 0; j < 3; j++) {{
        f[j] = body_z[j] * thrust + (j == 2 ? -L1_GRAVITY : 0.0f);
        fb[j] = {fb}[j];
    }}
    for (j = 0; j < 3; j++) {{
        float v_hat = s->v_hat[j] * (1.0f + L1_DT * L1_A_S) + (-L1_DT * L1_A_S) * s->prev_vel[j]
                      + L1_DT * (f[j] + fb[j]);
        float sigma = L1_LAW_GAIN * (v_hat - vel[j]);
        s->v_hat[j] = v_hat;
        s->sigma_hat[j] = sigma;
        s->d_hat[j] = lerp_f(sigma, s->d_hat[j], L1_ALPHA);
        s->prev_vel[j] = vel[j];
    }}
    for (j = 0; j < 4; j++) s->prev_quat[j] = quat[j];
    s->thrust_est = thrust;
}}

"""


def _self_test_c(p: str, spec: PolicySpec) -> str:
    g = spec.golden
    k = spec.action_history
    parts = [
        _array("golden_pos", g["pos"]),
        _array("golden_vel", g["vel"]),
        _array("golden_quat", g["quat"]),
        _array("golden_ref", g["ref"]),
        _array("golden_d_hat", g["d_hat"]),
        _array("golden_cmd_hist", g["cmd_hist"]),
        _array("golden_action", g["action"]),
        _array("golden_l1_cmd", g["l1_cmd"]),
        _array("golden_l1_vel", g["l1_vel"]),
        _array("golden_l1_quat", g["l1_quat"]),
        _array("golden_l1_d_hat", g["l1_d_hat"]),
    ]
    steps = int(np.asarray(g["l1_cmd"].detach() if isinstance(g["l1_cmd"], torch.Tensor) else g["l1_cmd"]).size) // 4
    parts.append(f"""
/* tolerances: the action (m/s^2, rad/s) and d-hat (m/s^2) against torch's float32 results */
#define ACTION_TOL {_f(g.get("action_tol", 1e-4))}
#define D_HAT_TOL {_f(g.get("d_hat_tol", 1e-4))}

int {p}_self_test(float *max_err) {{
    float action[4], worst = 0.0f;
    {p}_l1_state s;
    int j, i, fail = 0;
    {p}_act(golden_pos, golden_vel, golden_quat, golden_ref, golden_d_hat,
            {"golden_cmd_hist" if k else "NULL"}, action);
    for (j = 0; j < 4; j++) {{
        float e = action[j] - golden_action[j];
        e = e < 0.0f ? -e : e;
        if (!(e <= ACTION_TOL)) fail = 1;
        if (e > worst) worst = e;
    }}
    {p}_l1_reset(&s, golden_l1_vel, golden_l1_quat);
    for (i = 1; i < {steps}; i++) {{
        {p}_l1_step(&s, golden_l1_cmd + 4 * i, golden_l1_vel + 3 * i, golden_l1_quat + 4 * i);
    }}
    for (j = 0; j < 3; j++) {{
        float e = s.d_hat[j] - golden_l1_d_hat[j];
        e = e < 0.0f ? -e : e;
        if (!(e <= D_HAT_TOL)) fail = 1;
        if (e > worst) worst = e;
    }}
    if (max_err != NULL) *max_err = worst;
    return fail;
}}
""")
    return "".join(parts)
