/* ecca_onboard_core.c: the onboard module's logic without PX4 (see ecca_onboard_core.h). */
#include "ecca_onboard_core.h"

#include <math.h>
#include <string.h>

#include "ecca_setpoint.h"

/* ------------------------------------------------------------------------------ upload */

static uint32_t crc32_update(uint32_t crc, const void *data, unsigned long n) {
  const uint8_t *p = (const uint8_t *)data;
  unsigned long i;
  int k;
  crc = ~crc;
  for (i = 0; i < n; ++i) {
    crc ^= p[i];
    for (k = 0; k < 8; ++k) {
      crc = (crc >> 1) ^ (0xEDB88320u & (0u - (crc & 1u)));
    }
  }
  return ~crc;
}

/* CRC-32 (zlib's) of the upload: BEGIN's ECCA_B_COUNT floats, then each segment's
 * ECCA_S_COUNT floats as received (index and duration first), float32 in memory order. */
static uint32_t upload_crc(const ecca_onboard *m) {
  uint32_t crc = crc32_update(0u, m->begin, sizeof(m->begin));
  int i;
  for (i = 0; i < m->n_expected; ++i) {
    float head[2];
    head[0] = (float)i;
    head[1] = m->seg[i].duration;
    crc = crc32_update(crc, head, sizeof(head));
    crc = crc32_update(crc, m->seg[i].ctrl, sizeof(m->seg[i].ctrl));
    crc = crc32_update(crc, m->seg[i].yaw, sizeof(m->seg[i].yaw));
  }
  return crc;
}

static int flying(const ecca_onboard *m) {
  return m->state == ECCA_STATE_FLYING || m->state == ECCA_STATE_HOLDING;
}

static void op_ack(const ecca_onboard *m, ecca_onboard_ack *ack, int op, uint8_t result,
                   int32_t value) {
  ack->command = ECCA_ACK_CMD;
  ack->result = result;
  ack->state = (uint8_t)m->state;
  ack->value = (int32_t)(((uint32_t)op << 24) | ((uint32_t)value & 0xFFFFFFu));
}

static int32_t progress_value(const ecca_onboard *m) {
  double ms;
  if (m->state == ECCA_STATE_RECEIVING || m->state == ECCA_STATE_LOADED) {
    return m->n_received;
  }
  if (m->state == ECCA_STATE_FLYING || m->state == ECCA_STATE_HOLDING ||
      m->state == ECCA_STATE_DONE) {
    ms = (m->t_last - m->t0) * 1000.0; /* the trajectory's clock at the last step [ms] */
    return (int32_t)(ms < 0.0 ? 0.0 : ms > 16777215.0 ? 16777215.0 : ms + 0.5);
  }
  return 0;
}

void ecca_onboard_init(ecca_onboard *m) {
  memset(m, 0, sizeof(*m));
  m->state = ECCA_STATE_READY;
  m->vc_w = ECCA_VCORR_DEFAULT_RAD_S;
}

unsigned long ecca_onboard_size(void) { return (unsigned long)sizeof(ecca_onboard); }

void ecca_onboard_status(const ecca_onboard *m, ecca_onboard_ack *ack) {
  op_ack(m, ack, ECCA_OP_STATUS, 0, progress_value(m));
}

int ecca_onboard_start_report(const ecca_onboard *m, ecca_onboard_ack *ack) {
  double ms = m->t0 * 1000.0;
  if (!(m->state == ECCA_STATE_FLYING || m->state == ECCA_STATE_HOLDING ||
        m->state == ECCA_STATE_DONE) || !(ms >= 0.0 && ms < 2147483647.0)) {
    return 0;
  }
  ack->command = ECCA_ACK_START;
  ack->result = 0;
  ack->state = (uint8_t)m->state;
  ack->value = (int32_t)(ms + 0.5);
  return 1;
}

