/* The DATT controller onboard: see datt_onboard.h. No heap, no libm, no firmware headers. */
#include "datt_onboard.h"

#include <stddef.h>
#include <string.h>

#define RAD_TO_DEG 57.29577951308232f

static int finite_f(float x) { return x == x && x - x == 0.0f; } /* not NaN, not +-inf */

static float clip_f(float x, float lim) { return x > lim ? lim : (x < -lim ? -lim : x); }

void datt_onboard_init(datt_onboard *o) {
    /* the firmware's own thrust map for a 34 g vehicle with THRUST_MAX 0.12 N per motor */
    const float slope = 4.0f * 0.12f / (65535.0f * 0.034f);
    memset(o, 0, sizeof(*o));
    o->p.origin_m[2] = 1.0f;
    o->p.land_z_m = -0.95f;
    o->p.land_s = 2.5f;
    o->p.land_hold_s = 0.5f;
    o->p.slope_mps2_per_command = slope;
    o->p.hover_command = DATT_GRAVITY_MPS2 / slope;
    o->p.max_command = 60000;
    o->p.max_rate_degps[0] = 720.0f;
    o->p.max_rate_degps[1] = 720.0f;
    o->p.max_rate_degps[2] = 400.0f;
    o->p.max_tilt_deg = 75.0f;
    o->p.max_pos_std_m = 0.1f;
    o->phase = DATT_IDLE;
}

static float read_f32(const uint8_t *b) { /* little-endian, as cflib packs */
    uint32_t u = (uint32_t)b[0] | ((uint32_t)b[1] << 8) | ((uint32_t)b[2] << 16) | ((uint32_t)b[3] << 24);
    float f;
    memcpy(&f, &u, sizeof f);
    return f;
}

int datt_onboard_receive(datt_onboard *o, const uint8_t *data, int len, uint8_t reply[4]) {
    uint16_t index = 0;
    uint8_t status = DATT_ACK_MALFORMED;
    if (len >= 4 && data[0] == DATT_PKT_POINTS) {
        int count = data[3], i, j;
        index = (uint16_t)(data[1] | (data[2] << 8));
        if (count < 1 || count > 2 || len < 4 + 12 * count) {
            status = DATT_ACK_MALFORMED;
        } else if (o->phase == DATT_TRACK || o->phase == DATT_LAND) {
            status = DATT_ACK_BUSY;
        } else if ((int)index + count > DATT_TABLE_MAX) {
            status = DATT_ACK_RANGE;
        } else {
            for (i = 0; i < count; i++) {
                int k = index + i;
                for (j = 0; j < 3; j++) o->table[k][j] = read_f32(data + 4 + 12 * i + 4 * j);
                if (!(o->received[k / 8] & (1u << (k % 8)))) {
                    o->received[k / 8] |= (uint8_t)(1u << (k % 8));
                    o->n_received++;
                }
            }
            status = DATT_ACK_OK;
        }
    }
    reply[0] = DATT_PKT_ACK;
    reply[1] = (uint8_t)(index & 0xff);
    reply[2] = (uint8_t)(index >> 8);
    reply[3] = status;
    return 4;
}

static int table_complete(const datt_onboard *o) {
    int k;
    for (k = 0; k < o->p.n_points; k++)
        if (!(o->received[k / 8] & (1u << (k % 8)))) return 0;
    return 1;
}

static int params_valid(const datt_onboard_params *p) {
    return p->n_points >= 1 && p->n_points <= DATT_TABLE_MAX && p->track_steps < p->n_points &&
           p->slope_mps2_per_command > 0.0f && p->hover_command > 0.0f &&
           p->hover_command < (float)p->max_command && p->land_s > 0.0f && p->land_hold_s >= 0.0f &&
           p->max_tilt_deg > 0.0f && p->max_tilt_deg < 180.0f && p->max_pos_std_m >= 0.0f;
}

uint8_t datt_state_sane(const float pos[3], const float vel[3], const float quat[4]) {
    float norm2 = 0.0f;
    int i;
    for (i = 0; i < 3; i++)
        if (!finite_f(pos[i]) || !finite_f(vel[i])) return 0;
    for (i = 0; i < 4; i++) {
        if (!finite_f(quat[i])) return 0;
        norm2 += quat[i] * quat[i];
    }
    return norm2 > 0.98f && norm2 < 1.02f;
}

uint32_t datt_onboard_state_max_age_ms(void) { return DATT_STATE_MAX_AGE_MS; }

