"""The firmware numbers the host relies on (:mod:`datt.deploy.firmware`) against a firmware checkout
(``CRAZYFLIE_FIRMWARE=/path/to/crazyflie-firmware``, tag 2026.08), and the rules that read them
against hand-written sources (so a rule that cannot find what it looks for fails here, not only
on a checkout)."""

import os
import re

import pytest

from datt.deploy import firmware
from datt.deploy.firmware import FACTS, Fact, read_fact

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
    assert (st.ARM_LENGTH_M, st.THRUST2TORQUE_M) == (FACTS["arm_length_m"].value, FACTS["thrust2torque_m"].value)
    assert st.INERTIA_KGM2 == tuple(FACTS[f"inertia_{a}_kgm2"].value for a in "xyz")
    terms = ("kp", "ki", "kd", "integration_limit")
    assert st.RATE_PID_CF2 == tuple(
        tuple(FACTS[f"pid_{axis}_rate_{t}"].value for t in terms) for axis in ("roll", "pitch", "yaw")
    )


def test_the_training_sides_firmware_rate_model_is_the_same_firmware():
    """``env.quad.rate_model: firmware`` keeps its own copy too (it is not the simulated vehicle's)."""
    from datt.sim import firmware_rates as fr

    assert fr.ATTITUDE_RATE_HZ == FACTS["attitude_rate_hz"].value
    assert (fr.ARM_LENGTH_M, fr.THRUST2TORQUE_M) == (FACTS["arm_length_m"].value, FACTS["thrust2torque_m"].value)
    assert (fr.THRUST_MAX_N, fr.THRUST_MIN_N) == (FACTS["thrust_max_n"].value, FACTS["thrust_min_n"].value)
    assert fr.INERTIA_KGM2 == tuple(FACTS[f"inertia_{a}_kgm2"].value for a in "xyz")
    terms = ("kp", "ki", "kd", "integration_limit")
    assert fr.RATE_PID_GAINS == tuple(
        tuple(FACTS[f"pid_{axis}_rate_{t}"].value for t in terms) for axis in ("roll", "pitch", "yaw")
    )


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
