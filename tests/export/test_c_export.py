"""The generated C controller (datt.export.c_code), built with the system compiler and called
through ctypes, against the project's torch policy and L1 estimator."""

import ctypes
import shutil
import subprocess
from dataclasses import replace

import numpy as np
import pytest
import torch

from datt.configuration import compose, instantiate_option
from datt.control.datt import DattController
from datt.export import export_spec, record_rollout, reference_action, replay_l1, write_c
from datt.export.c_code import GOLDEN_TOL
from datt.export.harness import COMMON_FLAGS

GCC = shutil.which("gcc")
pytestmark = pytest.mark.skipif(GCC is None, reason="no gcc on this machine: the C export cannot be built here")
FLAGS = [*COMMON_FLAGS, "-Werror"]
F = ctypes.POINTER(ctypes.c_float)


def build(src_dir, name="libdatt.so"):
    lib = src_dir / name
    subprocess.run([GCC, *FLAGS, "-shared", "-fPIC", "-o", str(lib), str(src_dir / "datt_policy.c")], check=True)
    return ctypes.CDLL(str(lib))


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    cfg = compose("export", [])
    spec, controller, merged = export_spec(cfg)
    out = tmp_path_factory.mktemp("c")
    write_c(spec, out)
    return spec, controller, merged, out, build(out)