static int begin_valid(const float *d) {
  int n = (int)d[ECCA_B_N_SEGMENTS];
  int i;
  for (i = 0; i < ECCA_B_COUNT; ++i) {
    if (!(d[i] == d[i]) || d[i] > 1e9f || d[i] < -1e9f) {
      return 0; /* NaN or absurd */
    }
  }
  return (int)d[ECCA_B_VERSION] == ECCA_PROTO_VERSION && n >= 1 && n <= ECCA_MAX_SEGMENTS &&
         d[ECCA_B_HOVER] > 0.0f && d[ECCA_B_HOVER] < 1.0f && d[ECCA_B_MASS] > 0.0f &&
         d[ECCA_B_G] > 0.0f && d[ECCA_B_TILT_MAX] > 0.0f && d[ECCA_B_TILT_MAX] < 1.5f &&
         d[ECCA_B_THRUST_MAX] > d[ECCA_B_THRUST_MIN] && d[ECCA_B_START_TOL_M] > 0.0f &&
         d[ECCA_B_LEAD_S] >= 0.0f && d[ECCA_B_LEAD_S] <= 1.0f && d[ECCA_B_DIST_BW] >= 0.0f &&
         d[ECCA_B_DIST_BW] <= 20.0f && d[ECCA_B_VCORR_RAD_S] >= 0.0f &&
         d[ECCA_B_VCORR_RAD_S] <= 20.0f && d[ECCA_B_UPLOAD_ID] >= 0.0f &&
         d[ECCA_B_UPLOAD_ID] < 16777216.0f;
}

/* Segment k as held equals the SEGMENT message d (its index already checked). */
static int segment_held(const ecca_onboard *m, int k, const float *d) {
  return m->have[k] && m->seg[k].duration == d[ECCA_S_DURATION] &&
         memcmp(m->seg[k].ctrl, d + ECCA_S_CTRL, sizeof(m->seg[k].ctrl)) == 0 &&
         memcmp(m->seg[k].yaw, d + ECCA_S_YAW, sizeof(m->seg[k].yaw)) == 0;
}

static int segment_valid(const float *d) {
  int i;
  for (i = 0; i < ECCA_S_COUNT; ++i) {
    if (!(d[i] == d[i]) || d[i] > 1e7f || d[i] < -1e7f) {
      return 0;
    }
  }
  return d[ECCA_S_DURATION] > 0.0f;
}

