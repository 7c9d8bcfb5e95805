"""The vehicles a flight or a training run can mean, one preset each, every number with its source.

A preset is the truth about one kind of Crazyflie: its firmware's thrust map and motor fit, its
frame, its inertia, the rate loop that flies a rate setpoint on it, and the mass it flies with.
The simulated Crazyflie (:mod:`datt.deploy.sim`), the host's thrust map (``deploy.thrust``), the
training side's firmware rate model (:mod:`datt.sim.firmware_rates`) and the checks before TRACK
all read the preset named by ``deploy.vehicle`` / ``env.quad.vehicle``; nothing else types these
numbers.

Every firmware number carries a :class:`Source` (file in crazyflie-firmware, the rule that reads
it); :func:`datt.deploy.firmware.vehicle_facts` puts them into the firmware-facts table, which
``tests/deploy/test_firmware_table.py`` reads back from a firmware checkout. The two numbers the
firmware does not hold (the flying mass, the rate loop) cite where they come from instead.

* ``cf21``: a stock Crazyflie 2.1+ (2.1+ propellers, the firmware's default platform setup,
  ``CONFIG_CRAZYFLIE_21_PLUS``) with motion-capture markers; a rate setpoint is flown by the
  firmware's PID rate controller (``controller_pid.c``).
* ``cf21_upgrade``: the paper's vehicle (§5): the thrust upgrade kit
  (``CONFIG_CRAZYFLIE_THRUST_UPGRADE_KIT``), 40 g as flown, and the authors' custom PI rate
  controller, which the training simulator's first-order rate response approximates
  (``pi_first_order``).

Not shipped: ``cf21_brushless``. Its firmware (``platform_defaults_cf21bl.h``) publishes thrust,
mass, arm and rate gains but no inertia, and a guessed inertia would make the simulated vehicle
kinder or harsher than the real one in a way no test could catch.
"""

from __future__ import annotations

from dataclasses import dataclass, field

RATE_LOOPS = ("firmware", "pi_first_order")
PLATFORM_CF2 = "src/platform/interface/platform_defaults_cf2.h"
CONTROLLER_LEE = "src/modules/src/controller/controller_lee.c"
RPYT = "src/modules/src/crtp_commander_rpyt.c"


@dataclass(frozen=True)
class Source:
    """Where a number comes from. Firmware: ``file`` inside crazyflie-firmware and the rule of
    :func:`datt.deploy.firmware.read_fact` (``rule``, ``where``) that finds it. Elsewhere: ``file``
    names the document (the paper, an assumption of this project) and ``rule`` is ``"cited"``."""

    file: str
    rule: str
    where: str = ""


def _branch(option: str, macro: str) -> Source:
    """``#define macro`` inside the ``#if`` branch that names ``option`` (``!option``: its ``#else``)."""
    return Source(PLATFORM_CF2, "branch", f"{option}:{macro}")


def _lee_inertia(axis: int) -> Source:
    return Source(CONTROLLER_LEE, "regex", r"\.J = \{" + r"[-+.\de]+, " * axis + r"([-+.\de]+)")


_PID_TERMS = ("KP", "KI", "KD", "INTEGRATION_LIMIT")
# platform_defaults_cf2.h: kp, ki, kd, integration limit of the roll, pitch and yaw rate PIDs (both presets)
_CF2_RATE_PID = ((250.0, 500.0, 2.5, 33.3), (250.0, 500.0, 2.5, 33.3), (120.0, 16.7, 0.0, 166.7))
_CF2_INERTIA = (16.571710e-6, 16.655602e-6, 29.261652e-6)


@dataclass(frozen=True)
class Vehicle:
    """One preset. Units: N per motor, m, kg, kg m²; ``vmotor2thrust`` the cubic of motor force (N)
    against motor volts (``motors.c``); ``rate_pid`` ``(kp, ki, kd, integration limit)`` per body
    axis roll, pitch, yaw, on deg/s; ``max_command`` the off-board setpoint's ceiling (the legacy
    commander's ``MAX_THRUST``)."""

    name: str
    description: str
    platform_option: str  # the firmware's Kconfig choice of platform setup
    thrust_max_n: float
    thrust_min_n: float
    thrust2torque_m: float
    vmotor2thrust: tuple[float, float, float, float]
    firmware_mass_kg: float  # CF_MASS (used by the firmware only in Mellinger, Brescianini, Lee)
    mass_kg: float  # what it flies with
    rate_loop: str  # firmware | pi_first_order
    arm_length_m: float = 0.046
    inertia_kgm2: tuple[float, float, float] = _CF2_INERTIA
    rate_pid: tuple[tuple[float, float, float, float], ...] = _CF2_RATE_PID
    max_command: int = 60000
    sources: dict[str, Source] = field(default_factory=dict, compare=False, repr=False)

    def ceiling_mps2(self, max_command: int | None = None, mass_kg: float | None = None) -> float:
        """The collective thrust (m/s²) at ``max_command`` (default: the preset's) on ``mass_kg``
        (default: the flying mass), with the firmware's linear map."""
        command = self.max_command if max_command is None else max_command
        return 4.0 * self.thrust_max_n * command / 65535 / (self.mass_kg if mass_kg is None else mass_kg)

    def thrust_to_weight(self, gravity_mps2: float = 9.81) -> float:
        """Full thrust (every motor at THRUST_MAX) over the flying weight."""
        return 4.0 * self.thrust_max_n / (self.mass_kg * gravity_mps2)


