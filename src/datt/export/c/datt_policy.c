/* The fixed part of the generated controller. The generator (datt.export.c_code) writes above
   this text: the #defines of the layout (H, KERNEL, BODY_FRAME, FEEDBACK, USE_D_HAT, N_CONV,
   N_MLP, EMBED, CHANNELS, MLP_IN, WIDTH, the L1 constants, the tolerances), the weight arrays and
   the layer tables (conv_w, conv_b, conv_out, conv_in, mlp_w, mlp_b, mlp_out), the action bounds
   and the golden case; it renames datt_ / DATT_ to its prefix. Plain C99: no heap, no libm. */

static float relu(float x) { return x > 0.0f ? x : 0.0f; }

/* exp(x) for x in [0, 88] (Cephes expf: x = n ln2 + r, |r| <= ln2 / 2, a degree-6 polynomial
   for exp(r), 2^n through the exponent bits): the code's own, so that every platform computes
   the same bits (libm's expf differs between glibc and newlib in the last place). */
static float exp_pos(float x) {
    union { float f; uint32_t i; } scale;
    float r, z, y;
    int32_t n;
    if (x > 88.0f) x = 88.0f;
    n = (int32_t)(x * 1.44269504088896341f + 0.5f);
    r = x - (float)n * 0.693359375f;
    r = r - (float)n * -2.12194440e-4f;
    z = r * r;
    y = ((((1.9875691500e-4f * r + 1.3981999507e-3f) * r + 8.3334519073e-3f) * r + 4.1665795894e-2f) * r
         + 1.6666665459e-1f) * r + 5.0000001201e-1f;
    y = y * z + r + 1.0f;
    scale.i = (uint32_t)(n + 127) << 23;
    return y * scale.f;
}

static float tanh_f(float x) {
    /* 1 - 2 / (exp(2|x|) + 1), odd */
    float a = x < 0.0f ? -x : x;
    float t = 1.0f - 2.0f / (exp_pos(2.0f * a) + 1.0f);
    return x < 0.0f ? -t : t;
}

/* y = W x + b (W row-major [n_out][n_in]), then ReLU if use_relu. One accumulator, summed in
   index order (the order fixes the bits); unrolled by 4 for fewer loop instructions. */
static void linear(const float *w, const float *b, const float *x, float *y, int n_out, int n_in, int use_relu) {
    int o, i;
    for (o = 0; o < n_out; o++) {
        const float *row = w + o * n_in;
        float acc = b[o];
        for (i = 0; i + 4 <= n_in; i += 4) {
            acc += row[i] * x[i];
            acc += row[i + 1] * x[i + 1];
            acc += row[i + 2] * x[i + 2];
            acc += row[i + 3] * x[i + 3];
        }
        for (; i < n_in; i++) {
            acc += row[i] * x[i];
        }
        y[o] = use_relu ? relu(acc) : acc;
    }
}

/* 'same'-padded stride-1 conv1d + ReLU: x [c_in][H] -> y [c_out][H], w [c_out][c_in][KERNEL];
   taps outside [0, H) are skipped (zero padding), the rest summed in (ci, j) order. Positions
   with every tap inside run a loop of constant length, which the compiler unrolls. */
static void conv1d_relu(const float *w, const float *b, const float *x, float *y, int c_out, int c_in) {
    int o, t, ci, j;
    for (o = 0; o < c_out; o++) {
        for (t = 0; t < H; t++) {
            int lo = t < KERNEL / 2 ? KERNEL / 2 - t : 0;
            int hi = t + (KERNEL - KERNEL / 2) > H ? H - t + KERNEL / 2 : KERNEL;
            float acc = b[o];
            for (ci = 0; ci < c_in; ci++) {
                const float *wr = w + (o * c_in + ci) * KERNEL;
                const float *xr = x + ci * H + t; /* the input under the centre tap */
                if (lo == 0 && hi == KERNEL) {
                    for (j = 0; j < KERNEL; j++) {
                        acc += wr[j] * xr[j - KERNEL / 2];
                    }
                } else {
                    for (j = lo; j < hi; j++) {
                        acc += wr[j] * xr[j - KERNEL / 2];
                    }
                }
            }
            y[o * H + t] = relu(acc);
        }
    }
}

/* A world vector in the policy's frame: the body frame, R(q)^T v = v - w t + u x t with
   t = 2 u x v (as datt.sim.frames.quat_rotate_inverse), or the world frame unchanged. */
