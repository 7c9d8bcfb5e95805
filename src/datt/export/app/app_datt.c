/* The DATT policy as a Crazyflie app (datt.export.app; docs/onboard.md). Built out of tree
   against crazyflie-firmware with CONFIG_APP_ENABLE and CONFIG_CONTROLLER_OOT (app-config).

   - appMain, a low-priority task, runs the policy and L1 (datt_onboard_step) every 20 ms on the
     latest state estimate and pushes a rate setpoint (thrust + body rates) to the commander at
     COMMANDER_PRIORITY_EXTRX: the firmware's PID rate controller flies it, and the commander's
     watchdog (supervisor.c: 2 s without a setpoint locks the vehicle) is fed onboard, so a lost
     radio does not stop the flight.
   - controllerOutOfTree (stabilizer.controller = ControllerTypeOot, published as the read-only
     parameter datt.controllerId, which the host selects and verifies) hands each stabilizer
     tick's state estimate to the task and runs the firmware's PID controller unchanged (the
     policy is far too slow for the stabilizer loop; it lives in the task). The task starts only
     on a state the hook wrote within DATT_STATE_MAX_AGE_MS that is sane (finite, unit
     quaternion), and pushes no setpoint on a stale one, so the commander's watchdog takes over.
   - The host uploads the reference table through the app channel (datt_onboard.h: packet
     layout, one acknowledgement per packet), sets the datt.* parameters and starts the flight
     with datt.run = 1 (datt.run = 0 stops it and hands the commander back). */
#include <stdbool.h>
#include <stdint.h>
#include <string.h>

#include "FreeRTOS.h"
#include "app.h"
#include "app_channel.h"
#include "commander.h"
#include "controller.h"
#include "controller_pid.h"
#include "log.h"
#include "param.h"
#include "stabilizer_types.h"
#include "task.h"

#define DEBUG_MODULE "DATT"
#include "debug.h"

#include "datt_onboard.h"

static datt_onboard onboard;
static uint8_t run_request;    /* param datt.run */
static uint8_t self_test_ok;   /* log datt.selfTest: the embedded golden case passed at boot */
static uint32_t policy_id = DATT_POLICY_ID; /* param datt.policyId (read-only): the host checks it */
static uint8_t controller_id = ControllerTypeOot; /* param datt.controllerId (read-only): the host selects it */
static state_t latest_state;   /* written by the stabilizer task, read by appMain */
static TickType_t latest_state_tick; /* when the hook last wrote latest_state */
static uint8_t state_written;  /* the hook has run at least once */
static logVarId_t var_px, var_py; /* the Kalman filter's position variances (kalman.varPX, varPY) */

void controllerOutOfTreeInit(void) { controllerPidInit(); }

bool controllerOutOfTreeTest(void) { return controllerPidTest(); }

void controllerOutOfTree(control_t *control, const setpoint_t *setpoint, const sensorData_t *sensors,
                         const state_t *state, const stabilizerStep_t stabilizerStep) {
    taskENTER_CRITICAL();
    latest_state = *state;
    latest_state_tick = xTaskGetTickCount();
    state_written = 1;
    taskEXIT_CRITICAL();
    controllerPid(control, setpoint, sensors, state, stabilizerStep);
}

/* The hook's latest state; returns 1 if the hook wrote it within DATT_STATE_MAX_AGE_MS. */
static int read_state(float pos[3], float vel[3], float quat[4]) {
    state_t s;
    TickType_t written;
    uint8_t ever;
    taskENTER_CRITICAL();
    s = latest_state;
    written = latest_state_tick;
    ever = state_written;
    taskEXIT_CRITICAL();
    pos[0] = s.position.x;
    pos[1] = s.position.y;
    pos[2] = s.position.z;
    vel[0] = s.velocity.x;
    vel[1] = s.velocity.y;
    vel[2] = s.velocity.z;
    quat[0] = s.attitudeQuaternion.w;
    quat[1] = s.attitudeQuaternion.x;
    quat[2] = s.attitudeQuaternion.y;
    quat[3] = s.attitudeQuaternion.z;
    return ever && (xTaskGetTickCount() - written) <= M2T(DATT_STATE_MAX_AGE_MS);
}

/* The larger of the Kalman filter's horizontal position variances, m^2 (huge when the Kalman
   filter is not running: its position is then unknown). */
static float position_var_m2(void) {
    if (!logVarIdIsValid(var_px) || !logVarIdIsValid(var_py)) return 1e6f;
    float vx = logGetFloat(var_px), vy = logGetFloat(var_py);
    return vx > vy ? vx : vy;
}

static void push_setpoint(const datt_setpoint *sp) {
    setpoint_t s;
    memset(&s, 0, sizeof s); /* all modes disabled, thrust 0: the stop setpoint */
    if (!sp->stop) {
        s.mode.x = modeDisable;
        s.mode.y = modeDisable;
        s.mode.z = modeDisable; /* thrust as given */
        s.thrust = (float)sp->thrust;
        s.mode.roll = modeVelocity;
        s.mode.pitch = modeVelocity;
        s.mode.yaw = modeVelocity;
        s.attitudeRate.roll = sp->roll_degps;
        s.attitudeRate.pitch = sp->pitch_degps;
        s.attitudeRate.yaw = sp->yaw_degps;
    }
    commanderSetSetpoint(&s, COMMANDER_PRIORITY_EXTRX);
}

