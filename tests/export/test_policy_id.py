"""The exported build's identity (``datt.export.c_code.policy_id``, ``DATT_POLICY_ID`` in the
generated header, checked by the host against the onboard app): a CRC-32 of everything the C
step computes with, as float32, so that any change to the policy or its estimator changes it."""

import copy
import zlib
from dataclasses import fields, replace

import numpy as np
import pytest

from datt.configuration import compose
from datt.errors import ConfigError
from datt.export import export_spec
from datt.export.c_code import L1Spec, PolicySpec, generate, policy_id


def small_spec(dtype=np.float32) -> PolicySpec:
    g = np.random.default_rng(0)

    def layer(*shape):
        return g.normal(size=shape).astype(dtype), g.normal(size=shape[0]).astype(dtype)

    l1 = L1Spec(0.02, 9.81, -5.0, 1.0, 0.9, 1.0, 1, False)
    return PolicySpec(
        horizon=3,
        body_frame=True,
        feedback=True,
        action_history=2,
        action_low=[0.0, -10.0, -10.0, -3.0],
        action_high=[20.0, 10.0, 10.0, 3.0],
        convs=[layer(4, 3, 2)],
        proj=layer(5, 12),
        mlp=[layer(6, 26)],
        head=layer(4, 6),
        l1=l1,
    )


def by_definition(spec: PolicySpec) -> int:
    """The id as the docstring defines it, written out: CRC-32 over the float32 bytes of every
    weight and bias (conv layers, projection, MLP, head, in order), then of the numbers (action
    bounds, dt, the L1 constants), then of the layout's repr."""
    crc = 0
    for w, b in (*spec.convs, spec.proj, *spec.mlp, spec.head):
        crc = zlib.crc32(np.asarray(w, np.float32).tobytes(), crc)
        crc = zlib.crc32(np.asarray(b, np.float32).tobytes(), crc)
    l1 = spec.l1
    numbers = [*spec.action_low, *spec.action_high, spec.dt_s]
    numbers += [l1.dt_s, l1.gravity_mps2, l1.a_s, l1.law_gain, l1.alpha, l1.k_thrust, l1.latency_steps]
    crc = zlib.crc32(np.asarray(numbers, np.float32).tobytes(), crc)
    layout = (spec.horizon, spec.body_frame, spec.feedback, spec.action_history, spec.use_d_hat, spec.ref_stride)
    return zlib.crc32(repr((*layout, l1.predictor_uses_filtered)).encode(), crc)


def test_the_id_is_the_crc32_of_what_the_c_step_computes_with_in_float32():
    spec = small_spec()
    assert policy_id(spec) == by_definition(spec)
    # float64 weights are exported as float32: the id is of the float32 values, as the C computes
    assert policy_id(small_spec(np.float64)) == by_definition(small_spec(np.float64))


def test_any_one_weight_changes_the_id_and_the_same_spec_keeps_it():
    spec = small_spec()
    assert policy_id(spec) == policy_id(copy.deepcopy(spec))
    ids = {policy_id(spec)}
    layers = [*spec.convs, spec.proj, *spec.mlp, spec.head]
    for i in range(len(layers)):
        for which in range(2):
            changed = copy.deepcopy(spec)
            arrays = [*changed.convs, changed.proj, *changed.mlp, changed.head][i]
            arrays[which].reshape(-1)[-1] += 0.5  # the last element of each array
            ids.add(policy_id(changed))
    assert len(ids) == 1 + 2 * len(layers)


def test_every_layout_field_bound_and_l1_constant_changes_the_id():
    spec = small_spec()
    variants = {
        "horizon": replace(spec, horizon=4),
        "body_frame": replace(spec, body_frame=False),
        "feedback": replace(spec, feedback=False),
        "action_history": replace(spec, action_history=1),
        "use_d_hat": replace(spec, use_d_hat=False),
        "ref_stride": replace(spec, ref_stride=2),
        "dt_s": replace(spec, dt_s=0.01),
        "action_low": replace(spec, action_low=[0.0, -10.0, -10.0, -2.0]),
        "action_high": replace(spec, action_high=[21.0, 10.0, 10.0, 3.0]),
        "no l1": replace(spec, l1=None),
    }
    new_values = {"dt_s": 0.01, "gravity_mps2": 9.8, "a_s": -4.0, "law_gain": 2.0, "alpha": 0.8}
    new_values.update({"k_thrust": 0.9, "latency_steps": 2, "predictor_uses_filtered": True})
    assert set(new_values) == {f.name for f in fields(L1Spec)}
    for name, value in new_values.items():
        variants[f"l1.{name}"] = replace(spec, l1=replace(spec.l1, **{name: value}))
    ids = {name: policy_id(v) for name, v in variants.items()}
    assert len(set(ids.values()) | {policy_id(spec)}) == len(ids) + 1, ids


@pytest.mark.parametrize("bad", [float("inf"), float("-inf"), float("nan")], ids=["inf", "-inf", "nan"])
def test_a_non_finite_weight_is_refused_in_one_line(bad):
    spec, _, _ = export_spec(compose("export", []))
    spec.head[1][0] = bad
    with pytest.raises(ConfigError, match=r"^export: non-finite value (-?inf|nan) in the policy$"):
        generate(spec)


def test_generate_refuses_an_incomplete_spec_in_one_line():
    spec = small_spec()
    with pytest.raises(ConfigError) as no_l1:
        generate(replace(spec, l1=None))
    assert str(no_l1.value) == "export: the C export needs the L1 constants (spec.l1)"
    with pytest.raises(ConfigError) as no_golden:
        generate(spec)
    assert str(no_golden.value) == "export: the C export needs a golden input/output pair (spec.golden)"
    g = np.random.default_rng(1)
    second = (g.normal(size=(4, 4, 3)).astype(np.float32), np.zeros(4, np.float32))
    with pytest.raises(ConfigError) as kernels:
        generate(replace(spec, convs=[*spec.convs, second], golden={"present": True}))
    assert str(kernels.value) == "export: every conv layer must have the same kernel size"


def test_write_c_makes_the_directories_it_needs(tmp_path):
    from datt.export import write_c

    spec, _, _ = export_spec(compose("export", []))
    header, source = write_c(spec, tmp_path / "new" / "deeper")
    assert header.read_text().startswith("/* Generated by datt") and source.is_file()