def c_actions(lib, spec, obs: dict) -> np.ndarray:
    n = len(obs["pos_m"])
    arrays = {k: np.ascontiguousarray(v.detach().numpy(), dtype=np.float32) for k, v in obs.items()}
    out = np.zeros((n, 4), np.float32)
    for i in range(n):
        lib.datt_act(
            *(arrays[k][i].ctypes.data_as(F) for k in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_hist")),
            out[i].ctypes.data_as(F),
        )
    return out


def random_observations(n: int, horizon: int, history: int, seed: int = 0) -> dict:
    """States within the training ranges: anywhere in the 3 m safety box, up to 3 m/s, any
    attitude, references up to 1 m away, |d| up to 3.5 m/s², commands across their bounds."""
    g = torch.Generator().manual_seed(seed)

    def u(*shape, scale=1.0):
        return (2 * torch.rand(*shape, generator=g) - 1) * scale

    pos = u(n, 3, scale=3.0)
    quat = torch.randn(n, 4, generator=g)
    return {
        "pos_m": pos,
        "vel_mps": u(n, 3, scale=3.0),
        "quat": quat / quat.norm(dim=-1, keepdim=True),
        "ref_m": pos.unsqueeze(1) + u(n, horizon, 3, scale=1.0),
        "d_hat": u(n, 3, scale=3.5),
        "cmd_hist": u(n, 4 * history),
    }


def recorded_observations(merged, controller, drones: int, steps: int) -> dict:
    rec = record_rollout(merged, DattController(controller.actor, frozen=False), num_envs=drones, steps=steps)
    flat = {k: getattr(rec, k).flatten(0, 1) for k in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_hist")}
    return flat


def test_c_action_matches_torch_on_ten_thousand_observations(exported):
    """Recorded flight states and random states across the training ranges: within 8 float32
    ulps of the largest output of torch (float32 itself rounds at ~4e-6 on a 40 m/s² thrust), and
    as close to the exact (float64) result as torch's float32 is."""
    import copy

    spec, controller, merged, _, lib = exported
    obs_params = merged.env.obs
    rand = random_observations(5000, spec.horizon, spec.action_history)
    flown = recorded_observations(merged, controller, drones=10, steps=500)  # Brownian, L1, zigzags
    assert len(flown["pos_m"]) == 5000
    got = {name: c_actions(lib, spec, obs) for name, obs in (("random", rand), ("recorded", flown))}
    expect = {
        name: reference_action(controller, obs_params, obs).numpy()
        for name, obs in (("random", rand), ("recorded", flown))
    }
    for name in ("recorded", "random"):  # within 8 float32 ulps of the largest output (the last layer's scale)
        assert np.abs(got[name] - expect[name]).max() <= 8 * np.spacing(np.abs(expect[name]).max()), name
    exact_ctrl = copy.deepcopy(controller)
    exact_ctrl.net, exact_ctrl.center, exact_ctrl.half = (
        x.double() for x in (exact_ctrl.net, exact_ctrl.center, exact_ctrl.half)
    )
    for name, obs in (("random", rand), ("recorded", flown)):
        exact = reference_action(exact_ctrl, obs_params, {k: v.double() for k, v in obs.items()}).numpy()
        c_err, torch_err = np.abs(got[name] - exact).max(), np.abs(expect[name] - exact).max()
        assert c_err <= 1.25 * torch_err, (name, c_err, torch_err)


class L1State(ctypes.Structure):
    _fields_ = [
        ("v_hat", ctypes.c_float * 3),
        ("sigma_hat", ctypes.c_float * 3),
        ("d_hat", ctypes.c_float * 3),
        ("prev_vel", ctypes.c_float * 3),
        ("prev_quat", ctypes.c_float * 4),
        ("thrust_est", ctypes.c_float),
        ("thrust_queue", ctypes.c_float * 2),  # latency 1 + 1
    ]


def test_c_l1_follows_the_project_l1_over_a_3000_step_replay(exported):
    spec, controller, merged, _, lib = exported
    assert spec.l1.latency_steps == 1
    long = merged.copy()
    long.env.episode_steps = 3000
    rec = record_rollout(long, DattController(controller.actor, frozen=False), num_envs=1, steps=3000)
    cmd, vel, quat = rec.action[:, 0], rec.vel_after[:, 0], rec.quat_after[:, 0]
    l1 = instantiate_option(merged, "adaptation")
    expect = replay_l1(l1, spec.l1.dt_s, spec.l1.gravity_mps2, cmd, vel, quat).numpy()
    assert np.abs(expect).max() > 0.5  # the Brownian disturbance is there to be estimated
    c = [np.ascontiguousarray(x.numpy(), dtype=np.float32) for x in (cmd, vel, quat)]
    state = L1State()
    lib.datt_l1_reset(ctypes.byref(state), c[1][0].ctypes.data_as(F), c[2][0].ctypes.data_as(F))
    worst = 0.0
    for k in range(1, 3000):
        lib.datt_l1_step(ctypes.byref(state), *(x[k].ctypes.data_as(F) for x in c))
        worst = max(worst, float(np.abs(np.array(state.d_hat) - expect[k]).max()))
    assert worst <= 1e-4


def test_self_test_passes_and_fails_on_a_changed_weight(exported, tmp_path):
    spec, _, _, out, lib = exported
    err = ctypes.c_float()
    assert lib.datt_self_test(ctypes.byref(err)) == 0 and err.value <= 1e-5
    bad = with_first_value_moved(out, tmp_path / "bad", "head_b", 0.05)
    assert build(bad, "libbad.so").datt_self_test(ctypes.byref(err)) == 1 and err.value > 1e-3


def with_first_value_moved(out, to, array: str, shift: float):
    """A copy of the export in ``out`` written to ``to`` with the first value of the C array
    ``array`` moved by ``shift``; returns ``to``."""
    source = (out / "datt_policy.c").read_text()
    start = source.index("{", source.index(f"static const float {array}[")) + 1
    start += len(source[start:]) - len(source[start:].lstrip())
    first = source[start : source.index(",", start)]
    to.mkdir()
    (to / "datt_policy.h").write_text((out / "datt_policy.h").read_text())
    literal = f"{float(first.rstrip('f')) + shift:.9g}f"
    (to / "datt_policy.c").write_text(source[:start] + literal + source[start + len(first) :])
    return to


@pytest.mark.parametrize("array", ["golden_action", "golden_l1_d_hat"])
def test_the_self_test_holds_the_c_to_its_tolerance(exported, tmp_path, array):
    """The self-test's bound on |C - torch| is GOLDEN_TOL for the action and for d-hat: a golden
    value moved by three times the bound fails it, by a third of it still passes."""
    _, _, _, out, _ = exported
    results = []
    for name, shift in (("far", 3 * GOLDEN_TOL), ("near", GOLDEN_TOL / 3)):
        moved = with_first_value_moved(out, tmp_path / name, array, shift)
        results.append(build(moved, f"lib{name}.so").datt_self_test(None))
    assert results == [1, 0]


def small_layout(spec, channels: int, hidden: list[int], seed: int = 0):
    """``spec`` with random weights of another width: ``channels`` conv channels (one layer) and
    MLP layers of ``hidden`` units."""
    rng = np.random.default_rng(seed)

    def layer(n_out, n_in, *kernel):
        return rng.standard_normal((n_out, n_in, *kernel)).astype(np.float32) * 0.3, np.zeros(n_out, np.float32)

    kernel, h, embed = spec.convs[0][0].shape[2], spec.horizon, spec.proj[0].shape[0]
    sizes = [spec.mlp[0][0].shape[1], *hidden]
    mlp = [layer(n_out, n_in) for n_in, n_out in zip(sizes, sizes[1:])]
    convs, proj = [layer(channels, 3, kernel)], layer(embed, channels * h)
    return replace(spec, convs=convs, proj=proj, mlp=mlp, head=layer(4, hidden[-1]))


# the widest buffer the step fills: a conv output [16][H] (shipped), the reference window [3][H],
# the last MLP layer's output
LAYOUTS = {"shipped": None, "input_widest": (2, [8, 8, 8]), "last_mlp_widest": (2, [8, 8, 200])}


@pytest.fixture(scope="module")
def sanitizer_flags(tmp_path_factory) -> tuple[str, ...]:
    """AddressSanitizer and UBSan, aborting at the first finding; skips where they cannot link."""
    flags = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer")
    probe = tmp_path_factory.mktemp("probe") / "probe.c"
    probe.write_text("int main(void) { return 0; }\n")
    if subprocess.run([GCC, *flags, "-o", str(probe.with_suffix("")), str(probe)], capture_output=True).returncode:
        pytest.skip("this compiler cannot link AddressSanitizer/UBSan programs")
    return flags


@pytest.mark.parametrize("layout", LAYOUTS)
def test_the_generated_step_stays_inside_its_buffers(exported, tmp_path, layout, sanitizer_flags):
    """Built with AddressSanitizer and UBSan, the host harness runs the step on 300 random
    states and the L1 over a flight without a single out-of-bounds access: the scratch buffers
    hold the widest layer whichever layer that is."""
    from datt.export.harness import build_host, vectors_h, write_harness

    spec = exported[0] if LAYOUTS[layout] is None else small_layout(exported[0], *LAYOUTS[layout])
    widths = {
        "input_widest": 3 * spec.horizon,
        "shipped": spec.convs[0][0].shape[0] * spec.horizon,
        "last_mlp_widest": spec.mlp[-1][0].shape[0],
    }
    assert max(widths, key=widths.get) == layout
    if layout == "last_mlp_widest":  # and wider than the MLP's input: only out-features size the buffer
        assert spec.mlp[0][0].shape[1] < widths[layout]
    write_c(spec, tmp_path)
    obs = random_observations(300, spec.horizon, spec.action_history, seed=2)
    g = spec.golden
    write_harness(tmp_path, vectors_h(obs, g["l1_cmd"], g["l1_vel"], g["l1_quat"]))
    exe = build_host(tmp_path, cc=GCC, opt="-O1", extra_flags=sanitizer_flags)
    run = subprocess.run([str(exe)], capture_output=True, text=True)
    assert run.returncode == 0 and "Sanitizer" not in run.stderr and "runtime error" not in run.stderr, run.stderr
    assert len(run.stdout.splitlines()) == 300 + len(g["l1_cmd"]) - 1 + 1


def test_generated_code_needs_no_heap_and_no_libm(exported, tmp_path):
    _, _, _, out, _ = exported
    obj = tmp_path / "p.o"
    subprocess.run([GCC, *FLAGS, "-c", "-o", str(obj), str(out / "datt_policy.c")], check=True)
    nm = shutil.which("nm")
    if nm is None:
        pytest.skip("no nm on this machine")
    undefined = subprocess.run([nm, "-u", str(obj)], check=True, capture_output=True, text=True).stdout.split()
    assert [s for s in undefined if s != "U"] == []  # not even expf: the code has its own exp
    source = (out / "datt_policy.c").read_text()
    assert "malloc" not in source and "double" not in source


def test_torchscript_and_onnx_exports_compute_the_same_action(exported, tmp_path):
    """Random states (large activations): agreement within float32's rounding at ~40 m/s²."""
    from datt.tasks.export import run_export

    spec, controller, merged, _, _ = exported
    obs = random_observations(256, spec.horizon, spec.action_history, seed=1)
    expect = reference_action(controller, merged.env.obs, obs).numpy()
    args = [obs[k] for k in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_hist")]
    (ts,) = run_export(compose("export", ["format=torchscript", f"out_dir={tmp_path}"]))
    with torch.no_grad():
        got = torch.jit.load(str(ts))(*args).numpy()
    assert np.abs(got - expect).max() <= 2e-5
    ort = pytest.importorskip("onnxruntime")
    (path,) = run_export(compose("export", ["format=onnx", f"out_dir={tmp_path}"]))
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    names = [i.name for i in session.get_inputs()]
    (got,) = session.run(None, {n: a.numpy() for n, a in zip(names, args)})
    assert np.abs(got - expect).max() <= 2e-5


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["format=tflite"], "format: unknown value 'tflite'; allowed: c, app, torchscript, onnx"),
        (["format=app", "prefix=cf"], "prefix: format=app uses the prefix datt"),
        (["prefix=9lives"], "prefix: must be a C identifier"),
        (["controller=datt"], "adaptation: the C export runs the L1 estimator onboard"),
        (["controller=pid"], "controller: the export needs a DATT policy"),
    ],
)
def test_bad_export_settings_are_one_line(overrides, message, tmp_path):
    from datt.errors import ConfigError
    from datt.tasks.export import run_export

    with pytest.raises(ConfigError) as info:
        run_export(compose("export", [*overrides, f"out_dir={tmp_path}"]))
    assert str(info.value).startswith(message) and "\n" not in str(info.value)