def _sources(option: str) -> dict[str, Source]:
    """The firmware sources of a CF2-platform preset whose setup is ``option``."""
    out = {
        "thrust_max_n": _branch(option, "THRUST_MAX"),
        "thrust_min_n": _branch(option, "THRUST_MIN"),
        "thrust2torque_m": _branch(option, "THRUST2TORQUE"),
        "arm_length_m": Source(PLATFORM_CF2, "define", "ARM_LENGTH"),
        "max_command": Source(RPYT, "define", "MAX_THRUST"),
    }
    out.update({f"vmotor2thrust[{i}]": _branch(option, f"VMOTOR2THRUST{i}") for i in range(4)})
    out.update({f"inertia_kgm2[{i}]": _lee_inertia(i) for i in range(3)})
    for i, axis in enumerate(("ROLL", "PITCH", "YAW")):
        out.update(
            {
                f"rate_pid[{i}][{j}]": Source(PLATFORM_CF2, "define", f"PID_{axis}_RATE_{t}")
                for j, t in enumerate(_PID_TERMS)
            }
        )
    return out


CF21 = Vehicle(
    name="cf21",
    description="stock Crazyflie 2.1+ (2.1+ propellers), markers; the firmware's PID rate loop",
    platform_option="CONFIG_CRAZYFLIE_21_PLUS",
    thrust_max_n=0.12,
    thrust_min_n=0.012817578393224994,
    thrust2torque_m=0.0069928948992470565,
    vmotor2thrust=(-0.02476537915958403, 0.06523793527519485, -0.026792504967750107, 0.006776789303971145),
    firmware_mass_kg=0.029,
    mass_kg=0.034,
    rate_loop="firmware",
    sources={
        **_sources("CONFIG_CRAZYFLIE_21_PLUS"),
        "firmware_mass_kg": _branch("!CONFIG_CRAZYFLIE_THRUST_UPGRADE_KIT", "CF_MASS"),
        # CF_MASS 29 g + ~5 g of markers and their mount (this project's default since it began)
        "mass_kg": Source("assumption: CF_MASS 0.029 kg + 5 g of motion-capture markers", "cited"),
        "rate_loop": Source("src/modules/src/controller/controller_pid.c (rate mode)", "cited"),
    },
)

CF21_UPGRADE = Vehicle(
    name="cf21_upgrade",
    description="the paper's vehicle: thrust upgrade kit, 40 g, the authors' custom PI rate loop",
    platform_option="CONFIG_CRAZYFLIE_THRUST_UPGRADE_KIT",
    thrust_max_n=0.18,
    thrust_min_n=0.01922636758983749,
    thrust2torque_m=0.0051648627905205285,
    vmotor2thrust=(0.006728127583707208, 0.01011557616217668, 0.010263198062061085, 0.0028358638322392503),
    firmware_mass_kg=0.0325,
    mass_kg=0.040,
    rate_loop="pi_first_order",
    sources={
        **_sources("CONFIG_CRAZYFLIE_THRUST_UPGRADE_KIT"),
        "firmware_mass_kg": _branch("CONFIG_CRAZYFLIE_THRUST_UPGRADE_KIT", "CF_MASS"),
        "mass_kg": Source("paper §5: 'the quadrotor as tested weighs 40 g'", "cited"),
        "rate_loop": Source("paper §5: 'a custom low-level PI attitude rate controller'", "cited"),
    },
)

VEHICLES: dict[str, Vehicle] = {v.name: v for v in (CF21, CF21_UPGRADE)}
DEFAULT_VEHICLE = "cf21"


def vehicle(name: str) -> Vehicle:
    """The preset ``name`` (a ConfigError names the presets there are)."""
    if name not in VEHICLES:
        from datt.errors import ConfigError

        raise ConfigError(f"vehicle: unknown preset {name!r}; allowed: {', '.join(VEHICLES)}")
    return VEHICLES[name]


def number(v: Vehicle, key: str) -> float | int | str:
    """The value behind a source key of :attr:`Vehicle.sources` (``inertia_kgm2[0]``,
    ``rate_pid[2][1]`` index into tuples)."""
    name, _, rest = key.partition("[")
    value = getattr(v, name)
    for index in rest.replace("]", "").split("[") if rest else []:
        value = value[int(index)]
    return value
