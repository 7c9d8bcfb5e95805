"""The firmware numbers the host relies on (:mod:`datt.deploy.firmware`) against a firmware checkout
(``CRAZYFLIE_FIRMWARE=/path/to/crazyflie-firmware``, tag 2026.08), and the rules that read them
against hand-written sources (so a rule that cannot find what it looks for fails here, not only
on a checkout)."""

import math
import os
import re

import pytest
import torch

from datt.deploy import firmware
from datt.deploy.firmware import FACTS, Fact, read_fact
from datt.sim.vehicles import RATE_LOOPS, VEHICLES, number

FIRMWARE = os.environ.get("CRAZYFLIE_FIRMWARE")


@pytest.mark.skipif(not FIRMWARE, reason="set CRAZYFLIE_FIRMWARE to a crazyflie-firmware checkout")
@pytest.mark.parametrize("name", sorted(FACTS))
def test_each_fact_is_what_the_firmware_says(name):
    item = FACTS[name]
    assert read_fact(FIRMWARE, item) == item.value, f"{name}: {item.file} ({item.rule} {item.where!r})"


@pytest.mark.skipif(not FIRMWARE, reason="set CRAZYFLIE_FIRMWARE to a crazyflie-firmware checkout")
def test_the_simulated_firmware_models_the_same_firmware():
    """The simulated Crazyflie keeps its own copy of what it emulates (so that a host typo is not
    shared with it); that copy must be the firmware's too."""
    from datt.deploy.sim import server

    for name in ("PID", "Mellinger", "INDI", "Brescianini", "Lee"):
        assert server.CONTROLLERS.index(name) == FACTS[f"controller_{name.lower()}"].value
    assert server.CONTROLLERS.index("OutOfTree") == FACTS["controller_oot"].value
    assert server.APP_CHANNEL_QUEUE == FACTS["app_channel_rx_queue"].value
    assert server.SUPERVISOR_PERIOD_S == pytest.approx(1 / FACTS["supervisor_update_hz"].value)
    assert server.ESTOP_WATCHDOG_S * 1000 == FACTS["estop_watchdog_ms"].value
    assert (server.WATCHDOG_LEVEL_S * 1000, server.WATCHDOG_OFF_S * 1000) == (
        FACTS["setpoint_watchdog_level_ms"].value,
        FACTS["setpoint_watchdog_off_ms"].value,
    )
    assert (server.RPYT_MIN_THRUST, server.RPYT_MAX_THRUST) == (
        FACTS["rpyt_min_thrust"].value,
        FACTS["rpyt_max_thrust"].value,
    )
    from datt.deploy.sim import stabilizer as st

    assert st.ATTITUDE_RATE_HZ == FACTS["attitude_rate_hz"].value


@pytest.mark.parametrize("name", sorted(VEHICLES))
def test_every_number_of_a_vehicle_preset_is_a_fact_or_cited(name):
    """Each preset's numbers have one source each: a firmware fact (read back from a checkout by
    the test above) or a citation; nothing of the preset is left unsourced."""
    v = VEHICLES[name]
    numbers = {"thrust_max_n", "thrust_min_n", "thrust2torque_m", "firmware_mass_kg", "mass_kg", "rate_loop"}
    numbers |= {"arm_length_m", "max_command"} | {f"vmotor2thrust[{i}]" for i in range(4)}
    numbers |= {f"inertia_kgm2[{i}]" for i in range(3)} | {f"rate_pid[{i}][{j}]" for i in range(3) for j in range(4)}
    assert set(v.sources) == numbers
    for key, src in v.sources.items():
        if src.rule == "cited":
            assert src.file, key
        else:
            assert FACTS[f"{name}.{key}"].value == number(v, key)
    assert v.rate_loop in RATE_LOOPS
    assert v.max_command == FACTS["rpyt_max_thrust"].value


