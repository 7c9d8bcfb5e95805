"""The simulated Crazyflie below its commander: the firmware's rate loop, motor mixing and motors
driving a rigid body, in place of the training simulator's rate model (so a policy meets a
vehicle whose rotational dynamics it never trained on, as it will on the real one).

Read from crazyflie-firmware 2026.08:

* **rate loop** (``controller_pid.c`` in rate mode, ``attitude_pid_controller.c``,
  ``utils/src/pid.c``; gains ``platform_defaults_cf2.h``): one PID per body axis at
  ``ATTITUDE_RATE`` (500 Hz) on the rate error in deg/s, the derivative on the measurement, the
  integral clamped to its limit, each output saturated to int16; thrust 0 resets the loop and
  stops the motors;
* **mixing** (``power_distribution_quadrotor.c``, legacy mode): each motor gets the thrust command
  plus or minus half the roll and pitch outputs and plus or minus the yaw output;
  ``powerDistributionCap`` lowers every motor by the highest one's excess over ``UINT16_MAX`` (the
  attitude keeps priority over the thrust) and holds each at the idle thrust (0) or above;
* **motors** (:mod:`datt.deploy.sim.motors`): each motor's command becomes its own force (off under
  ``THRUST_MIN``, capped by the battery, the vehicle's motor gain); the force follows the command
  with a first-order lag (``motor_time_constant_s``: an estimate of the motors' spin-up, not a
  firmware number);
* **body**: the X frame of ``platform_defaults_cf2.h`` (``ARM_LENGTH`` from the centre to a
  motor, ``THRUST2TORQUE`` of the propellers) and the inertia of ``controller_lee.c``: the numbers
  of the vehicle preset (``deploy.vehicle``, :mod:`datt.sim.vehicles`), as are the rate PID gains.

Frames: body rates and torques are body-frame FLU (x forward, y left, z up); the firmware's own
pitch sign (``-gyro.y``, the commander's inverted pitch) cancels out, so positive outputs here are
positive torques about the body axes. Motors M1..M4 sit front-right, back-right, back-left,
front-left; M2 and M4 spin so that their drag turns the body about +z.
"""

from __future__ import annotations

import math

from datt.deploy.sim.motors import UINT16_MAX, FirmwareMotors
from datt.sim.vehicles import CF21, Vehicle

INT16_MAX = 32767
ATTITUDE_RATE_HZ = 500  # stabilizer.h: ATTITUDE_RATE
# legacy mixing (power_distribution_quadrotor.c) in body torque terms: the sign each motor's
# command takes from the roll, pitch and yaw outputs that turn the body about +x, +y and +z
MIX_ROLL = (-0.5, -0.5, 0.5, 0.5)  # M3, M4 on the left (+y) lift to roll about +x
MIX_PITCH = (-0.5, 0.5, 0.5, -0.5)  # positive about +y (nose down): the back motors M2, M3 lift
MIX_YAW = (-1.0, 1.0, -1.0, 1.0)
MOTOR_XY = ((1, -1), (-1, -1), (-1, 1), (1, 1))  # each motor's (x, y) on the X frame, in arm / sqrt 2


class PidAxis:
    """``pidUpdate`` of the firmware for one rate axis (deg/s in, int16 command units out)."""

    def __init__(self, kp: float, ki: float, kd: float, i_limit: float, dt_s: float) -> None:
        self.kp, self.ki, self.kd, self.i_limit, self.dt_s = kp, ki, kd, i_limit, dt_s
        self.reset()

    def reset(self, measured_dps: float = 0.0) -> None:
        self.integ = 0.0
        self.prev_measured = measured_dps

    def update(self, desired_dps: float, measured_dps: float) -> int:
        error = desired_dps - measured_dps
        deriv = -(measured_dps - self.prev_measured) / self.dt_s  # on the measurement: no kick
        self.integ = max(-self.i_limit, min(self.i_limit, self.integ + error * self.dt_s))
        self.prev_measured = measured_dps
        out = self.kp * error + self.kd * deriv + self.ki * self.integ
        return int(max(-INT16_MAX - 1, min(INT16_MAX, out)))  # saturateSignedInt16 (truncates)


