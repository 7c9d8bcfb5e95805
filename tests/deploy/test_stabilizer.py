"""The simulated Crazyflie below its commander (datt.deploy.sim.stabilizer): the firmware's rate
PIDs, legacy mixing with the cap, per-motor forces and the rigid body, against their definitions."""

import math

import pytest
import torch

from datt.deploy.sim.motors import UINT16_MAX, FirmwareMotors, MotorParams
from datt.deploy.sim.server import SimCrazyflie, SimCrazyflieParams, check_server_settings
from datt.deploy.sim.stabilizer import PidAxis, Stabilizer, body_torques_nm, mix_and_cap
from datt.errors import ConfigError
from datt.sim.vehicles import CF21

ARM_LENGTH_M, INERTIA_KGM2, THRUST2TORQUE_M = CF21.arm_length_m, CF21.inertia_kgm2, CF21.thrust2torque_m

MASS_KG = 0.034


def stabilizer(tau_s=0.03):
    return Stabilizer(FirmwareMotors(MotorParams(mass_kg=MASS_KG)), tau_s)


def test_legacy_mixing_splits_roll_and_pitch_in_halves_and_yaw_whole():
    assert mix_and_cap(30000, 0, 0, 0) == [30000] * 4
    assert mix_and_cap(30000, 1000, 0, 0) == [29500, 29500, 30500, 30500]  # M3, M4 (left) up
    assert mix_and_cap(30000, 0, 1000, 0) == [29500, 30500, 30500, 29500]  # M2, M3 (back) up
    assert mix_and_cap(30000, 0, 0, 1000) == [29000, 31000, 29000, 31000]  # M2, M4 up


def test_the_cap_lowers_every_motor_by_the_largest_excess_and_floors_at_zero():
    """powerDistributionCap: the attitude's differences survive, the collective pays."""
    capped = mix_and_cap(60000, 20000, 0, 0)
    assert max(capped) == UINT16_MAX
    assert capped == [50000 - 4465, 50000 - 4465, UINT16_MAX, UINT16_MAX]
    assert capped[2] - capped[0] == 20000  # the roll difference kept
    assert mix_and_cap(1000, 0, 0, 4000) == [0, 5000, 0, 5000]  # no negative command


def test_the_x_frame_turns_each_motors_force_into_its_torques():
    arm = ARM_LENGTH_M / math.sqrt(2)
    assert body_torques_nm([0.1] * 4) == pytest.approx((0.0, 0.0, 0.0), abs=1e-15)
    # one motor at a time: M1 front-right, M2 back-right, M3 back-left, M4 front-left
    expected = [(-arm, -arm, -THRUST2TORQUE_M), (-arm, arm, THRUST2TORQUE_M), (arm, arm, -THRUST2TORQUE_M)]
    expected.append((arm, -arm, THRUST2TORQUE_M))
    for i, (tx, ty, tz) in enumerate(expected):
        forces = [0.0] * 4
        forces[i] = 1.0
        assert body_torques_nm(forces) == pytest.approx((tx, ty, tz))


def test_the_pid_differentiates_the_measurement_and_clamps_its_integral():
    pid = PidAxis(kp=2.0, ki=10.0, kd=0.5, i_limit=0.3, dt_s=0.01)
    # a setpoint step: no derivative kick (the measurement did not move)
    assert pid.update(100.0, 0.0) == int(2.0 * 100 + 10.0 * 0.3)  # the integral 1.0 clamped at 0.3
    # the measurement moves by 5 in one tick: D = -kd * 5 / dt
    assert pid.update(100.0, 5.0) == int(2.0 * 95 - 0.5 * 5 / 0.01 + 10.0 * 0.3)
    assert PidAxis(1e6, 0, 0, 0, 0.01).update(1.0, 0.0) == 32767  # int16 saturation
    assert PidAxis(1e6, 0, 0, 0, 0.01).update(-1.0, 0.0) == -32768


@pytest.mark.parametrize("axis, rise_s", [(0, 0.05), (1, 0.05), (2, 0.2)], ids=["roll", "pitch", "yaw"])
def test_a_rate_step_is_tracked_on_its_own_axis(axis, rise_s):
    """Roll and pitch reach 90 % of a 1 rad/s step within 50 ms, yaw (drag torque only) within
    0.2 s; the PI loop overshoots by less than 20 % and settles to 2 % within a second."""
    stab = stabilizer()
    hover = FirmwareMotors(MotorParams(mass_kg=MASS_KG)).command_for_mps2(9.81)
    setpoint = [0.0, 0.0, 0.0]
    for _ in range(100):  # 0.2 s of hover: motors spun up, loop settled
        stab.tick(tuple(setpoint), hover, 4.1)
    setpoint[axis] = 1.0
    trace = []
    for _ in range(500):  # 1 s
        stab.tick(tuple(setpoint), hover, 4.1)
        trace.append(list(stab.rate_radps))
    rise_ticks = round(rise_s / stab.tick_s)
    assert trace[rise_ticks - 1][axis] >= 0.9 and trace[2][axis] < 0.5  # fast, not instant
    assert max(t[axis] for t in trace) < 1.2
    assert trace[-1][axis] == pytest.approx(1.0, abs=0.02)
    others = [i for i in range(3) if i != axis]
    assert max(abs(t[i]) for t in trace for i in others) < 1e-3  # no coupling at these rates


