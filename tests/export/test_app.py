"""``datt export format=app``'s two steps on their own, each in a fresh directory: the app
directory written (every file, nested output paths, a rewrite over an earlier export) and the
firmware-independent part compiled for the simulated Crazyflie (the library holds the policy and
the onboard controller; a missing compiler and a failing build are one clear error)."""

import ctypes
import shutil
from importlib import resources

import pytest

from datt.configuration import compose
from datt.errors import ConfigError
from datt.export import export_spec
from datt.export.app import SIL_FLAGS, SOURCES, build_sil_library, write_app

needs_gcc = pytest.mark.skipif(shutil.which("gcc") is None, reason="no gcc: the onboard library cannot be built")


@pytest.fixture(scope="module")
def spec():
    return export_spec(compose("export", []))[0]


def test_the_app_is_written_into_a_new_nested_directory_and_again_over_itself(tmp_path, spec):
    out = tmp_path / "a" / "b" / "app"  # none of it exists yet
    files = write_app(spec, out)
    names = sorted(str(p.relative_to(out)) for p in files)
    expected = ["Kbuild", "Makefile", "app-config", "src/Kbuild", "src/datt_policy.c", "src/datt_policy.h"]
    assert names == sorted(expected + [f"src/{n}" for n in SOURCES])
    shipped = resources.files("datt.export") / "app"
    for name in SOURCES:
        assert (out / "src" / name).read_text() == (shipped / name).read_text()
    assert (out / "Kbuild").read_text() == (shipped / "Kbuild.top").read_text()
    assert (out / "src" / "Kbuild").read_text() == (shipped / "Kbuild.src").read_text()
    assert "void datt_act(" in (out / "src" / "datt_policy.h").read_text()  # the functions' prefix
    (out / "src" / "datt_policy.c").write_text("stale")
    assert write_app(spec, out) == files  # a second export over the first rewrites every file
    assert (out / "src" / "datt_policy.c").read_text() != "stale"


@needs_gcc
def test_the_library_holds_the_policy_and_the_onboard_controller(tmp_path, spec):
    write_app(spec, tmp_path)
    lib = build_sil_library(tmp_path)
    assert lib == tmp_path / "libdatt_onboard.so" and lib.is_file()
    assert sorted(p.name for p in tmp_path.glob("*.so*")) == ["libdatt_onboard.so"]  # no temporary left
    loaded = ctypes.CDLL(str(lib))
    assert hasattr(loaded, "datt_onboard_params_of")  # datt_onboard.c
    for name in ("datt_act", "datt_l1_step", "datt_self_test"):  # datt_policy.c
        assert hasattr(loaded, name)


def test_a_missing_compiler_is_one_line_naming_it(tmp_path, spec):
    write_app(spec, tmp_path)
    with pytest.raises(ConfigError) as err:
        build_sil_library(tmp_path, cc="no-such-compiler-datt")
    assert str(err.value) == (
        "deploy.onboard: the simulated onboard controller is compiled with no-such-compiler-datt, not found"
    )
    assert not (tmp_path / "libdatt_onboard.so").exists()


@needs_gcc
def test_a_failing_build_says_the_command_and_the_compilers_message(tmp_path, spec):
    write_app(spec, tmp_path)
    (tmp_path / "src" / "datt_onboard.c").write_text("int broken(void) { return undeclared_name; }\n")
    with pytest.raises(RuntimeError) as err:
        build_sil_library(tmp_path)
    text = str(err.value)
    src = tmp_path / "src"
    command = " ".join(["gcc", *SIL_FLAGS, str(src / "datt_policy.c"), str(src / "datt_onboard.c")])
    assert text.startswith(f"building the onboard controller failed: {command} -o ")
    first, _, stderr = text.partition("\n")
    assert "undeclared_name" in stderr and "error" in stderr and not stderr.startswith(("b'", 'b"', "None"))
    assert not (tmp_path / "libdatt_onboard.so").exists()