def mix_and_cap(thrust_cmd: float, roll: int, pitch: int, yaw: int) -> list[float]:
    """The four motor commands (uint16 units) of ``powerDistributionLegacy`` then
    ``powerDistributionCap``: lowered together by the largest one's excess, floored at 0."""
    motors = [thrust_cmd + MIX_ROLL[i] * roll + MIX_PITCH[i] * pitch + MIX_YAW[i] * yaw for i in range(4)]
    excess = max(0.0, max(motors) - UINT16_MAX)
    return [max(0.0, m - excess) for m in motors]


def body_torques_nm(forces_n: list[float], vehicle: Vehicle = CF21) -> tuple[float, float, float]:
    """Torques about body x, y, z of the four rotor forces on ``vehicle``'s X frame."""
    arm = vehicle.arm_length_m / math.sqrt(2.0)
    tx = sum(MOTOR_XY[i][1] * arm * f for i, f in enumerate(forces_n))
    ty = -sum(MOTOR_XY[i][0] * arm * f for i, f in enumerate(forces_n))
    tz = sum(MIX_YAW[i] * vehicle.thrust2torque_m * f for i, f in enumerate(forces_n))
    return tx, ty, tz


class Stabilizer:
    """Rate loop, mixing, motors and rotational dynamics of one vehicle, advanced in 2 ms ticks.

    :meth:`tick` takes the rate setpoint (body rad/s) and the commander's thrust command (uint16
    units) and returns the collective rotor force (N) for the caller's translational step;
    ``rate_radps`` holds the body rates after it."""

    def __init__(self, motors: FirmwareMotors, motor_time_constant_s: float = 0.03) -> None:
        self.motors = motors
        self.vehicle = motors.vehicle  # gains, frame and inertia of the motors' preset
        self.motor_time_constant_s = motor_time_constant_s
        self.tick_s = 1.0 / ATTITUDE_RATE_HZ
        self.pids = [PidAxis(*gains, self.tick_s) for gains in self.vehicle.rate_pid]
        self.rate_radps = [0.0, 0.0, 0.0]
        self.forces_n = [0.0, 0.0, 0.0, 0.0]
        self.motor_cmds = [0.0, 0.0, 0.0, 0.0]  # the last tick's capped commands (uint16 units)

    def reset(self, rate_radps: list[float] | None = None) -> None:
        self.rate_radps = list(rate_radps or [0.0, 0.0, 0.0])
        self.forces_n = [0.0] * 4
        self._reset_pids()

    def _reset_pids(self) -> None:
        """``controllerPidReinitialize``: integrals cleared, derivatives from the current rates."""
        for pid, w in zip(self.pids, self.rate_radps):
            pid.reset(math.degrees(w))

    def tick(self, rate_sp_radps: tuple[float, float, float], thrust_cmd: float, battery_v: float) -> float:
        """One 2 ms stabilizer tick; returns the collective rotor force (N) over it."""
        if thrust_cmd <= 0:  # controller_pid.c: thrust 0 zeroes the outputs and resets the loop
            self._reset_pids()
            self.motor_cmds = [0.0] * 4
        else:
            roll, pitch, yaw = (
                pid.update(math.degrees(sp), math.degrees(w))
                for pid, sp, w in zip(self.pids, rate_sp_radps, self.rate_radps)
            )
            self.motor_cmds = mix_and_cap(float(thrust_cmd), roll, pitch, yaw)
        target = [self.motors.motor_force_n(int(c), battery_v) for c in self.motor_cmds]
        tau = self.motor_time_constant_s
        blend = 1.0 if tau <= 0 else 1.0 - math.exp(-self.tick_s / tau)
        self.forces_n = [f + blend * (t - f) for f, t in zip(self.forces_n, target)]
        self._rotate(body_torques_nm(self.forces_n, self.vehicle))
        return sum(self.forces_n)

    def _rotate(self, torque_nm: tuple[float, float, float]) -> None:
        """Euler's equations, J dw/dt = tau - w x (J w), over one tick."""
        w = self.rate_radps
        inertia = self.vehicle.inertia_kgm2
        jw = [inertia[i] * w[i] for i in range(3)]
        gyro = (w[1] * jw[2] - w[2] * jw[1], w[2] * jw[0] - w[0] * jw[2], w[0] * jw[1] - w[1] * jw[0])
        self.rate_radps = [w[i] + self.tick_s * (torque_nm[i] - gyro[i]) / inertia[i] for i in range(3)]