def test_near_full_thrust_a_hard_roll_takes_its_torque_from_the_collective():
    """The cap keeps the attitude: at 60000 a saturated roll demand lowers the total force, at
    30000 it does not (the mixing then has room above every motor)."""
    for thrust, loses in ((60000, True), (30000, False)):
        stab = stabilizer(tau_s=0.0)
        level = stab.tick((0.0, 0.0, 0.0), thrust, 4.1)
        stab.reset()
        rolled = stab.tick((20.0, 0.0, 0.0), thrust, 4.1)
        assert (rolled < level - 1e-3) is loses, (thrust, level, rolled)


def test_under_thrust_min_a_motor_stops_so_a_small_differential_gives_no_torque_from_it():
    motors = FirmwareMotors(MotorParams(mass_kg=MASS_KG))
    just_under = int(motors.p.thrust_min_n / motors.p.thrust_max_n * UINT16_MAX) - 1
    assert motors.motor_force_n(just_under, 4.1) == 0.0
    stab = Stabilizer(motors, 0.0)
    stab.tick((5.0, 0.0, 0.0), just_under, 4.1)
    assert stab.forces_n[0] == stab.forces_n[1] == 0.0  # the lowered right motors are off
    assert stab.forces_n[2] > 0.0


def test_thrust_zero_stops_the_motors_and_resets_the_loop():
    stab = stabilizer(tau_s=0.0)
    for _ in range(20):
        stab.tick((3.0, 0.0, 0.0), 30000, 4.1)
    assert stab.pids[0].integ != 0.0
    assert stab.tick((3.0, 0.0, 0.0), 0, 4.1) == 0.0
    assert stab.motor_cmds == [0.0] * 4 and stab.pids[0].integ == 0.0


def test_euler_equations_keep_a_torque_free_spin_about_a_principal_axis():
    stab = stabilizer()
    stab.rate_radps = [0.0, 0.0, 5.0]
    stab._rotate((0.0, 0.0, 0.0))
    assert stab.rate_radps == [0.0, 0.0, 5.0]
    stab.rate_radps = [1.0, 0.0, 5.0]  # off-axis: w x Jw turns the x rate into y
    stab._rotate((0.0, 0.0, 0.0))
    jx, jy, jz = INERTIA_KGM2
    # dw_y/dt = -(w x Jw)_y / J_y = -(w_z J_x w_x - w_x J_z w_z) / J_y
    assert stab.rate_radps[1] == pytest.approx(-stab.tick_s * (5.0 * jx - 5.0 * jz) / jy, rel=1e-9)


def test_the_simulated_vehicle_hovers_on_the_firmware_loop_at_the_hover_command():
    server = SimCrazyflie(SimCrazyflieParams(rate_loop="firmware", motors=MotorParams(mass_kg=MASS_KG)))
    server.armed = True
    server.quad.state.pos_m[0, 2] = 1.0
    hover = server.motors.command_for_mps2(9.81)
    vz = []
    for _ in range(100):  # 2 s
        server.cmd = (0.0, 0.0, 0.0, hover)
        server.last_setpoint_t = server.sim_time_s
        server._physics_step()
        vz.append(float(server.quad.state.vel_mps[0, 2]))
    s = server.quad.state
    assert vz[9] < -0.2  # the motors' spin-up from rest costs about g x their time constant
    assert vz[-1] == pytest.approx(vz[24], abs=0.005)  # then the thrust holds the weight
    assert torch.allclose(s.quat[0], torch.tensor([1.0, 0.0, 0.0, 0.0]), atol=1e-6)
    assert float(s.thrust_mps2[0]) == pytest.approx(9.81, rel=0.002)


def test_the_rate_loop_setting_is_checked():
    check_server_settings({"rate_loop": "pi_first_order", "motor_time_constant_s": 0.0})
    with pytest.raises(
        ConfigError,
        match=r"^deploy\.server\.rate_loop: unknown value 'pid'; allowed: firmware, pi_first_order, null$",
    ):
        check_server_settings({"rate_loop": "pid"})
    with pytest.raises(ConfigError, match=r"^deploy\.server\.motor_time_constant_s: "):
        check_server_settings({"motor_time_constant_s": -0.1})


@pytest.mark.parametrize("rate_loop", ["pi_first_order", "firmware"])
def test_a_position_hold_mode_holds_the_height_of_a_vehicle_with_weak_motors(rate_loop):
    """``flightmode.althold`` (as an earlier flight may leave it): the vehicle's own height loop
    stops a climb and holds, whatever its motors' gain against the firmware's map."""
    motors = MotorParams(mass_kg=MASS_KG, thrust_gain=0.9)
    server = SimCrazyflie(SimCrazyflieParams(rate_loop=rate_loop, motors=motors))
    server.params["flightmode.althold"] = 1
    server.armed = True
    server.quad.state.pos_m[0, 2] = 1.0
    server.quad.state.vel_mps[0, 2] = 0.5
    for _ in range(150):  # 3 s
        server.cmd = (0.0, 0.0, 0.0, 40000)
        server.last_setpoint_t = server.sim_time_s
        server._physics_step()
    s = server.quad.state
    assert float(s.vel_mps[0, 2]) == pytest.approx(0.0, abs=0.01) and 0.9 < float(s.pos_m[0, 2]) < 1.3


@pytest.mark.parametrize("name", ["refuse_arming", "log_before_step"])
@pytest.mark.parametrize("value", ["maybe", 1, None])
def test_every_switch_of_the_simulated_vehicle_takes_only_true_or_false(name, value):
    check_server_settings({name: True})
    check_server_settings({name: False})
    with pytest.raises(ConfigError, match=rf"^deploy.server.{name}: must be true or false, got {value!r}$"):
        check_server_settings({name: value})