uint8_t datt_onboard_start(datt_onboard *o, const float pos[3], const float vel[3], const float quat[4]) {
    const float hover[4] = {DATT_GRAVITY_MPS2, 0.0f, 0.0f, 0.0f};
    int i;
    if (!params_valid(&o->p) || !table_complete(o) || !datt_state_sane(pos, vel, quat)) {
        o->phase = DATT_REFUSED;
        return o->phase;
    }
    datt_l1_reset(&o->l1, vel, quat);
    for (i = 0; i < 4; i++) o->last_cmd[i] = hover[i];
#if DATT_HISTORY > 0
    for (i = 0; i < DATT_HISTORY; i++) datt_scale_command(hover, o->cmd_hist + 4 * i);
#endif
    o->step = 0;
    o->land_steps_done = 0;
    o->landed_early = 0;
    o->phase = DATT_TRACK;
    return o->phase;
}

void datt_onboard_stop(datt_onboard *o) { o->phase = DATT_IDLE; }

void datt_onboard_refuse(datt_onboard *o) { o->phase = DATT_REFUSED; }

static void table_point(const datt_onboard *o, uint32_t k, float out[3]) {
    uint32_t last = o->p.n_points ? o->p.n_points - 1u : 0u;
    const float *row = o->table[k < last ? k : last];
    out[0] = row[0];
    out[1] = row[1];
    out[2] = row[2];
}

/* The landing ramp m steps after it began: from land_from_m straight down to land_z_m over
   land_s, then held. */
static void ramp_point(const datt_onboard *o, uint32_t m, float out[3]) {
    float u = (float)m * DATT_DT_S / o->p.land_s;
    if (u > 1.0f) u = 1.0f;
    out[0] = o->land_from_m[0];
    out[1] = o->land_from_m[1];
    out[2] = o->land_from_m[2] + u * (o->p.land_z_m - o->land_from_m[2]);
}

static void begin_landing(datt_onboard *o, uint32_t from_step) {
    table_point(o, from_step, o->land_from_m);
    o->land_steps_done = 0;
    o->phase = DATT_LAND;
}

static void stop_setpoint(datt_setpoint *sp) {
    sp->roll_degps = sp->pitch_degps = sp->yaw_degps = 0.0f;
    sp->thrust = 0;
    sp->stop = 1;
    sp->active = 1;
}

static uint8_t abort_flight(datt_onboard *o, datt_setpoint *sp) {
    o->phase = DATT_ABORTED;
    stop_setpoint(sp);
    return o->phase;
}

static uint16_t thrust_command(const datt_onboard_params *p, float thrust_mps2) {
    float c;
    if (!(thrust_mps2 > 0.0f)) return 0; /* also NaN */
    c = p->hover_command + (thrust_mps2 - DATT_GRAVITY_MPS2) / p->slope_mps2_per_command;
    if (c < 0.0f) c = 0.0f;
    if (c > (float)p->max_command) c = (float)p->max_command;
    return (uint16_t)(c + 0.5f);
}

