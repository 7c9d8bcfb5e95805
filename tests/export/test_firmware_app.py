"""The exported app built out of tree against the Crazyflie firmware (``make`` with the
firmware's own Kbuild and flags, ``-Werror``), when a firmware checkout is at hand:
``CRAZYFLIE_FIRMWARE=/path/to/crazyflie-firmware`` (tag 2026.08, with its submodules;
docs/onboard.md). A full firmware build takes minutes: slow."""

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from datt.configuration import compose
from datt.export import export_spec
from datt.export.app import write_app

FIRMWARE = os.environ.get("CRAZYFLIE_FIRMWARE")


@pytest.mark.slow
@pytest.mark.skipif(not FIRMWARE, reason="set CRAZYFLIE_FIRMWARE to a crazyflie-firmware checkout to build the app")
@pytest.mark.skipif(shutil.which("arm-none-eabi-gcc") is None, reason="arm-none-eabi-gcc not found")
def test_the_app_builds_into_the_firmware(tmp_path):
    spec, _, _ = export_spec(compose("export", []))
    write_app(spec, tmp_path)
    run = subprocess.run(
        ["make", f"CRAZYFLIE_BASE={Path(FIRMWARE).resolve()}", f"-j{os.cpu_count() or 1}"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
    )
    assert run.returncode == 0, run.stdout[-3000:] + run.stderr[-3000:]
    for name in ("datt_policy.o", "datt_onboard.o", "app_datt.o"):
        assert (tmp_path / "src" / name).is_file()  # built with the firmware's flags, -Werror
    flash = re.search(r"Flash \|\s+(\d+)/(\d+)", run.stdout)
    assert flash and int(flash[1]) < int(flash[2])  # the image fits
    symbols = subprocess.run(
        ["arm-none-eabi-nm", str(tmp_path / "build" / "cf2.elf")], capture_output=True, text=True, check=True
    ).stdout
    for symbol in ("appMain", "controllerOutOfTree", "datt_onboard_step", "datt_act", "__params_datt"):
        assert re.search(rf" {symbol}$", symbols, re.M), symbol