static void to_policy_frame(const float q[4], const float v[3], float out[3]) {
#if BODY_FRAME
    float t[3], c[3];
    t[0] = 2.0f * (q[2] * v[2] - q[3] * v[1]);
    t[1] = 2.0f * (q[3] * v[0] - q[1] * v[2]);
    t[2] = 2.0f * (q[1] * v[1] - q[2] * v[0]);
    c[0] = q[2] * t[2] - q[3] * t[1];
    c[1] = q[3] * t[0] - q[1] * t[2];
    c[2] = q[1] * t[1] - q[2] * t[0];
    out[0] = v[0] - q[0] * t[0] + c[0];
    out[1] = v[1] - q[0] * t[1] + c[1];
    out[2] = v[2] - q[0] * t[2] + c[2];
#else
    (void)q;
    out[0] = v[0];
    out[1] = v[1];
    out[2] = v[2];
#endif
}

void datt_observe(const float pos[3], const float vel[3], const float quat[4], const float *ref,
                  const float *cmd_hist, float *state, float *feedforward) {
    int i, j;
    float v[3], out[3];
    /* position and velocity */
    for (j = 0; j < 3; j++) v[j] = pos[j];
    to_policy_frame(quat, v, out);
    for (j = 0; j < 3; j++) state[j] = FEEDBACK ? out[j] : 0.0f;
    for (j = 0; j < 3; j++) v[j] = vel[j];
    to_policy_frame(quat, v, out);
    for (j = 0; j < 3; j++) state[3 + j] = out[j];
    for (j = 0; j < 4; j++) state[6 + j] = quat[j];
    /* feedback error (i = 0) and the feedforward points */
    for (i = 0; i < H; i++) {
        for (j = 0; j < 3; j++) v[j] = pos[j] - ref[3 * i + j];
        to_policy_frame(quat, v, out);
        if (i == 0) {
            for (j = 0; j < 3; j++) state[10 + j] = out[j];
        }
        /* without the body frame the policy reads the raw future positions */
        for (j = 0; j < 3; j++) feedforward[3 * i + j] = BODY_FRAME ? out[j] : ref[3 * i + j];
    }
#if DATT_HISTORY > 0
    for (j = 0; j < 4 * DATT_HISTORY; j++) state[13 + j] = cmd_hist[j];
#else
    (void)cmd_hist;
#endif
}

void datt_network(const float *state, const float *feedforward, const float d_hat[3], float loc[4]) {
    float a[WIDTH], b[WIDTH];
    float x[MLP_IN];
    float *bufs[2];
    float *src = a, *dst = b, *swap;
    const float *cur = x;
    int i, j, n_in = MLP_IN;
    /* channel-major input of the encoder: a[c * H + t] = feedforward[t][c] */
    for (i = 0; i < H; i++) for (j = 0; j < 3; j++) a[j * H + i] = feedforward[3 * i + j];
    for (i = 0; i < N_CONV; i++) {
        conv1d_relu(conv_w[i], conv_b[i], src, dst, conv_out[i], i == 0 ? 3 : conv_out[i - 1]);
        swap = src;
        src = dst;
        dst = swap;
    }
    for (j = 0; j < DATT_STATE_DIM; j++) x[j] = state[j];
    linear(proj_w, proj_b, src, x + DATT_STATE_DIM, EMBED, CHANNELS * H, 1);
#if USE_D_HAT
    for (j = 0; j < 3; j++) x[DATT_STATE_DIM + EMBED + j] = d_hat[j];
#else
    (void)d_hat;
#endif
    bufs[0] = a;
    bufs[1] = b;
    for (i = 0; i < N_MLP; i++) {
        linear(mlp_w[i], mlp_b[i], cur, bufs[i % 2], mlp_out[i], n_in, 1);
        cur = bufs[i % 2];
        n_in = mlp_out[i];
    }
    linear(head_w, head_b, cur, loc, 4, n_in, 0);
}

void datt_act(const float pos[3], const float vel[3], const float quat[4], const float *ref,
              const float d_hat[3], const float *cmd_hist, float action[4]) {
    float state[DATT_STATE_DIM], feedforward[3 * H], loc[4];
    int j;
    datt_observe(pos, vel, quat, ref, cmd_hist, state, feedforward);
    datt_network(state, feedforward, d_hat, loc);
    for (j = 0; j < 4; j++) {
        float u = act_center[j] + act_half[j] * tanh_f(loc[j]);
        action[j] = u < act_low[j] ? act_low[j] : (u > act_high[j] ? act_high[j] : u);
    }
}

