"""The Crazyflie firmware's numbers and names the host relies on, each with the file it was read
from (crazyflie-firmware, tag :data:`FIRMWARE_VERSION`). Nothing in the host types such a number
by hand: it takes it from :data:`FACTS`. ``tests/deploy/test_firmware_table.py`` reads every fact
back from a firmware checkout (``CRAZYFLIE_FIRMWARE=<dir>``), so a firmware that renumbers an enum
or renames a parameter fails a test instead of a flight.

A fact is located in its file by one of five rules (:func:`read_fact`):

* ``enum``: the position of a member in a ``typedef enum`` as the compiler counts it (explicit
  values, comments left out), the members behind ``#ifdef`` / ``#if defined`` / ``#ifndef`` /
  ``#else`` counted only as the options the build enables (:data:`BUILD_OPTIONS`) select them;
* ``define``: a ``#define`` (``M2T(...)`` and a float suffix stripped);
* ``branch``: a ``#define`` inside one branch of an ``#if`` chain, ``where`` = ``"OPTION:MACRO"``
  (the branch whose ``#if`` / ``#elif`` names ``OPTION``; ``"!OPTION:MACRO"``: that ``#if``'s ``#else``);
* ``regex``: the first group of a regular expression (a number, or the text for a text fact);
* ``param`` / ``log``: a parameter or log variable ``group.name`` declared in the file.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

from datt.sim.vehicles import VEHICLES, number

FIRMWARE_VERSION = "2026.08"
# Kconfig options of the builds this project flies: the DATT app (app-config) adds the
# out-of-tree controller; every Crazyflie 2.x build has the Kalman filter.
BUILD_OPTIONS = ("CONFIG_CONTROLLER_OOT", "CONFIG_ESTIMATOR_KALMAN_ENABLE")


@dataclass(frozen=True)
class Fact:
    value: int | float | str
    file: str  # path inside crazyflie-firmware
    rule: str  # enum | define | regex | param | log
    where: str  # enum: "Typedef.Member"; define: macro name; regex: pattern; param/log: unused


def vehicle_facts() -> dict[str, Fact]:
    """The firmware numbers of every vehicle preset (:data:`datt.sim.vehicles.VEHICLES`) as facts
    ``"<preset>.<field>"``, so the checkout test reads them back like every other fact."""
    return {
        f"{v.name}.{key}": Fact(number(v, key), src.file, src.rule, src.where)
        for v in VEHICLES.values()
        for key, src in v.sources.items()
        if src.rule != "cited"
    }


_CONTROLLER_H = "src/modules/interface/controller/controller.h"
_ESTIMATOR_H = "src/modules/interface/estimator/estimator.h"
_SUPERVISOR_H = "src/modules/interface/crtp_supervisor.h"
_SUPERVISOR_C = "src/modules/src/supervisor.c"
_RPYT_C = "src/modules/src/crtp_commander_rpyt.c"
_PID_C = "src/modules/src/controller/controller_pid.c"


def _bit(condition: str) -> str:
    """The bit of ``supervisor.info`` that ``supervisor.c`` sets under ``condition``."""
    return re.escape(condition) + r"\s*\)?\s*\{\s*this->infoBitfield \|= (0x[0-9a-fA-F]+);"


FACTS: dict[str, Fact] = {
    # stabilizer.controller: only PID and INDI (and the app's out-of-tree hook, which runs the PID)
    # fly roll/pitch-rate setpoints; Mellinger, Brescianini and Lee hold an attitude
    "controller_pid": Fact(1, _CONTROLLER_H, "enum", "ControllerType.ControllerTypePID"),
    "controller_mellinger": Fact(2, _CONTROLLER_H, "enum", "ControllerType.ControllerTypeMellinger"),
    "controller_indi": Fact(3, _CONTROLLER_H, "enum", "ControllerType.ControllerTypeINDI"),
    "controller_brescianini": Fact(4, _CONTROLLER_H, "enum", "ControllerType.ControllerTypeBrescianini"),
    "controller_lee": Fact(5, _CONTROLLER_H, "enum", "ControllerType.ControllerTypeLee"),
    "controller_oot": Fact(6, _CONTROLLER_H, "enum", "ControllerType.ControllerTypeOot"),
    # stabilizer.estimator
    "estimator_complementary": Fact(1, _ESTIMATOR_H, "enum", "StateEstimatorType.StateEstimatorTypeComplementary"),
    "estimator_kalman": Fact(2, _ESTIMATOR_H, "enum", "StateEstimatorType.StateEstimatorTypeKalman"),
    # the app channel: the firmware queues at most this many incoming packets; more are dropped
    "app_channel_rx_queue": Fact(
        10, "src/modules/src/app_channel.c", "regex", r"rxQueue = xQueueCreate\((\d+), sizeof\(CRTPPacket\)\)"
    ),
    "app_channel_mtu": Fact(30, "src/modules/interface/app_channel.h", "define", "APPCHANNEL_MTU"),
    # supervisor commands (port 9) and the state bitfield (supervisor.info)
    "supervisor_info_channel": Fact(0, _SUPERVISOR_H, "define", "SUPERVISOR_CH_INFO"),
    "supervisor_command_channel": Fact(1, _SUPERVISOR_H, "define", "SUPERVISOR_CH_COMMAND"),
    "supervisor_cmd_arm": Fact(0x01, _SUPERVISOR_H, "define", "CMD_ARM_SYSTEM"),
    "supervisor_cmd_get_state_bitfield": Fact(0x0C, _SUPERVISOR_H, "define", "CMD_GET_STATE_BITFIELD"),
    "supervisor_cmd_response": Fact(0x80, _SUPERVISOR_H, "define", "CMD_RESPONSE"),
    "supervisor_bit_can_be_armed": Fact(0x0001, _SUPERVISOR_C, "regex", _bit("if (supervisorCanArm()")),
    "supervisor_bit_armed": Fact(0x0002, _SUPERVISOR_C, "regex", _bit("if (supervisorIsArmed()")),
    "supervisor_bit_can_fly": Fact(0x0008, _SUPERVISOR_C, "regex", _bit("if (this->canFly")),
    "supervisor_bit_tumbled": Fact(0x0020, _SUPERVISOR_C, "regex", _bit("if (this->isTumbled")),
    "supervisor_bit_locked": Fact(0x0040, _SUPERVISOR_C, "regex", _bit("if (supervisorStateLocked == this->state")),
    "supervisor_bit_crashed": Fact(0x0080, _SUPERVISOR_C, "regex", _bit("if (this->isCrashed")),
    "supervisor_update_hz": Fact(
        25, "src/modules/interface/stabilizer_types.h", "regex", r"#define RATE_SUPERVISOR RATE_(\d+)_HZ"
    ),
    # watchdogs (ms)
    "setpoint_watchdog_level_ms": Fact(500, _SUPERVISOR_C, "define", "COMMANDER_WDT_TIMEOUT_STABILIZE"),
    "setpoint_watchdog_off_ms": Fact(2000, _SUPERVISOR_C, "define", "COMMANDER_WDT_TIMEOUT_SHUTDOWN"),
    "estop_watchdog_ms": Fact(1000, _SUPERVISOR_C, "define", "DEFAULT_EMERGENCY_STOP_WATCHDOG_TIMEOUT"),
    # the legacy commander (the off-board setpoints): a thrust under MIN_THRUST flies 0, above
    # MAX_THRUST it flies MAX_THRUST (the host's deploy.thrust.max_command is at most this)
    "rpyt_min_thrust": Fact(1000, _RPYT_C, "define", "MIN_THRUST"),
    "rpyt_max_thrust": Fact(60000, _RPYT_C, "define", "MAX_THRUST"),
    # the app's setpoints (commanderSetSetpoint, thrust as given) skip that clamp: the PID takes the
    # setpoint's thrust as is, and the power distribution lowers every motor by the highest one's
    # excess over UINT16_MAX (attitude first); the app's deploy.thrust.app_max_command is at most this
    "pid_thrust_from_setpoint": Fact("setpoint->thrust", _PID_C, "regex", r"actuatorThrust = (setpoint->thrust);"),
    "power_cap_max_thrust": Fact(
        "UINT16_MAX", "src/modules/src/power_distribution_quadrotor.c", "regex", r"maxAllowedThrust = (\w+);"
    ),
    # parameters the host sets, verifies and restores
    "param_controller": Fact("stabilizer.controller", "src/modules/src/stabilizer.c", "param", ""),
    "param_estimator": Fact("stabilizer.estimator", "src/modules/src/stabilizer.c", "param", ""),
    "param_stab_mode_roll": Fact("flightmode.stabModeRoll", _RPYT_C, "param", ""),
    "param_stab_mode_pitch": Fact("flightmode.stabModePitch", _RPYT_C, "param", ""),
    "param_althold": Fact("flightmode.althold", _RPYT_C, "param", ""),
    "param_poshold": Fact("flightmode.poshold", _RPYT_C, "param", ""),
    "param_posset": Fact("flightmode.posSet", _RPYT_C, "param", ""),
    "param_kalman_reset": Fact("kalman.resetEstimation", "src/modules/src/estimator/estimator_kalman.c", "param", ""),
    "log_supervisor_info": Fact("supervisor.info", _SUPERVISOR_C, "log", ""),
    # below the commander (the simulated vehicle's rate loop, datt.deploy.sim.stabilizer)
    "attitude_rate_hz": Fact(
        500, "src/modules/interface/stabilizer_types.h", "regex", r"#define ATTITUDE_RATE RATE_(\d+)_HZ"
    ),
    # the gyro's full scale as the firmware sets it up (deploy.safety.max_rate_radps stays inside it)
    "gyro_full_scale_dps": Fact(
        2000, "src/hal/src/sensors_bmi088_bmp3xx.c", "regex", r"SENSORS_BMI088_DEG_PER_LSB_CFG\s+\(2\.0f \*(\d+)\.0f\)"
    ),
    # a Crazyflie 2.x's battery thresholds: below the critical one the firmware shuts the vehicle
    # down; deploy.safety's battery limits stay above it
    "battery_low_v": Fact(3.2, "src/platform/interface/platform_defaults_cf2.h", "define", "DEFAULT_BAT_LOW_VOLTAGE"),
    "battery_critical_v": Fact(
        3.0, "src/platform/interface/platform_defaults_cf2.h", "define", "DEFAULT_BAT_CRITICAL_LOW_VOLTAGE"
    ),
    # each vehicle preset's numbers (datt.sim.vehicles): "<preset>.<field>"
    **vehicle_facts(),
}


def fact(name: str) -> int | float | str:
    """The value of fact ``name`` (a KeyError names a fact that is not in the table)."""
    return FACTS[name].value


# the names the host code uses
CONTROLLER_PID = int(fact("controller_pid"))
CONTROLLER_OOT = int(fact("controller_oot"))
RATE_CONTROLLERS = {int(fact("controller_pid")): "PID", int(fact("controller_indi")): "INDI"}
ESTIMATOR_KALMAN = int(fact("estimator_kalman"))
APP_CHANNEL_RX_QUEUE = int(fact("app_channel_rx_queue"))
SUPERVISOR_CMD_GET_STATE_BITFIELD = int(fact("supervisor_cmd_get_state_bitfield"))
SUPERVISOR_CMD_RESPONSE = int(fact("supervisor_cmd_response"))
SUPERVISOR_BIT_ARMED = int(fact("supervisor_bit_armed"))
SUPERVISOR_BIT_LOCKED = int(fact("supervisor_bit_locked"))
SUPERVISOR_BIT_CRASHED = int(fact("supervisor_bit_crashed"))
SUPERVISOR_BIT_TUMBLED = int(fact("supervisor_bit_tumbled"))
SUPERVISOR_PERIOD_S = 1.0 / float(fact("supervisor_update_hz"))


def _number(text: str) -> int | float:
    text = text.strip()
    while text.startswith("(") and text.endswith(")"):
        text = text[1:-1].strip()
    text = re.sub(r"^M2T\((.*)\)$", r"\1", text).strip("() ").rstrip("fFuU")
    try:
        return int(text, 0)
    except ValueError:
        return float(text)


def _enum_index(source: str, typedef: str, member: str, options: tuple[str, ...]) -> int | None:
    body = re.search(r"typedef enum\s*\{(.*?)\}\s*" + re.escape(typedef) + r"\s*;", source, re.S)
    if body is None:
        return None
    index, conditions = -1, []  # the #ifdef / #ifndef conditions around the current line
    members = re.sub(r"/\*.*?\*/", " ", body.group(1), flags=re.S)  # block comments are not code
    for line in members.splitlines():
        line = line.split("//")[0].strip()
        if line.startswith("#if"):  # #ifdef X, #if defined(X), #ifndef X, #if 0 / #if 1
            constant = re.fullmatch(r"#if\s+([01])", line)
            enabled = constant.group(1) == "1" if constant else any(opt in line for opt in options)
            conditions.append(not enabled if line.startswith("#ifndef") else enabled)
        elif line.startswith("#else"):
            conditions[-1] = not conditions[-1]
        elif line.startswith("#endif"):
            conditions.pop()
        elif line and not line.startswith("#") and all(conditions):
            name, _, value = line.rstrip(",").partition("=")
            index = int(value, 0) if value.strip() else index + 1
            if name.strip() == member:
                return index
    return None


def _branch_define(source: str, option: str, macro: str) -> str | None:
    """The text of ``#define macro`` in the branch of the ``#if`` / ``#elif`` that names ``option``
    (``!option``: the ``#else`` of the ``#if`` that names it), nested conditionals skipped; the
    first such branch that defines it."""
    negate = option.startswith("!")
    name = option.lstrip("!")
    lines = [line.strip() for line in source.splitlines()]
    for i, line in enumerate(lines):
        if not (line.startswith(("#if", "#elif")) and re.search(r"\b" + re.escape(name) + r"\b", line)):
            continue
        inside, depth = not negate, 0
        for text in lines[i + 1 :]:
            if text.startswith("#if"):
                depth += 1
            elif text.startswith("#endif"):
                if depth == 0:
                    break
                depth -= 1
            elif text.startswith(("#elif", "#else")) and depth == 0:
                if not negate:
                    break
                inside = text.startswith("#else")
            elif inside and depth == 0:
                found = re.match(r"#define\s+" + re.escape(macro) + r"\s+([^\n/]+)", text)
                if found:
                    return found.group(1)
    return None  # no branch naming option defines macro


def read_fact(root: str | Path, item: Fact, options: tuple[str, ...] = BUILD_OPTIONS) -> int | float | str | None:
    """The value ``item`` has in the firmware checkout at ``root`` (None: not found there)."""
    path = Path(root) / item.file
    if not path.is_file():
        return None
    source = path.read_text(errors="replace")
    if item.rule == "enum":
        typedef, member = item.where.split(".")
        return _enum_index(source, typedef, member, options)
    if item.rule == "define":
        found = re.search(r"#define\s+" + re.escape(item.where) + r"\s+([^\n/]+)", source)
        return None if found is None else _number(found.group(1))
    if item.rule == "branch":
        option, macro = item.where.split(":")
        found = _branch_define(source, option, macro)
        return None if found is None else _number(found)
    if item.rule == "regex":
        found = re.search(item.where, source)
        if found is None:
            return None
        return found.group(1) if isinstance(item.value, str) else _number(found.group(1))
    if item.rule in ("param", "log"):
        group, name = str(item.value).split(".")
        kind = "PARAM" if item.rule == "param" else "LOG"
        block = re.search(
            kind + r"_GROUP_START\(" + re.escape(group) + r"\)(.*?)" + kind + r"_GROUP_STOP", source, re.S
        )
        declared = block is not None and re.search(
            kind + r"_ADD\w*\([^,]+,\s*" + re.escape(name) + r"\s*,", block.group(1)
        )
        return item.value if declared else None
    raise ValueError(f"unknown rule {item.rule!r}")