@pytest.mark.parametrize("name", sorted(VEHICLES))
def test_the_simulated_vehicle_and_the_training_loop_fly_the_presets_numbers(name):
    """The simulated Crazyflie's stabilizer and motors and the training side's firmware rate model
    take every constant from the preset (no copy of their own to drift)."""
    from datt.deploy.sim.motors import FirmwareMotors, MotorParams
    from datt.deploy.sim.stabilizer import Stabilizer, body_torques_nm
    from datt.sim.firmware_rates import FirmwareRateLoop

    v = VEHICLES[name]
    motors = FirmwareMotors(MotorParams(vehicle=name))
    assert (motors.p.mass_kg, motors.p.thrust_max_n, motors.p.thrust_min_n) == (
        v.mass_kg,
        v.thrust_max_n,
        v.thrust_min_n,
    )
    p0, p1, p2, p3 = v.vmotor2thrust
    assert motors.fit_force_n(3.5) == pytest.approx(p0 + 3.5 * (p1 + 3.5 * (p2 + 3.5 * p3)), rel=1e-12)
    st = Stabilizer(motors)
    assert [(p.kp, p.ki, p.kd, p.i_limit) for p in st.pids] == list(v.rate_pid)
    arm = v.arm_length_m / math.sqrt(2)
    assert body_torques_nm([1.0, 0.0, 0.0, 0.0], v) == pytest.approx((-arm, -arm, -v.thrust2torque_m), rel=1e-12)
    loop = FirmwareRateLoop(1, 0.02, v.mass_kg, 0.03, 9.81, torch.device("cpu"), torch.float64, v)
    assert loop.kp.tolist() == [g[0] for g in v.rate_pid] and loop.inertia.tolist() == list(v.inertia_kgm2)
    assert loop.torque_per_n[:, 0].tolist() == pytest.approx([-arm, -arm, -v.thrust2torque_m], rel=1e-12)
    assert loop.command_per_mps2 == pytest.approx(v.mass_kg / 4 / v.thrust_max_n * 65535, rel=1e-12)


def test_the_branch_rule_reads_the_define_of_the_named_setup_only():
    source = """
#if defined(CONFIG_KIT)
    #define CF_MASS 0.0325f
#else
    #define CF_MASS 0.029f
#endif
#ifdef CONFIG_COMPENSATED
    #if defined(CONFIG_PLUS)
        #define THRUST_MAX 0.12f
    #elif defined(CONFIG_KIT) // kit
        #if 0
        #define THRUST_MAX 9.0f
        #endif
        #define THRUST_MAX 0.18f
    #endif
#endif
"""
    assert firmware._branch_define(source, "CONFIG_KIT", "THRUST_MAX") == "0.18f"
    assert firmware._branch_define(source, "CONFIG_PLUS", "THRUST_MAX") == "0.12f"
    assert firmware._branch_define(source, "CONFIG_KIT", "CF_MASS") == "0.0325f"
    assert firmware._branch_define(source, "!CONFIG_KIT", "CF_MASS") == "0.029f"
    assert firmware._branch_define(source, "CONFIG_PLUS", "CF_MASS") is None
    assert firmware._branch_define(source, "CONFIG_KI", "THRUST_MAX") is None  # a whole word only


CONTROLLER_H = """
typedef enum {
  ControllerTypeAutoSelect,
  ControllerTypePID,
  ControllerTypeLee,
#ifdef CONFIG_CONTROLLER_OOT
  ControllerTypeOot,
#endif
  ControllerType_COUNT,
} ControllerType;
"""


def test_an_enum_member_is_counted_with_the_builds_options(tmp_path):
    (tmp_path / "c.h").write_text(CONTROLLER_H)
    assert read_fact(tmp_path, Fact(3, "c.h", "enum", "ControllerType.ControllerTypeOot")) == 3
    assert read_fact(tmp_path, Fact(0, "c.h", "enum", "ControllerType.ControllerType_COUNT"), options=()) == 3
    assert read_fact(tmp_path, Fact(0, "c.h", "enum", "ControllerType.ControllerTypeOot"), options=()) is None
    assert read_fact(tmp_path, Fact(0, "c.h", "enum", "ControllerType.ControllerTypeMellinger")) is None


def test_defines_regexes_and_parameters_are_read(tmp_path):
    (tmp_path / "s.c").write_text(
        "#define COMMANDER_WDT_TIMEOUT_SHUTDOWN   M2T(2000)\n#define X_TIMEOUT (M2T(1000))\n#define T 0.12f  // N\n"
        "rxQueue = xQueueCreate(10, sizeof(CRTPPacket));\n"
        "PARAM_GROUP_START(flightmode)\nPARAM_ADD_CORE(PARAM_UINT8, althold, &a)\nPARAM_GROUP_STOP(flightmode)\n"
    )
    assert read_fact(tmp_path, Fact(0, "s.c", "define", "COMMANDER_WDT_TIMEOUT_SHUTDOWN")) == 2000
    assert read_fact(tmp_path, Fact(0, "s.c", "define", "X_TIMEOUT")) == 1000
    assert read_fact(tmp_path, Fact(0, "s.c", "define", "T")) == 0.12
    assert read_fact(tmp_path, Fact(0, "s.c", "regex", FACTS["app_channel_rx_queue"].where)) == 10
    assert read_fact(tmp_path, Fact("flightmode.althold", "s.c", "param", "")) == "flightmode.althold"
    assert read_fact(tmp_path, Fact("flightmode.poshold", "s.c", "param", "")) is None
    assert read_fact(tmp_path, Fact(0, "missing.c", "define", "T")) is None