int ecca_onboard_message(ecca_onboard *m, int op, const float *d, ecca_onboard_ack *ack) {
  int i;
  switch (op) {
  case ECCA_OP_STATUS:
    if (d[0] >= 1.0f && d[0] <= 255.0f) {
      m->peer_sys = (uint8_t)d[0];
      m->peer_comp = (uint8_t)d[1];
    }
    ecca_onboard_status(m, ack);
    return 1;
  case ECCA_OP_BEGIN:
    if (d[ECCA_B_SYSID] >= 1.0f && d[ECCA_B_SYSID] <= 255.0f) {
      m->peer_sys = (uint8_t)d[ECCA_B_SYSID];
      m->peer_comp = (uint8_t)d[ECCA_B_COMPID];
    }
    if (flying(m)) {
      op_ack(m, ack, ECCA_OP_BEGIN, 1 /* TEMPORARILY_REJECTED */, 0);
      return 1;
    }
    if ((m->state == ECCA_STATE_RECEIVING || m->state == ECCA_STATE_LOADED) &&
        memcmp(m->begin, d, sizeof(m->begin)) == 0) {
      /* a repeated BEGIN (delayed, duplicated, or the same upload again: ECCA_B_UPLOAD_ID
       * names its segments): no reset. A late copy arriving after COMMIT reset a loaded
       * trajectory whose CRC the companion had already been given. */
      op_ack(m, ack, ECCA_OP_BEGIN, 0, 0);
      return 1;
    }
    if (!begin_valid(d)) {
      m->state = ECCA_STATE_READY;
      op_ack(m, ack, ECCA_OP_BEGIN, 2 /* DENIED */, 0);
      return 1;
    }
    memcpy(m->begin, d, sizeof(m->begin));
    m->vc_w = (double)d[ECCA_B_VCORR_RAD_S]; /* the companion's, from now on */
    m->n_expected = (int)d[ECCA_B_N_SEGMENTS];
    m->n_received = 0;
    memset(m->have, 0, sizeof(m->have));
    m->state = ECCA_STATE_RECEIVING;
    op_ack(m, ack, ECCA_OP_BEGIN, 0, 0);
    return 1;
  case ECCA_OP_SEGMENT: {
    int k = (int)d[ECCA_S_INDEX];
    if (m->state == ECCA_STATE_LOADED && k >= 0 && k < m->n_expected &&
        (float)k == d[ECCA_S_INDEX] && segment_held(m, k, d)) {
      op_ack(m, ack, ECCA_OP_SEGMENT, 0, k); /* what is held already (the same upload again) */
      return 1;
    }
    if (m->state != ECCA_STATE_RECEIVING || k < 0 || k >= m->n_expected ||
        (float)k != d[ECCA_S_INDEX] || !segment_valid(d)) {
      op_ack(m, ack, ECCA_OP_SEGMENT, 2, k < 0 ? 0 : k);
      return 1;
    }
    m->seg[k].duration = d[ECCA_S_DURATION];
    memcpy(m->seg[k].ctrl, d + ECCA_S_CTRL, sizeof(m->seg[k].ctrl));
    memcpy(m->seg[k].yaw, d + ECCA_S_YAW, sizeof(m->seg[k].yaw));
    if (!m->have[k]) {
      m->have[k] = 1;
      m->n_received++;
    }
    op_ack(m, ack, ECCA_OP_SEGMENT, 0, k);
    return 1;
  }
  case ECCA_OP_COMMIT: {
    uint32_t want = (uint32_t)d[0] | ((uint32_t)d[1] << 16);
    uint32_t got = 0;
    if (m->state == ECCA_STATE_LOADED && want == m->crc) {
      got = m->crc; /* a repeated COMMIT (its first answer lost): answer it again */
    } else if (m->state == ECCA_STATE_RECEIVING && m->n_received == m->n_expected &&
               (got = upload_crc(m)) == want) {
      m->crc = got;
      m->t_start_seg[0] = 0.0;
      for (i = 0; i < m->n_expected; ++i) {
        m->t_start_seg[i + 1] = m->t_start_seg[i] + (double)m->seg[i].duration;
      }
      m->state = ECCA_STATE_LOADED;
    } else if (!flying(m)) {
      m->state = ECCA_STATE_READY; /* never flown: upload again */
    }
    ack->command = ECCA_ACK_CRC;
    ack->result = (uint8_t)(m->state == ECCA_STATE_LOADED && got == want ? 0 : 2);
    ack->state = (uint8_t)m->state;
    ack->value = (int32_t)got;
    return 1;
  }
  case ECCA_OP_ABORT:
    if (flying(m)) {
      op_ack(m, ack, ECCA_OP_ABORT, 1, 0);
      return 1;
    }
    m->state = ECCA_STATE_READY;
    m->n_expected = m->n_received = 0;
    op_ack(m, ack, ECCA_OP_ABORT, 0, 0);
    return 1;
  default:
    return 0;
  }
}

/* ----------------------------------------------------------------------------- flight */

static void reference_at(const ecca_onboard *m, double t, ecca_flat_state *s) {
  ecca_bezier_segment b;
  int k = 0, i, j;
  double total = m->t_start_seg[m->n_expected];
  if (t > total) {
    t = total;
  }
  while (k + 1 < m->n_expected && t >= m->t_start_seg[k + 1]) {
    ++k;
  }
  for (i = 0; i < 8; ++i) {
    for (j = 0; j < 3; ++j) {
      b.ctrl_pts_ned_m[i][j] = m->seg[k].ctrl[i][j];
    }
    b.yaw_ctrl_pts_rad[i] = m->seg[k].yaw[i];
  }
  b.duration_s = m->seg[k].duration;
  if (ecca_bezier_eval(&b, t - m->t_start_seg[k], s) != ECCA_OK) {
    memset(s, 0, sizeof(*s));
  }
}

/* Fuse the position sample `pos`, `vel` taken at `sample_s` into the velocity correction (once
 * per sample; the bookkeeping of the companion's VelocityCorrection.update around the same
 * generated step). Frequency 0: off, no correction. */
