/* The DATT controller onboard (datt.export.app): the reference table, the 50 Hz step and the
   upload protocol. Firmware-independent C99: app_datt.c wires it into the Crazyflie firmware, and
   the simulated Crazyflie (datt.deploy.sim) calls the same code through ctypes. */
#ifndef DATT_ONBOARD_H
#define DATT_ONBOARD_H

#include <stdint.h>
#include "datt_policy.h"

#ifndef DATT_TABLE_MAX
#define DATT_TABLE_MAX 1024 /* reference points held onboard (12 bytes each): 20 s at 50 Hz */
#endif

#ifndef DATT_STATE_MAX_AGE_MS
#define DATT_STATE_MAX_AGE_MS 10 /* the controller hook's state older than this: no start, no setpoint */
#endif

/* phases (log datt.phase) */
#define DATT_IDLE 0      /* not flying: the commander's other setpoints (the radio's) fly the vehicle */
#define DATT_TRACK 1     /* the policy tracks the uploaded table */
#define DATT_LAND 2      /* the policy tracks a ramp down to land_z_m (from the table's end, or from
                            where it was when the position estimate grew too uncertain), then stops */
#define DATT_DONE 3      /* landed: motors stopped */
#define DATT_ABORTED 4   /* a check failed in flight (tilt, non-finite state or action): motors stopped */
#define DATT_REFUSED 5   /* start refused: the table is incomplete or the parameters are invalid */

/* app channel packets (CRTP port 13, channel 2; at most 31 bytes) */
#define DATT_PKT_POINTS 0x01 /* host -> vehicle: u8 kind, u16 index, u8 count (1..2), count * 3 float32 */
#define DATT_PKT_ACK 0x81    /* vehicle -> host: u8 kind, u16 index, u8 status */
#define DATT_ACK_OK 0
#define DATT_ACK_RANGE 1     /* index + count beyond DATT_TABLE_MAX */
#define DATT_ACK_BUSY 2      /* flying: the table cannot change */
#define DATT_ACK_MALFORMED 3

/* Parameters (firmware: the param group "datt"; set by the host before starting). All positions
   in the controller frame: the world (mocap) frame shifted to the hover point origin_m. */
typedef struct {
    float origin_m[3];       /* hover point in the world frame; the policy sees pos - origin_m */
    uint16_t n_points;       /* points uploaded: the track's table (track_steps + the window) */
    uint16_t track_steps;    /* steps flown on the table before the landing ramp */
    float land_z_m;          /* the ramp's end height (controller frame: ground + 5 cm = -origin_z + 0.05) */
    float land_s;            /* the ramp's duration; then land_hold_s at land_z_m, then motors off */
    float land_hold_s;
    float hover_command;     /* the thrust map: command = hover + (thrust - g) / slope, clipped */
    float slope_mps2_per_command;
    uint16_t max_command;
    float max_rate_degps[3]; /* roll, pitch, yaw limits on the sent rates */
    float max_tilt_deg;      /* larger tilt in flight: abort (motors off) */
    float max_pos_std_m;     /* the estimate's horizontal position std above this (no measurements
                                for a while: a lost mocap stream): land now from the current
                                reference point; 0 = never */
} datt_onboard_params;

/* The rate setpoint for the firmware's commander, in its own convention (setpoint_t):
   attitudeRate roll, pitch, yaw in deg/s (roll = wx, pitch = -wy, yaw = wz for the body rates
   wx, wy, wz), thrust as the motor command; stop = 1: a stop setpoint (motors off). */
typedef struct {
    float roll_degps, pitch_degps, yaw_degps;
    uint16_t thrust;
    uint8_t stop;
    uint8_t active;          /* 1: push this setpoint at the app's priority; 0: leave the commander alone */
} datt_setpoint;

typedef struct {
    datt_onboard_params p;
    float table[DATT_TABLE_MAX][3];
    uint8_t received[(DATT_TABLE_MAX + 7) / 8];
    uint16_t n_received;     /* distinct points received (log datt.nRx) */
    uint8_t phase;           /* log datt.phase */
    uint16_t step;           /* control steps since the start (log datt.step) */
    float error_m;           /* |pos - p_d| at the last step (log datt.errM) */
    float ref_m[3];          /* p_d at the last step, controller frame (log datt.refX/Y/Z) */
    float action[4];         /* the last action: thrust m/s^2, body rates rad/s */
    float last_cmd[4];       /* the command the L1 update takes (the one sent last step) */
    float cmd_hist[DATT_HISTORY > 0 ? DATT_HISTORY * 4 : 1]; /* scaled, oldest first */
    datt_l1_state l1;
    uint16_t land_steps_done;
    float land_from_m[3];    /* the landing ramp's start (controller frame) */
    uint8_t landed_early;    /* 1: the landing began before the table's end (uncertain position) */
} datt_onboard;

/* Defaults (a 34 g Crazyflie 2.1, THRUST_MAX 0.12 N); clears the table. */
void datt_onboard_init(datt_onboard *o);
/* One app-channel packet from the host; writes the reply into reply[4], returns its length. */
int datt_onboard_receive(datt_onboard *o, const uint8_t *data, int len, uint8_t reply[4]);
/* Start tracking from the measured state (world frame): returns the new phase (DATT_TRACK, or
   DATT_REFUSED when the table is incomplete, a parameter is out of range or the state is not
   sane). */
uint8_t datt_onboard_start(datt_onboard *o, const float pos[3], const float vel[3], const float quat[4]);
/* The state estimate is one to fly on: every value finite and the quaternion of unit norm (a
   zero quaternion is what a state the controller hook never wrote looks like). */
uint8_t datt_state_sane(const float pos[3], const float vel[3], const float quat[4]);
/* Stop (host request): back to DATT_IDLE; the caller hands the commander back. */
void datt_onboard_stop(datt_onboard *o);
/* Refuse to start (the caller's own check failed, e.g. the boot self-test): DATT_REFUSED. */
void datt_onboard_refuse(datt_onboard *o);
/* One control step (50 Hz) from the state estimate (world frame: pos m, vel m/s, quat w x y z)
   and its horizontal position variance (m^2; the Kalman filter's max(varPX, varPY)): fills sp and
   returns the phase after the step. */
uint8_t datt_onboard_step(datt_onboard *o, const float pos[3], const float vel[3], const float quat[4],
                          float pos_var_m2, datt_setpoint *sp);

/* For callers that do not see this header (the simulated Crazyflie's ctypes binding): the size
   of datt_onboard, its parameters, and a fixed-layout copy of what the firmware logs. */
typedef struct {
    float error_m;
    float ref_m[3];
    float d_hat[3];
    float action[4];
    uint16_t step;
    uint16_t n_received;
    uint8_t phase;
    uint8_t landed_early;
} datt_onboard_status;
uint32_t datt_onboard_size(void);
uint32_t datt_onboard_policy_id(void); /* DATT_POLICY_ID of the policy compiled in */
uint32_t datt_onboard_state_max_age_ms(void); /* DATT_STATE_MAX_AGE_MS */
datt_onboard_params *datt_onboard_params_of(datt_onboard *o);
void datt_onboard_get_status(const datt_onboard *o, datt_onboard_status *s);

#endif
