"""The generated C built for the Crazyflie's Cortex-M4F with the firmware's flags and run under
qemu (STM32F405 model) gives the same bits as the host build with the same flags."""

import subprocess

import pytest

from datt.configuration import compose
from datt.control.datt import DattController
from datt.export import export_spec, record_rollout, write_c
from datt.export.harness import build_host, build_m4, run_qemu, toolchain_missing, vectors_h, write_harness

from .test_c_export import GCC, random_observations

MISSING = toolchain_missing() or (None if GCC else "gcc not found")
pytestmark = pytest.mark.skipif(MISSING is not None, reason=f"Cortex-M4F build or qemu unavailable: {MISSING}")


@pytest.mark.parametrize("opt", ["-Os", "-O2"])  # -Os: the firmware's level (GCC uses VMLA there)
def test_cortex_m4_build_under_qemu_matches_the_host_build_bit_for_bit(opt, tmp_path):
    spec, controller, merged = export_spec(compose("export", []))
    write_c(spec, tmp_path)
    obs = random_observations(300, spec.horizon, spec.action_history, seed=2)
    rec = record_rollout(merged, DattController(controller.actor, frozen=False), num_envs=1, steps=500)
    write_harness(tmp_path, vectors_h(obs, rec.action[:, 0], rec.vel_after[:, 0], rec.quat_after[:, 0]))
    host = subprocess.run([str(build_host(tmp_path, opt=opt))], check=True, capture_output=True, text=True).stdout
    m4 = run_qemu(build_m4(tmp_path, opt=opt))
    lines = host.splitlines()
    assert len(lines) == 300 + 499 + 1 and lines[-1] == "self-test ok"
    assert m4 == host  # every action and d-hat word, and the on-target self-test