static void receive_packets(void) {
    uint8_t rx[APPCHANNEL_MTU], reply[4];
    size_t n;
    while ((n = appchannelReceiveDataPacket(rx, sizeof rx, 0)) > 0) {
        int len = datt_onboard_receive(&onboard, rx, (int)n, reply);
        appchannelSendDataPacketBlock(reply, (size_t)len);
    }
}

void appMain(void) {
    const TickType_t period = M2T((uint32_t)(DATT_DT_S * 1000.0f + 0.5f));
    TickType_t wake;
    float err = 0.0f, pos[3], vel[3], quat[4];
    int fresh;
    datt_setpoint sp;

    datt_onboard_init(&onboard);
    var_px = logGetVarId("kalman", "varPX");
    var_py = logGetVarId("kalman", "varPY");
    self_test_ok = datt_self_test(&err) == 0;
    DEBUG_PRINT("self-test %s (max error %f)\n", self_test_ok ? "passed" : "FAILED", (double)err);
    wake = xTaskGetTickCount();
    while (1) {
        receive_packets();
        fresh = read_state(pos, vel, quat);
        if (run_request && onboard.phase == DATT_IDLE) {
            if (!self_test_ok || !fresh) datt_onboard_refuse(&onboard); /* no hook: not the OOT controller */
            if (onboard.phase == DATT_REFUSED || datt_onboard_start(&onboard, pos, vel, quat) != DATT_TRACK) {
                DEBUG_PRINT("start refused (table %u of %u points, self-test %u)\n", onboard.n_received,
                            onboard.p.n_points, self_test_ok);
            }
        } else if (!run_request && onboard.phase != DATT_IDLE) {
            datt_onboard_stop(&onboard);
            commanderRelaxPriority(); /* the radio's setpoints fly the vehicle again */
        }
        if (fresh || onboard.phase == DATT_IDLE) {
            datt_onboard_step(&onboard, pos, vel, quat, position_var_m2(), &sp);
            if (sp.active) push_setpoint(&sp);
        } /* stale: no setpoint, the commander's watchdog levels the vehicle, then stops it */
        vTaskDelayUntil(&wake, period);
    }
}

/* The host's handles (docs/onboard.md): parameters set before datt.run = 1. */
PARAM_GROUP_START(datt)
PARAM_ADD(PARAM_UINT8, run, &run_request)
PARAM_ADD(PARAM_UINT32 | PARAM_RONLY, policyId, &policy_id)
PARAM_ADD(PARAM_UINT8 | PARAM_RONLY, controllerId, &controller_id)
PARAM_ADD(PARAM_FLOAT, originX, &onboard.p.origin_m[0])
PARAM_ADD(PARAM_FLOAT, originY, &onboard.p.origin_m[1])
PARAM_ADD(PARAM_FLOAT, originZ, &onboard.p.origin_m[2])
PARAM_ADD(PARAM_UINT16, nPoints, &onboard.p.n_points)
PARAM_ADD(PARAM_UINT16, trackSteps, &onboard.p.track_steps)
PARAM_ADD(PARAM_FLOAT, landZ, &onboard.p.land_z_m)
PARAM_ADD(PARAM_FLOAT, landS, &onboard.p.land_s)
PARAM_ADD(PARAM_FLOAT, landHoldS, &onboard.p.land_hold_s)
PARAM_ADD(PARAM_FLOAT, hoverCmd, &onboard.p.hover_command)
PARAM_ADD(PARAM_FLOAT, slope, &onboard.p.slope_mps2_per_command)
PARAM_ADD(PARAM_UINT16, maxCmd, &onboard.p.max_command)
PARAM_ADD(PARAM_FLOAT, maxRateRoll, &onboard.p.max_rate_degps[0])
PARAM_ADD(PARAM_FLOAT, maxRatePitch, &onboard.p.max_rate_degps[1])
PARAM_ADD(PARAM_FLOAT, maxRateYaw, &onboard.p.max_rate_degps[2])
PARAM_ADD(PARAM_FLOAT, maxTiltDeg, &onboard.p.max_tilt_deg)
PARAM_ADD(PARAM_FLOAT, maxPosStdM, &onboard.p.max_pos_std_m)
PARAM_GROUP_STOP(datt)

LOG_GROUP_START(datt)
LOG_ADD(LOG_UINT8, phase, &onboard.phase)
LOG_ADD(LOG_UINT16, step, &onboard.step)
LOG_ADD(LOG_UINT16, nRx, &onboard.n_received)
LOG_ADD(LOG_FLOAT, errM, &onboard.error_m)
LOG_ADD(LOG_FLOAT, refX, &onboard.ref_m[0])
LOG_ADD(LOG_FLOAT, refY, &onboard.ref_m[1])
LOG_ADD(LOG_FLOAT, refZ, &onboard.ref_m[2])
LOG_ADD(LOG_UINT8, selfTest, &self_test_ok)
LOG_ADD(LOG_UINT8, landedEarly, &onboard.landed_early)
LOG_GROUP_STOP(datt)