static void correct(ecca_onboard *m, double sample_s, const double pos[3], const double vel[3]) {
  double in[ECCA_VCORR_N_IN], out[ECCA_VCORR_N_OUT];
  int i, n = 0;
  if (!(m->vc_w > 0.0)) {
    m->vc_c[0] = m->vc_c[1] = 0.0;
    m->vc_have = 0;
    return;
  }
  if (!(isfinite(sample_s) && isfinite(pos[0]) && isfinite(pos[1]) && isfinite(vel[0]) &&
        isfinite(vel[1]))) {
    return; /* a non-finite sample: ignored */
  }
  if (m->vc_have && sample_s == m->vc_t) {
    return; /* the same sample again (the step runs faster than the estimate) */
  }
  for (i = 0; i < 2; ++i) in[n++] = m->vc_p[i];
  for (i = 0; i < 2; ++i) in[n++] = m->vc_v[i];
  for (i = 0; i < 2; ++i) in[n++] = m->vc_c[i];
  for (i = 0; i < 2; ++i) in[n++] = pos[i];
  for (i = 0; i < 2; ++i) in[n++] = vel[i];
  in[n++] = m->vc_have ? sample_s - m->vc_t : 0.0; /* a gap or a clock jump: a restart */
  in[n++] = m->vc_w;
  in[n++] = ECCA_VCORR_MAX_M_S;
  in[n++] = ECCA_VCORR_RESET_M;
  in[n++] = m->vc_have ? 1.0 : 0.0; /* the first sample: a restart */
  if (n == ECCA_VCORR_N_IN && ecca_velocity_correction_step(in, out) == ECCA_OK) {
    m->vc_p[0] = out[0];
    m->vc_p[1] = out[1];
    m->vc_c[0] = out[2];
    m->vc_c[1] = out[3];
  } else {
    m->vc_p[0] = pos[0]; /* refused (e.g. |pos| absurd): restart from the sample, hold */
    m->vc_p[1] = pos[1];
  }
  m->vc_v[0] = vel[0];
  m->vc_v[1] = vel[1];
  m->vc_t = sample_s;
  m->vc_have = 1;
}

/* Fuse the velocity sample `vel` taken at `sample_s` into the disturbance observer (once per
 * sample), with the attitude `q` (NULL: unknown) and the thrust the last step commanded. */
static void observe(ecca_onboard *m, double sample_s, const double vel[3], const double *q) {
  double in[ECCA_DIST_N_IN], out[ECCA_DIST_N_OUT];
  const float *b = m->begin;
  double dt = 0.0, ax = 0.0, ay = 0.0, n2;
  int i, n = 0, learn;
  if (m->have_sample && !(sample_s > m->t_sample)) {
    return; /* the same sample again (the step runs faster than the estimate) */
  }
  if (!(isfinite(vel[0]) && isfinite(vel[1]) && isfinite(sample_s))) {
    m->have_sample = 0;
    return;
  }
  n2 = q != 0 ? q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3] : 0.0;
  learn = m->have_sample && n2 > 0.9 && n2 < 1.1 && m->u_last >= ECCA_DIST_MIN_THRUST &&
          b[ECCA_B_DIST_BW] > 0.0f; /* 0: no disturbance estimated (d_hat stays 0) */
  if (learn) {
    /* body z axis (third column of C_eb) in NED, horizontal part; thrust along -z_b */
    double zx = 2.0 * (q[1] * q[3] + q[0] * q[2]);
    double zy = 2.0 * (q[2] * q[3] - q[0] * q[1]);
    double f = m->u_last * (double)b[ECCA_B_G] / (double)b[ECCA_B_HOVER];
    double dm = (double)b[ECCA_B_DRAG] / (double)b[ECCA_B_MASS];
    dt = sample_s - m->t_sample;
    ax = -f * zx - dm * vel[0];
    ay = -f * zy - dm * vel[1];
    learn = isfinite(ax) && isfinite(ay) && isfinite(dt);
    if (!learn) {
      dt = ax = ay = 0.0;
    }
  }
  for (i = 0; i < 2; ++i) in[n++] = m->have_sample ? m->v_hat[i] : vel[i];
  for (i = 0; i < 2; ++i) in[n++] = m->d_hat[i];
  for (i = 0; i < 2; ++i) in[n++] = vel[i];
  in[n++] = ax;
  in[n++] = ay;
  in[n++] = dt;
  in[n++] = learn ? (double)b[ECCA_B_DIST_BW] : 1.0; /* (not used without learning) */
  in[n++] = ECCA_DIST_MAX_ACC;
  in[n++] = learn ? 1.0 : 0.0;
  if (n == ECCA_DIST_N_IN && ecca_disturbance_step(in, out) == ECCA_OK) {
    m->v_hat[0] = out[0];
    m->v_hat[1] = out[1];
    m->d_hat[0] = out[2];
    m->d_hat[1] = out[3];
  } else {
    m->v_hat[0] = vel[0]; /* refused (e.g. |vel| absurd): follow the sample, hold d_hat */
    m->v_hat[1] = vel[1];
  }
  m->t_sample = sample_s;
  m->have_sample = 1;
}