uint8_t datt_onboard_step(datt_onboard *o, const float pos[3], const float vel[3], const float quat[4],
                          float pos_var_m2, datt_setpoint *sp) {
    float rel[3], ref[DATT_HORIZON * 3], cos_tilt, cos_max, tilt2, max_var_m2, ceiling_mps2, err2;
    float tilt_rad = o->p.max_tilt_deg / RAD_TO_DEG;
    int i, j, landing;
    sp->active = 0;
    sp->stop = 0;
    if (o->phase == DATT_DONE || o->phase == DATT_ABORTED) { /* keep the motors off until stopped */
        stop_setpoint(sp);
        return o->phase;
    }
    if (o->phase != DATT_TRACK && o->phase != DATT_LAND) return o->phase;
    if (!datt_state_sane(pos, vel, quat)) return abort_flight(o, sp);
    /* cos(tilt) = body z . world z; cos(max tilt) by its series to x^8 (no libm; < 1e-4 to 90 deg) */
    cos_tilt = 1.0f - 2.0f * (quat[1] * quat[1] + quat[2] * quat[2]);
    tilt2 = tilt_rad * tilt_rad;
    cos_max = 1.0f - tilt2 / 2.0f * (1.0f - tilt2 / 12.0f * (1.0f - tilt2 / 30.0f * (1.0f - tilt2 / 56.0f)));
    if (cos_tilt < cos_max) return abort_flight(o, sp);
    max_var_m2 = o->p.max_pos_std_m * o->p.max_pos_std_m;
    if (o->phase == DATT_TRACK && max_var_m2 > 0.0f && !(pos_var_m2 <= max_var_m2)) {
        begin_landing(o, o->step); /* no position measurements: stop tracking, land from here */
        o->landed_early = 1;
    }

    datt_l1_step(&o->l1, o->last_cmd, vel, quat); /* the command sent last step, the state now */
    for (i = 0; i < 3; i++) rel[i] = pos[i] - o->p.origin_m[i];
    landing = o->phase == DATT_LAND;
    for (j = 0; j < DATT_HORIZON; j++) {
        uint32_t k = (uint32_t)j * DATT_REF_STRIDE;
        if (landing)
            ramp_point(o, o->land_steps_done + k, ref + 3 * j);
        else
            table_point(o, o->step + k, ref + 3 * j);
    }
#if DATT_HISTORY > 0
    datt_act(rel, vel, quat, ref, o->l1.d_hat, o->cmd_hist, o->action);
#else
    datt_act(rel, vel, quat, ref, o->l1.d_hat, NULL, o->action);
#endif
    for (i = 0; i < 4; i++)
        if (!finite_f(o->action[i])) return abort_flight(o, sp);
    /* the thrust map clips at max_command: the L1 update and the history take what is sent */
    ceiling_mps2 = DATT_GRAVITY_MPS2 + o->p.slope_mps2_per_command * ((float)o->p.max_command - o->p.hover_command);
    if (o->action[0] > ceiling_mps2) o->action[0] = ceiling_mps2;
    err2 = 0.0f;
    for (i = 0; i < 3; i++) {
        o->ref_m[i] = ref[i];
        err2 += (rel[i] - ref[i]) * (rel[i] - ref[i]);
    }
    /* sqrt by Newton's iteration from a bit-level first guess (no libm) */
    {
        float r = err2;
        uint32_t u;
        memcpy(&u, &r, sizeof u);
        u = (u >> 1) + 0x1fbd1df5u;
        memcpy(&r, &u, sizeof r);
        for (i = 0; i < 4 && err2 > 0.0f; i++) r = 0.5f * (r + err2 / r);
        o->error_m = err2 > 0.0f ? r : 0.0f;
    }
#if DATT_HISTORY > 0
    for (i = 0; i + 4 < DATT_HISTORY * 4; i++) o->cmd_hist[i] = o->cmd_hist[i + 4];
    datt_scale_command(o->action, o->cmd_hist + 4 * (DATT_HISTORY - 1));
#endif
    for (i = 0; i < 4; i++) o->last_cmd[i] = o->action[i];

    sp->thrust = thrust_command(&o->p, o->action[0]);
    sp->roll_degps = clip_f(o->action[1] * RAD_TO_DEG, o->p.max_rate_degps[0]);
    sp->pitch_degps = -clip_f(o->action[2] * RAD_TO_DEG, o->p.max_rate_degps[1]); /* pitch is inverted */
    sp->yaw_degps = clip_f(o->action[3] * RAD_TO_DEG, o->p.max_rate_degps[2]);
    sp->active = 1;

    o->step++;
    if (landing) {
        o->land_steps_done++;
        /* the ramp and the hold, in whole steps (rounded: 0.3 s / 0.02 s is 15, not 14.999) */
        if (o->land_steps_done >= (uint32_t)((o->p.land_s + o->p.land_hold_s) / DATT_DT_S + 0.5f)) {
            o->phase = DATT_DONE; /* this step's setpoint still flies; the next ones stop the motors */
        }
    } else if (o->step >= o->p.track_steps) {
        begin_landing(o, o->p.track_steps);
    }
    return o->phase;
}

uint32_t datt_onboard_size(void) { return (uint32_t)sizeof(datt_onboard); }

uint32_t datt_onboard_policy_id(void) { return DATT_POLICY_ID; }

datt_onboard_params *datt_onboard_params_of(datt_onboard *o) { return &o->p; }

void datt_onboard_get_status(const datt_onboard *o, datt_onboard_status *s) {
    int i;
    s->error_m = o->error_m;
    for (i = 0; i < 3; i++) {
        s->ref_m[i] = o->ref_m[i];
        s->d_hat[i] = o->l1.d_hat[i];
    }
    for (i = 0; i < 4; i++) s->action[i] = o->action[i];
    s->step = o->step;
    s->n_received = o->n_received;
    s->phase = o->phase;
    s->landed_early = o->landed_early;
}