void datt_scale_command(const float cmd[4], float scaled[4]) {
    int j;
    for (j = 0; j < 4; j++) scaled[j] = (cmd[j] - act_center[j]) / act_half[j];
}

void datt_l1_reset(datt_l1_state *s, const float vel[3], const float quat[4]) {
    int j;
    for (j = 0; j < 3; j++) {
        s->v_hat[j] = vel[j];
        s->sigma_hat[j] = 0.0f;
        s->d_hat[j] = 0.0f;
        s->prev_vel[j] = vel[j];
    }
    for (j = 0; j < 4; j++) s->prev_quat[j] = quat[j];
    s->thrust_est = L1_GRAVITY;
    for (j = 0; j < DATT_L1_LATENCY + 1; j++) s->thrust_queue[j] = L1_GRAVITY;
}

static float lerp_f(float a, float b, float w) {
    /* as torch.lerp: a + w (b - a) for w < 0.5, else b - (b - a)(1 - w) */
    return w < 0.5f ? a + w * (b - a) : b - (b - a) * (1.0f - w);
}

void datt_l1_step(datt_l1_state *s, const float cmd[4], const float vel[3], const float quat[4]) {
    const float *q = s->prev_quat;
    float acting, thrust, body_z[3], f[3], fb[3];
    int j;
    /* the oldest thrust command in flight acts now; this step's command joins the queue */
#if DATT_L1_LATENCY > 0
    acting = s->thrust_queue[0];
    for (j = 0; j + 1 < DATT_L1_LATENCY; j++) s->thrust_queue[j] = s->thrust_queue[j + 1];
    s->thrust_queue[DATT_L1_LATENCY - 1] = cmd[0];
#else
    acting = cmd[0];
#endif
    thrust = lerp_f(s->thrust_est, acting, L1_K_THRUST);
    body_z[0] = 2.0f * (q[1] * q[3] + q[0] * q[2]);
    body_z[1] = 2.0f * (q[2] * q[3] - q[0] * q[1]);
    body_z[2] = 1.0f - 2.0f * (q[1] * q[1] + q[2] * q[2]);
    for (j = 0; j < 3; j++) {
        f[j] = body_z[j] * thrust + (j == 2 ? -L1_GRAVITY : 0.0f);
        /* the predictor's feedback: the filtered estimate (the paper's) or the raw one */
        fb[j] = L1_PREDICTOR_USES_FILTERED ? s->d_hat[j] : s->sigma_hat[j];
    }
    for (j = 0; j < 3; j++) {
        float v_hat = s->v_hat[j] * (1.0f + L1_DT * L1_A_S) + (-L1_DT * L1_A_S) * s->prev_vel[j]
                      + L1_DT * (f[j] + fb[j]);
        float sigma = L1_LAW_GAIN * (v_hat - vel[j]);
        s->v_hat[j] = v_hat;
        s->sigma_hat[j] = sigma;
        s->d_hat[j] = lerp_f(sigma, s->d_hat[j], L1_ALPHA);
        s->prev_vel[j] = vel[j];
    }
    for (j = 0; j < 4; j++) s->prev_quat[j] = quat[j];
    s->thrust_est = thrust;
}

int datt_self_test(float *max_err) {
    float action[4], worst = 0.0f;
    datt_l1_state s;
    int j, i, fail = 0;
#if DATT_HISTORY > 0
    datt_act(golden_pos, golden_vel, golden_quat, golden_ref, golden_d_hat, golden_cmd_hist, action);
#else
    (void)golden_cmd_hist;
    datt_act(golden_pos, golden_vel, golden_quat, golden_ref, golden_d_hat, NULL, action);
#endif
    for (j = 0; j < 4; j++) {
        float e = action[j] - golden_action[j];
        e = e < 0.0f ? -e : e;
        if (!(e <= ACTION_TOL)) fail = 1;
        if (e > worst) worst = e;
    }
    datt_l1_reset(&s, golden_l1_vel, golden_l1_quat);
    for (i = 1; i < GOLDEN_L1_STEPS; i++) {
        datt_l1_step(&s, golden_l1_cmd + 4 * i, golden_l1_vel + 3 * i, golden_l1_quat + 4 * i);
    }
    for (j = 0; j < 3; j++) {
        float e = s.d_hat[j] - golden_l1_d_hat[j];
        e = e < 0.0f ? -e : e;
        if (!(e <= D_HAT_TOL)) fail = 1;
        if (e > worst) worst = e;
    }
    if (max_err != NULL) *max_err = worst;
    return fail;
}
