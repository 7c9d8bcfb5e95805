"""The policy as a Crazyflie app (``datt export format=app``; docs/onboard.md).

:func:`write_app` writes an out-of-tree firmware app: the generated policy and L1
(``datt_policy.c/.h``, :mod:`datt.export.c_code`), the firmware-independent onboard controller
(``datt_onboard.c/.h``: the reference table, the 50 Hz step, the upload protocol) and the firmware
glue (``app_datt.c``: the task, the out-of-tree controller hook, the ``datt`` parameters and log
variables), with the Kbuild files and the app config. :func:`build_sil_library` compiles the
firmware-independent part for this machine: the simulated Crazyflie runs it as its onboard
controller (``deploy.onboard=true``), the same C the vehicle runs.
"""

from __future__ import annotations

import shutil
import subprocess
from importlib import resources
from pathlib import Path

from datt.errors import ConfigError
from datt.export.c_code import PolicySpec, generate
from datt.runs import atomic_write

SOURCES = ("datt_onboard.h", "datt_onboard.c", "app_datt.c")  # shipped as package data (datt/export/app/)
SIL_FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-fPIC", "-shared", "-Wall", "-Wextra", "-Werror"]


def write_app(spec: PolicySpec, out_dir) -> list[Path]:
    """Write the app directory (``Makefile``, ``Kbuild``, ``app-config``, ``src/``) into
    ``out_dir``; returns the files written."""
    out = Path(out_dir)
    src = out / "src"
    src.mkdir(parents=True, exist_ok=True)
    header, source = generate(spec, "datt")
    files = {src / "datt_policy.h": header, src / "datt_policy.c": source}
    shipped = resources.files("datt.export") / "app"
    for name in SOURCES:
        files[src / name] = (shipped / name).read_text()
    files[src / "Kbuild"] = (shipped / "Kbuild.src").read_text()
    files[out / "Kbuild"] = (shipped / "Kbuild.top").read_text()
    files[out / "Makefile"] = (shipped / "Makefile").read_text()
    files[out / "app-config"] = (shipped / "app-config").read_text()
    for path, text in files.items():
        with atomic_write(path) as f:
            f.write(text)
    return list(files)


def build_sil_library(app_dir, cc: str = "gcc") -> Path:
    """Compile the app's firmware-independent sources (policy, L1, onboard controller) into a
    shared library for the simulated Crazyflie; returns its path (``<app_dir>/libdatt_onboard.so``)."""
    src = Path(app_dir) / "src"
    if shutil.which(cc) is None:
        raise ConfigError(f"deploy.onboard: the simulated onboard controller is compiled with {cc}, not found")
    lib = Path(app_dir) / "libdatt_onboard.so"
    tmp = lib.with_suffix(".so.tmp")
    cmd = [cc, *SIL_FLAGS, str(src / "datt_policy.c"), str(src / "datt_onboard.c"), "-o", str(tmp)]
    run = subprocess.run(cmd, capture_output=True, text=True)
    if run.returncode != 0:
        raise RuntimeError(f"building the onboard controller failed: {' '.join(cmd)}\n{run.stderr}")
    tmp.replace(lib)
    return lib