def test_the_host_types_no_firmware_number_of_its_own():
    """The modules that talk to the firmware take its numbers from the table."""
    from importlib import resources

    root = resources.files("datt.deploy")
    for module in ("link.py", "onboard.py", "runner.py"):
        text = (root / module).read_text()
        assert not re.search(r"stabilizer\.controller\"?, *\d", text), module
        assert not re.search(r"CONTROLLER_\w+ *= *\d", text) and "KALMAN_ESTIMATOR = " not in text, module
    assert firmware.CONTROLLER_OOT == 6 and firmware.CONTROLLER_PID == 1 and firmware.FIRMWARE_VERSION == "2026.08"


ENUM_H = """
typedef enum {
  ModeA = 0,  // the first; a comment with = and , in it
  /* a comment over two lines
     that names NotAMember, */
  ModeB,      /* counted */
#if defined(CONFIG_MODE_C)
  ModeC,
#endif
#ifdef CONFIG_MODE_D
  ModeD,
#else
  ModeNotD,
#endif
#if 0
  ModeDead,
#endif
#pragma GCC diagnostic push
#if 1
  ModeAlways,
#endif
#ifndef CONFIG_MODE_C
  ModeNotC,
#endif
  ModeHex = 0x10,
  ModeAfterHex,
  ModeMAX
} Mode;
"""


@pytest.mark.parametrize(
    "options, member, index",
    [
        ((), "ModeB", 1),
        ((), "ModeC", None),  # behind an option the build does not enable: not a member
        (("CONFIG_MODE_C",), "ModeC", 2),
        (("CONFIG_MODE_D",), "ModeD", 2),
        (("CONFIG_MODE_C", "CONFIG_MODE_D"), "ModeD", 3),
        (("CONFIG_MODE_D",), "ModeNotD", None),  # the #else branch of an enabled option
        ((), "ModeNotD", 2),
        ((), "ModeAlways", 3),  # #if 1: always
        ((), "ModeNotC", 4),  # #ifndef: there without the option ...
        (("CONFIG_MODE_C",), "ModeNotC", None),  # ... not with it
        ((), "ModeHex", 16),  # an explicit value, in hex, restarts the count ...
        (("CONFIG_MODE_C",), "ModeAfterHex", 17),  # ... whatever the options before it
        ((), "ModeMAX", 18),  # the last member, without a comma
        ((), "NotAMember", None),
        (("CONFIG_MODE_C", "CONFIG_MODE_D"), "ModeDead", None),  # #if 0: never; other directives: not members
    ],
    ids=["plain", "option-off", "if-defined-on", "ifdef-on", "both-on", "else-off", "else-on", "if-1",
         "ifndef-on", "ifndef-off", "hex", "after-hex", "last", "comment", "if-0"],
)  # fmt: skip
def test_an_enum_is_counted_as_the_compiler_counts_it(tmp_path, options, member, index):
    """C's rule: a member is one more than the one before unless it has its own value; members
    behind ``#ifdef`` / ``#if defined(...)`` exist only with the option; comments are not code."""
    (tmp_path / "m.h").write_text(ENUM_H)
    assert read_fact(tmp_path, Fact(0, "m.h", "enum", f"Mode.{member}"), options=options) == index


@pytest.mark.parametrize(
    "text, value",
    [("M2T(2000)", 2000), ("(M2T(500))", 500), ("M2T((100))", 100), ("0.25f", 0.25), ("2.0F", 2.0),
     ("10u", 10), ("7U", 7), ("0x20", 32), ("( 3 )", 3), ("(1.5f)", 1.5)],
)  # fmt: skip
def test_a_c_number_is_read_as_c_writes_it(text, value):
    """Ticks from milliseconds (``M2T``), float and unsigned suffixes of either case, hex, and
    parentheses around any of them."""
    value_read = firmware._number(text)
    assert value_read == value and type(value_read) is type(value)


def test_a_file_that_is_not_utf8_is_still_read_and_an_unknown_rule_is_refused(tmp_path):
    (tmp_path / "s.c").write_bytes(b"// \xff\xfe a Latin-1 comment\n#define RATE 500\n")
    assert read_fact(tmp_path, Fact(0, "s.c", "define", "RATE")) == 500
    assert read_fact(tmp_path, Fact(0, "s.c", "regex", r"#define NOPE (\d+)")) is None
    assert read_fact(tmp_path, Fact(0, "s.c", "define", "NOPE")) is None
    with pytest.raises(ValueError, match=r"^unknown rule 'table'$"):
        read_fact(tmp_path, Fact(0, "s.c", "table", "RATE"))
