"""The C test harness around the generated controller (datt.export.harness) on its own: the inputs
it embeds are the float32 bits of what it was given, its builds use the flags they say and fail
loudly with the compiler's message, and the Cortex-M4F timing program counts instructions the
same way every time."""

import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
import torch

from datt.configuration import compose
from datt.export import export_spec, write_c
from datt.export.harness import (
    COMMON_FLAGS,
    M4_GCC,
    QEMU,
    _floats,
    build_host,
    build_m4,
    build_m4_timing,
    flags_at,
    instructions_per_call,
    run_qemu,
    toolchain_missing,
    vectors_h,
    write_harness,
)

from .test_c_export import GCC, random_observations

ARRAY = re.compile(r"static const uint32_t (\w+)_bits\[(\d+)\] = \{([^}]*)\};")


def arrays_of(header: str) -> dict[str, np.ndarray]:
    """Every ``<name>_bits`` array of a generated header, as float32, checked against its length."""
    out = {}
    for name, length, words in ARRAY.findall(header):
        bits = np.array([int(w.strip().rstrip("u"), 16) for w in words.split(",")], dtype=np.uint32)
        assert len(bits) == int(length), name
        out[name] = bits.view(np.float32)
    return out


def define(header: str, name: str) -> int:
    return int(re.search(rf"#define {name} (\d+)", header).group(1))


def test_the_vectors_are_the_float32_bits_of_float64_arrays_and_of_tensors_that_need_grad():
    spec_h, hist = 5, 3
    obs = random_observations(4, spec_h, hist, seed=1)
    obs64 = {k: v.double().numpy() for k, v in obs.items()}  # float64: rounded to float32, never reinterpreted
    obs64["pos_m"] = torch.tensor(obs64["pos_m"], requires_grad=True)  # a tensor that needs grad: detached
    l1_cmd = np.random.default_rng(0).normal(size=(6, 4))  # float64 numpy
    l1_vel = torch.randn(6, 3, dtype=torch.float64, requires_grad=True)
    l1_quat = torch.randn(6, 4)
    header = vectors_h(obs64, l1_cmd, l1_vel, l1_quat)
    got = arrays_of(header)
    for key, value in obs.items():
        np.testing.assert_array_equal(got[key], value.numpy().reshape(-1), err_msg=key)
    np.testing.assert_array_equal(got["l1_cmd"], l1_cmd.astype(np.float32).reshape(-1))
    np.testing.assert_array_equal(got["l1_vel"], l1_vel.detach().float().numpy().reshape(-1))
    np.testing.assert_array_equal(got["l1_quat"], l1_quat.numpy().reshape(-1))
    assert (define(header, "N_OBS"), define(header, "HIST_LEN"), define(header, "N_L1")) == (4, 4 * hist, 6)


def test_an_array_declares_as_many_words_as_it_holds_and_an_empty_one_a_single_zero():
    """C99 has no empty initializer and no zero-length array: an empty input is one zero word."""
    assert _floats("one", [1.0]) == "static const uint32_t one_bits[1] = {0x3f800000u};\n"
    assert _floats("two", [[-2.0], [0.5]]) == "static const uint32_t two_bits[2] = {0xc0000000u, 0x3f000000u};\n"
    assert _floats("none", []) == "static const uint32_t none_bits[1] = {0u};\n"


@pytest.mark.parametrize("opt", ["-O0", "-Os", "-O2", "-O3"])
def test_the_flags_hold_exactly_one_optimisation_level_the_one_asked_for(opt):
    flags = flags_at(opt)
    assert [f for f in flags if f.startswith("-O")] == [opt]
    assert [f for f in flags if not f.startswith("-O")] == [f for f in COMMON_FLAGS if not f.startswith("-O")]


@pytest.fixture(scope="module")
def harness_dir(tmp_path_factory):
    """The default export's C and a small harness (20 observations, 30 L1 steps)."""
    spec, _, _ = export_spec(compose("export", []))
    out = tmp_path_factory.mktemp("harness")
    write_c(spec, out)
    obs = random_observations(20, spec.horizon, spec.action_history, seed=3)
    g = torch.Generator().manual_seed(4)
    quat = torch.randn(30, 4, generator=g)
    write_harness(
        out,
        vectors_h(
            obs, torch.rand(30, 4, generator=g), torch.randn(30, 3, generator=g), quat / quat.norm(dim=-1, keepdim=True)
        ),
    )
    return spec, out


def broken_copy(src: Path, dst: Path, program: str = "harness") -> Path:
    shutil.copytree(src, dst)
    (dst / f"{program}.c").write_text("int run_all(void) { return undeclared_name; }\n")
    return dst


@pytest.mark.skipif(GCC is None, reason="no gcc")
def test_the_host_build_defaults_to_o2_and_prints_every_output(harness_dir):
    _, out = harness_dir
    exe = build_host(out)
    assert exe == out / "harness_host-O2" and exe.is_file()
    lines = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout.splitlines()
    assert len(lines) == 20 + 29 + 1 and lines[-1] == "self-test ok"
    assert all(len(line.split()) == 4 for line in lines[:20]) and all(len(line.split()) == 3 for line in lines[20:-1])


@pytest.mark.skipif(GCC is None, reason="no gcc")
def test_a_failing_host_build_raises_with_the_compilers_message(harness_dir, tmp_path):
    _, out = harness_dir
    with pytest.raises(subprocess.CalledProcessError) as info:
        build_host(broken_copy(out, tmp_path / "broken"))
    assert "undeclared_name" in info.value.stderr  # captured, as text


needs_m4 = pytest.mark.skipif(toolchain_missing() is not None, reason=f"{toolchain_missing()}")


@needs_m4
def test_the_m4_build_defaults_to_o2_and_a_failing_one_raises_with_the_compilers_message(harness_dir, tmp_path):
    _, out = harness_dir
    elf = build_m4(out)
    assert elf == out / "harness_m4-O2.elf" and elf.is_file()
    lines = run_qemu(elf).splitlines()
    assert len(lines) == 20 + 29 + 1 and lines[-1] == "self-test ok"
    with pytest.raises(subprocess.CalledProcessError) as info:
        build_m4(broken_copy(out, tmp_path / "broken"))
    assert "undeclared_name" in info.value.stderr


@needs_m4
def test_the_timing_program_counts_the_same_instructions_every_run(harness_dir):
    """Under -icount every instruction takes the same virtual time: the counts repeat exactly.
    One action touches every weight of the network at least once; one L1 step is a few dozen
    operations, far fewer than one action."""
    spec, out = harness_dir
    elf = build_m4_timing(out)
    assert elf == out / "timing_m4-O2.elf" and (out / "timing.c").is_file()
    act, l1 = instructions_per_call(elf)
    assert instructions_per_call(elf) == (act, l1)
    weights = sum(w.size for w, _ in (*spec.convs, spec.proj, *spec.mlp, spec.head))
    assert weights <= act < 50 * weights
    assert 20 < l1 < act / 10


def test_a_missing_tool_is_named_with_how_to_install_it(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path))
    assert toolchain_missing().startswith(f"{M4_GCC} not found (Debian: apt-get install")
    fake = tmp_path / M4_GCC
    fake.write_text("#!/bin/sh\n")
    fake.chmod(0o755)
    assert toolchain_missing().startswith(f"{QEMU} not found")
    (tmp_path / QEMU).write_text("#!/bin/sh\n")
    (tmp_path / QEMU).chmod(0o755)
    assert toolchain_missing() is None
