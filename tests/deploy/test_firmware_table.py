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