/* One step of the law (attitude mode: no feedback jerk) at `t` on the trajectory's clock, from
 * the estimate `pos`, `vel` sampled at `ts` on that clock: the errors are taken against the
 * reference at `ts` (a sample ECCA_SAMPLE_AGE_MAX_S old or older counts as that old), the
 * feed-forward is the reference lead_s after `t`. 0 if no finite setpoint. */
static int control(ecca_onboard *m, double t, double ts, double dt, const double pos[3],
                   const double vel[3], ecca_onboard_output *o) {
  ecca_flat_state r, a;
  double in[ECCA_CORE_N_IN], out[ECCA_CORE_N_OUT];
  const float *b = m->begin;
  double tilt = (double)b[ECCA_B_TILT_MAX];
  int i, n = 0;
  if (!(ts <= t)) { /* not finite, or a clock that ran backwards */
    ts = t;
  } else if (ts < t - ECCA_SAMPLE_AGE_MAX_S) {
    ts = t - ECCA_SAMPLE_AGE_MAX_S;
  }
  reference_at(m, ts > 0.0 ? ts : 0.0, &r);
  /* the feed-forward of the reference lead_s ahead: it offsets PX4's attitude loop's lag */
  reference_at(m, t + (double)b[ECCA_B_LEAD_S], &a);
  for (i = 0; i < 3; ++i) in[n++] = r.pos_ned_m[i];
  for (i = 0; i < 3; ++i) in[n++] = r.vel_ned_m_s[i];
  for (i = 0; i < 3; ++i) in[n++] = r.acc_ned_m_s2[i];
  for (i = 0; i < 3; ++i) in[n++] = a.acc_ned_m_s2[i];
  for (i = 0; i < 3; ++i) in[n++] = a.jerk_ned_m_s3[i];
  for (i = 0; i < 3; ++i) in[n++] = a.snap_ned_m_s4[i];
  for (i = 0; i < 3; ++i) in[n++] = pos[i];
  for (i = 0; i < 3; ++i) in[n++] = vel[i];
  for (i = 0; i < 3; ++i) in[n++] = 0.0; /* acc_meas: unused without feedback jerk */
  for (i = 0; i < 3; ++i) in[n++] = m->integ[i];
  for (i = 0; i < 3; ++i) in[n++] = b[ECCA_B_KP + i];
  for (i = 0; i < 3; ++i) in[n++] = b[ECCA_B_KD + i];
  for (i = 0; i < 3; ++i) in[n++] = b[ECCA_B_KI + i];
  for (i = 0; i < 3; ++i) in[n++] = b[ECCA_B_IMAX + i];
  in[n++] = m->d_hat[0]; /* disturbance north, east (the observer's) */
  in[n++] = m->d_hat[1];
  in[n++] = r.yaw_rad;
  in[n++] = r.yaw_rate_rad_s;
  in[n++] = r.yaw_acc_rad_s2;
  in[n++] = b[ECCA_B_HOVER];
  in[n++] = b[ECCA_B_DRAG];
  in[n++] = b[ECCA_B_DRAG];
  in[n++] = b[ECCA_B_MASS];
  in[n++] = b[ECCA_B_G];
  in[n++] = b[ECCA_B_THRUST_MIN];
  in[n++] = b[ECCA_B_THRUST_MAX];
  in[n++] = cos(tilt);
  in[n++] = tan(tilt);
  in[n++] = 0.0; /* fb_share */
  in[n++] = b[ECCA_B_DRAG_EST];
  in[n++] = dt;
  in[n++] = 1.0; /* learn: in the air (OFFBOARD after the takeoff) */
  if (n != ECCA_CORE_N_IN || ecca_tracking_core(in, out) != ECCA_OK) {
    return 0;
  }
  for (i = 0; i < 3; ++i) {
    m->integ[i] = out[9 + i];
  }
  for (i = 0; i < 4; ++i) {
    o->q_d[i] = (float)out[i];
  }
  o->thrust = (float)out[4];
  o->yaw_rate = (float)out[7];
  return 1;
}

