/* The fixed part of the generated header: the generator (datt.export.c_code) writes the include
   guard and the DATT_* #defines above this text, and renames datt_ / DATT_ to its prefix. */

typedef struct {
    float v_hat[3];        /* predicted velocity, world, m/s */
    float sigma_hat[3];    /* unfiltered estimate, m/s^2 */
    float d_hat[3];        /* filtered disturbance estimate, world, m/s^2 (the policy's input) */
    float prev_vel[3];
    float prev_quat[4];
    float thrust_est;      /* modelled actuator thrust, m/s^2 */
    float thrust_queue[DATT_L1_LATENCY + 1]; /* thrust commands in flight, oldest first (DATT_L1_LATENCY used) */
} datt_l1_state;

/* Observation (state and feedforward) from the measured state and the reference window.
   pos, vel: world m, m/s; quat: w, x, y, z body-to-world; ref: DATT_HORIZON future points
   (world, m), x y z each, [DATT_HORIZON * 3]; state: [DATT_STATE_DIM]; feedforward:
   [DATT_HORIZON * 3]; cmd_hist: the last DATT_HISTORY commands scaled by datt_scale_command,
   oldest first (may be NULL if DATT_HISTORY is 0). */
void datt_observe(const float pos[3], const float vel[3], const float quat[4], const float *ref,
                  const float *cmd_hist, float *state, float *feedforward);
/* The network's four action locations (before the squash). */
void datt_network(const float *state, const float *feedforward, const float d_hat[3], float loc[4]);
/* The action (thrust m/s^2, body rates rad/s) for one control step. */
void datt_act(const float pos[3], const float vel[3], const float quat[4], const float *ref,
              const float d_hat[3], const float *cmd_hist, float action[4]);
/* A sent command in the history's units: (cmd - center) / half over the action bounds. */
void datt_scale_command(const float cmd[4], float scaled[4]);
/* L1: reset to a measured state, then one step per control step with the command sent at the
   start of the step and the state measured after it. */
void datt_l1_reset(datt_l1_state *s, const float vel[3], const float quat[4]);
void datt_l1_step(datt_l1_state *s, const float cmd[4], const float vel[3], const float quat[4]);
/* Runs the embedded golden case; returns 0 when the action and d-hat agree with torch's within
   the tolerances, else 1. max_err (may be NULL): the largest difference seen. */
int datt_self_test(float *max_err);