def test_every_layout_branch_of_the_fixed_c_matches_torch(tmp_path_factory):
    """The other side of every layout switch of the fixed C (``c/datt_policy.c``): world frame,
    no feedback, no command history, no d-hat input, H = 5 with one conv layer of kernel 5, the authors' L1 (raw
    command: no latency queue, raw predictor feedback) and another prefix; actions against torch on
    random states, the L1 against the project's over a flight, and the embedded self-test."""
    from tests.conftest import train_tiny_policy

    run = tmp_path_factory.mktemp("variant")
    overrides = ["horizon=5", "policy.kernel_size=5", "policy.conv_layers=1"]
    overrides += ["env.obs.body_frame=false", "env.obs.feedback=false"]
    checkpoint = train_tiny_policy(run, *overrides, "env.obs.action_history=0", "policy.use_d_hat=false")
    cfg = compose("export", [f"checkpoint={checkpoint}", "controller=datt_l1_paper"])
    spec, controller, merged = export_spec(cfg)
    assert (spec.body_frame, spec.feedback, spec.action_history, spec.use_d_hat) == (False, False, 0, False)
    assert (spec.horizon, len(spec.convs), spec.convs[0][0].shape[2], spec.l1.latency_steps) == (5, 1, 5, 0)
    out = run / "c"
    write_c(spec, out, prefix="cf")
    assert "datt_" not in (out / "cf_policy.c").read_text().replace("datt.", "")
    subprocess.run([GCC, *FLAGS, "-shared", "-fPIC", "-o", str(out / "libcf.so"), str(out / "cf_policy.c")], check=True)
    lib = ctypes.CDLL(str(out / "libcf.so"))
    err = ctypes.c_float()
    assert lib.cf_self_test(ctypes.byref(err)) == 0
    obs = random_observations(2000, spec.horizon, 0, seed=3)
    got = np.zeros((2000, 4), np.float32)
    arrays = {k: np.ascontiguousarray(v.numpy(), dtype=np.float32) for k, v in obs.items()}
    for i in range(2000):
        lib.cf_act(
            *(arrays[k][i].ctypes.data_as(F) for k in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat")),
            None,
            got[i].ctypes.data_as(F),
        )
    expect = reference_action(controller, merged.env.obs, obs).numpy()
    assert np.abs(got - expect).max() <= 8 * np.spacing(np.abs(expect).max())
    # the L1 without the actuator model: d-hat after a flight as the project computes it
    rec = record_rollout(merged, DattController(controller.actor, frozen=False), num_envs=1, steps=200)
    cmd, vel, quat = rec.action[:, 0], rec.vel_after[:, 0], rec.quat_after[:, 0]
    expect_d = replay_l1(instantiate_option(merged, "adaptation"), spec.l1.dt_s, spec.l1.gravity_mps2, cmd, vel, quat)
    c = [np.ascontiguousarray(x.numpy(), dtype=np.float32) for x in (cmd, vel, quat)]

    class State(ctypes.Structure):
        _fields_ = [*L1State._fields_[:-1], ("thrust_queue", ctypes.c_float * 1)]  # latency 0 + 1

    state = State()
    lib.cf_l1_reset(ctypes.byref(state), c[1][0].ctypes.data_as(F), c[2][0].ctypes.data_as(F))
    for k in range(1, 200):
        lib.cf_l1_step(ctypes.byref(state), *(x[k].ctypes.data_as(F) for x in c))
    assert np.abs(np.array(state.d_hat) - expect_d[-1].numpy()).max() <= 1e-4


def test_the_traced_example_is_one_level_drone_at_rest_on_its_reference(exported):
    """What TorchScript and ONNX trace with: one drone at the origin, at rest, level (the identity
    quaternion: a unit one, as every real input), its reference and d̂ zero, no command history."""
    from datt.export import ObservePolicyModule

    spec, controller, merged, _, _ = exported
    module = ObservePolicyModule(controller, spec.horizon, merged.env.obs)
    pos, vel, quat, ref, d_hat, hist = module.example_inputs()
    assert [t.shape for t in (pos, vel, quat, ref, d_hat, hist)] == [
        (1, 3),
        (1, 3),
        (1, 4),
        (1, spec.horizon, 3),
        (1, 3),
        (1, 4 * spec.action_history),
    ]
    assert quat.tolist() == [[1.0, 0.0, 0.0, 0.0]]
    assert all(not t.any() for t in (pos, vel, ref, d_hat, hist))
    assert module.example_inputs(5)[2].tolist() == [[1.0, 0.0, 0.0, 0.0]] * 5


# float32 values whose shortest 9-digit text takes each of _f's branches: an integer ("2" -> "2.0"),
# an exponent without a point ("1e+10"), a point, the extremes and a subnormal
TRICKY_FLOATS = [2.0, -3.0, 0.0, -0.0, 1e10, -1e10, 0.1, 16777216.0, 3.4028234663852886e38, 1.401298464324817e-45]


def test_every_float_literal_reads_back_as_the_same_float32_in_c(tmp_path):
    from datt.export.c_code import _f

    source = tmp_path / "floats.c"
    source.write_text(f"const float values[{len(TRICKY_FLOATS)}] = {{{', '.join(_f(v) for v in TRICKY_FLOATS)}}};\n")
    lib = tmp_path / "libfloats.so"
    subprocess.run([GCC, *FLAGS, "-shared", "-fPIC", "-o", str(lib), str(source)], check=True)
    read = (ctypes.c_float * len(TRICKY_FLOATS)).in_dll(ctypes.CDLL(str(lib)), "values")
    assert (
        np.array(read, np.float32).view(np.uint32).tolist()
        == np.array(TRICKY_FLOATS, np.float32).view(np.uint32).tolist()
    )


def test_the_golden_case_is_the_last_step_of_a_recorded_flight(exported):
    """The golden input is what the controller read at the 40th step of one drone's seed-0 flight
    on the export's reference, its action torch's for that input; the L1 sequence is that flight's
    commands and measured states, its d-hat the project's L1 replayed over them; the layout's
    timing is the env's (dt 0.02 s, reference points 3 steps apart)."""
    spec, controller, merged, _, _ = exported
    rec = record_rollout(merged, DattController(controller.actor, frozen=False), num_envs=1, steps=40, seed=0)
    g = spec.golden

    def same(a, b):  # replayed in another state of the process (kernels, threads): float32 rounding apart
        return torch.allclose(a, b, rtol=1e-4, atol=1e-4)

    one = {name: getattr(rec, name)[39] for name in ("pos_m", "vel_mps", "quat", "ref_m", "d_hat", "cmd_hist")}
    for key, name in (("pos", "pos_m"), ("vel", "vel_mps"), ("quat", "quat"), ("ref", "ref_m")):
        assert same(g[key], one[name][0]), key
    assert same(g["d_hat"], one["d_hat"][0]) and same(g["cmd_hist"], one["cmd_hist"][0])
    assert same(g["action"], reference_action(controller, merged.env.obs, one)[0])
    assert same(g["l1_cmd"], rec.action[:, 0]) and len(g["l1_cmd"]) == 40
    assert same(g["l1_vel"], rec.vel_after[:, 0]) and same(g["l1_quat"], rec.quat_after[:, 0])
    l1 = instantiate_option(merged, "adaptation")
    expect = replay_l1(l1, 0.02, 9.81, rec.action[:, 0], rec.vel_after[:, 0], rec.quat_after[:, 0])[-1]
    assert same(g["l1_d_hat"], expect) and expect.abs().max() > 0
    assert (spec.dt_s, spec.ref_stride, spec.l1.dt_s, spec.l1.gravity_mps2) == (0.02, 3, 0.02, 9.81)


def test_the_default_prefix_is_datt(exported):
    """``generate(spec)`` names the functions as the onboard app calls them (``datt_act``, ...)."""
    from datt.export.c_code import generate

    header, source = generate(exported[0])
    assert "datt_act(" in header and '#include "datt_policy.h"' in source


@pytest.mark.parametrize("cutoff_tau_s, filtered", [(0.0, False), (0.1, False), (0.1, True)])
def test_the_l1_spec_holds_the_bound_estimators_constants(cutoff_tau_s, filtered):
    """The C runs the constants the project's L1 runs with (law gain of eq. 7b, the filter's
    alpha; no filter, alpha 0, when the cutoff is 0)."""
    import math

    from datt.adapt.l1 import L1Adaptation
    from datt.export.c_code import l1_spec

    l1 = L1Adaptation(cutoff_tau_s=cutoff_tau_s, predictor_uses_filtered=filtered)
    l1.bind(1, 0.02, 9.81, "cpu", torch.float32)
    spec = l1_spec(l1, 0.02, 9.81)
    assert (spec.law_gain, spec.alpha, spec.predictor_uses_filtered) == (l1.law_gain, l1.alpha, filtered)
    assert spec.alpha == (math.exp(-0.02 / cutoff_tau_s) if cutoff_tau_s else 0.0)


def test_the_spec_carries_the_four_action_means_only(exported):
    """The head the C computes is the policy's mean of the 4 commands (the std rows are dropped)."""
    spec, controller, _, _, _ = exported
    hidden = spec.mlp[-1][0].shape[0]
    assert spec.head[0].shape == (4, hidden) and spec.head[1].shape == (4,)
    assert np.array_equal(spec.head[0], controller.net.head.weight[:4].detach().numpy())


@pytest.mark.parametrize(
    "change, message",
    [
        ({"stride": (2,)}, "export: only stride-1, 'same'-padded convolutions are supported"),
        ({"dilation": (2,)}, "export: only stride-1, 'same'-padded convolutions are supported"),
        ({"padding": (0,)}, "export: only stride-1, 'same'-padded convolutions are supported"),
        ({"kind": "mlp"}, "export: policy.encoder='mlp' is not supported by the C export; allowed: conv"),
    ],
    ids=["stride", "dilation", "padding", "encoder"],
)
def test_a_policy_the_fixed_c_cannot_run_is_refused_in_one_line(exported, change, message):
    """Each convolution the C cannot run (stride, dilation, padding other than 'same') and an
    encoder other than the conv is refused by name instead of exported wrong."""
    import copy

    from datt.errors import ConfigError
    from datt.export.c_code import policy_spec

    _, controller, merged, _, _ = exported
    net = copy.deepcopy(controller.net)
    if "kind" in change:
        net.encoder.kind = change["kind"]
    else:
        conv = next(m for m in net.encoder.conv if isinstance(m, torch.nn.Conv1d))
        for name, value in change.items():
            setattr(conv, name, value)
    low, high = torch.zeros(4), torch.ones(4)
    with pytest.raises(ConfigError) as info:
        policy_spec(net, 10, merged.env.obs, low, high)
    assert str(info.value) == message


@pytest.mark.parametrize("horizon", [1, 2], ids=["h1", "h2"])
def test_the_reference_stride_is_the_spacing_of_the_policys_points_in_steps(tmp_path, horizon):
    """``DATT_REF_STRIDE`` (the steps between two of the H points the app reads ahead) is
    ``env.ref_spacing_s / env.dt_s`` for every H > 1 and 1 when the policy reads one point only;
    it is part of the layout the header records."""
    from datt.export.c_code import generate
    from tests.conftest import train_tiny_policy

    checkpoint = train_tiny_policy(tmp_path, f"horizon={horizon}")
    spec, _, merged = export_spec(compose("export", [f"checkpoint={checkpoint}"]), golden_steps=5)
    spacing = round(merged.env.ref_spacing_s / merged.env.dt_s)
    assert spacing > 1  # else a stride of 1 could not tell the two cases apart
    assert spec.ref_stride == (spacing if horizon > 1 else 1)
    assert f"#define DATT_REF_STRIDE {spec.ref_stride}\n" in generate(spec)[0]