void ecca_onboard_step(ecca_onboard *m, double now_s, int offboard, int pos_ok,
                       const double pos[3], const double vel[3], double sample_s,
                       const double q_wxyz[4], ecca_onboard_output *o) {
  double vel_c[3]; /* the velocity the observer and the law get */
  memset(o, 0, sizeof(*o));
  o->final_action = -1;
  if (pos_ok) {
    correct(m, sample_s, pos, vel); /* in every state: converged before OFFBOARD */
  }
  vel_c[0] = m->vc_w > 0.0 ? vel[0] + m->vc_c[0] : vel[0];
  vel_c[1] = m->vc_w > 0.0 ? vel[1] + m->vc_c[1] : vel[1];
  vel_c[2] = vel[2];
  if (m->state == ECCA_STATE_LOADED && offboard) {
    ecca_flat_state r0;
    double dx, dy, dz, err;
    reference_at(m, 0.0, &r0);
    dx = pos[0] - r0.pos_ned_m[0];
    dy = pos[1] - r0.pos_ned_m[1];
    dz = pos[2] - r0.pos_ned_m[2];
    err = sqrt(dx * dx + dy * dy + dz * dz);
    if (!pos_ok || !(err <= (double)m->begin[ECCA_B_START_TOL_M])) {
      m->state = ECCA_STATE_ERROR;
      o->event = ECCA_EV_START_REFUSED;
      o->start_error_m = err;
      o->final_action = (int)m->begin[ECCA_B_FINAL_ACTION] == ECCA_FINAL_LAND ? ECCA_FINAL_LAND
                                                                              : ECCA_FINAL_HOLD;
      return;
    }
    m->state = ECCA_STATE_FLYING;
    m->t0 = now_s;
    m->t_last = now_s;
    m->integ[0] = m->integ[1] = m->integ[2] = 0.0;
    m->v_hat[0] = m->v_hat[1] = m->d_hat[0] = m->d_hat[1] = 0.0;
    m->have_sample = 0;
    m->u_last = 0.0;
    o->event = ECCA_EV_FLYING;
  } else if ((flying(m) || m->state == ECCA_STATE_DONE) && !offboard) {
    if (m->state != ECCA_STATE_DONE) { /* the pilot or a failsafe: stopped for good */
      m->state = ECCA_STATE_STOPPED;
      o->event = ECCA_EV_STOPPED;
    }
    return;
  }
  /* after the final action is commanded the end point is held until PX4 leaves OFFBOARD */
  o->publish_mode = m->state == ECCA_STATE_LOADED || flying(m) || m->state == ECCA_STATE_DONE;
  if ((flying(m) || m->state == ECCA_STATE_DONE) && pos_ok) {
    double t = now_s - m->t0;
    double dt = now_s - m->t_last;
    double total = m->t_start_seg[m->n_expected];
    m->t_last = now_s;
    observe(m, sample_s, vel_c, q_wxyz);
    o->publish_setpoint = control(m, t, sample_s - m->t0, dt > 0.1 ? 0.1 : (dt < 0.0 ? 0.0 : dt),
                                  pos, vel_c, o);
    m->u_last = o->publish_setpoint ? (double)o->thrust : 0.0;
    o->dist_ne[0] = (float)m->d_hat[0];
    o->dist_ne[1] = (float)m->d_hat[1];
    m->progress = total > 0.0 ? (t > total ? 1.0 : t / total) : 1.0;
    if (m->state == ECCA_STATE_FLYING && t >= total) {
      m->state = ECCA_STATE_HOLDING;
      m->t_hold = now_s;
      if (o->event == ECCA_EV_NONE) {
        o->event = ECCA_EV_HOLDING;
      }
    }
    if (m->state == ECCA_STATE_HOLDING && now_s - m->t_hold >= (double)m->begin[ECCA_B_HOLD_S]) {
      m->state = ECCA_STATE_DONE;
      m->t_final = now_s;
      o->final_action = (int)m->begin[ECCA_B_FINAL_ACTION];
      o->event = ECCA_EV_DONE;
    } else if (m->state == ECCA_STATE_DONE && now_s - m->t_final >= 1.0) {
      m->t_final = now_s; /* still in OFFBOARD a second later: the command again */
      o->final_action = (int)m->begin[ECCA_B_FINAL_ACTION];
    }
  }
}
