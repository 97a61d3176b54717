/* test_ecca_setpoint.c: checks the ecca_setpoint library against the golden vectors written by
 * `python -m gen_c --vectors` (gen_c/tests/vectors.json), without Python.
 *
 * Usage: test_ecca_setpoint [path/to/vectors.json]
 * Build: cc -std=c99 -Wall -Wextra -Werror -pedantic -I../ecca_setpoint test_ecca_setpoint.c
 *        ../ecca_setpoint/ecca_setpoint.c ../ecca_setpoint/ecca_gen_d.c
 *        ../ecca_setpoint/ecca_gen_f.c -lm
 *
 * Every case runs in double and in float. A field passes when, per component,
 *   |got - expect| <= rtol * max(max_j |expect_j| over the field, 1)
 * with rtol = 1e-12 (double) and 1e-4 (float); flags and singular must match exactly. Also
 * checks the error paths (NaN input, bad duration/mass/wheel base, NULL) leave the outputs
 * untouched.
 * Exit status 0 when everything passes; prints one line per failure and a summary.
 *
 * The JSON reader below is deliberately minimal (objects, arrays, numbers, strings, literals;
 * no escapes other than skipping them): enough for the generator's output, not a general parser.
 */
#include <ctype.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ecca_setpoint.h"

/* ------------------------------------------------------------------ minimal JSON reader */

static const char *ws(const char *p) {
  while (*p != '\0' && isspace((unsigned char)*p)) {
    ++p;
  }
  return p;
}

/* Returns the first character after the JSON value starting at p (NULL on malformed input). */
static const char *skip_value(const char *p) {
  p = ws(p);
  if (*p == '{' || *p == '[') {
    char close = (*p == '{') ? '}' : ']';
    p = ws(p + 1);
    if (*p == close) {
      return p + 1;
    }
    for (;;) {
      if (close == '}') {
        p = skip_value(p); /* key */
        if (p == NULL) {
          return NULL;
        }
        p = ws(p);
        if (*p != ':') {
          return NULL;
        }
        ++p;
      }
      p = skip_value(p);
      if (p == NULL) {
        return NULL;
      }
      p = ws(p);
      if (*p == ',') {
        ++p;
        continue;
      }
      if (*p == close) {
        return p + 1;
      }
      return NULL;
    }
  }
  if (*p == '"') {
    ++p;
    while (*p != '\0' && *p != '"') {
      p += (*p == '\\' && p[1] != '\0') ? 2 : 1;
    }
    return (*p == '"') ? p + 1 : NULL;
  }
  if (*p == '-' || *p == '+' || isdigit((unsigned char)*p) || *p == '.' || isalpha((unsigned char)*p)) {
    while (*p != '\0' && (isalnum((unsigned char)*p) || *p == '-' || *p == '+' || *p == '.')) {
      ++p;
    }
    return p;
  }
  return NULL;
}

/* Value of key in the object starting at obj, or NULL. */
static const char *get(const char *obj, const char *key) {
  const char *p = ws(obj);
  size_t n = strlen(key);
  if (p == NULL || *p != '{') {
    return NULL;
  }
  p = ws(p + 1);
  while (*p == '"') {
    const char *k = p + 1;
    const char *after = skip_value(p);
    if (after == NULL) {
      return NULL;
    }
    p = ws(after);
    if (*p != ':') {
      return NULL;
    }
    p = ws(p + 1);
    if ((size_t)(after - 1 - k) == n && strncmp(k, key, n) == 0) {
      return p;
    }
    p = skip_value(p);
    if (p == NULL) {
      return NULL;
    }
    p = ws(p);
    if (*p == ',') {
      p = ws(p + 1);
    }
  }
  return NULL;
}

/* Element i of the array starting at arr, or NULL. */
static const char *at(const char *arr, int i) {
  const char *p = ws(arr);
  if (p == NULL || *p != '[') {
    return NULL;
  }
  p = ws(p + 1);
  if (*p == ']') {
    return NULL;
  }
  while (i-- > 0) {
    p = skip_value(p);
    if (p == NULL) {
      return NULL;
    }
    p = ws(p);
    if (*p != ',') {
      return NULL;
    }
    p = ws(p + 1);
  }
  return p;
}

static int length(const char *arr) {
  int n = 0;
  while (at(arr, n) != NULL) {
    ++n;
  }
  return n;
}

static int g_parse_errors = 0;

static double num(const char *p) {
  char *end = NULL;
  double v;
  if (p == NULL) {
    ++g_parse_errors;
    return 0.0;
  }
  v = strtod(ws(p), &end);
  if (end == ws(p)) {
    ++g_parse_errors;
  }
  return v;
}

/* Reads up to n numbers of a (possibly nested) array into out, row-major; returns the count. */
static int nums_rec(const char *p, double *out, int n) {
  int count = 0;
  const char *q;
  int i;
  p = ws(p);
  if (*p != '[') {
    if (n >= 1) {
      out[0] = num(p);
      return 1;
    }
    return 0;
  }
  for (i = 0; (q = at(p, i)) != NULL; ++i) {
    count += nums_rec(q, out + count, n - count);
  }
  return count;
}

/* Reads exactly n numbers (a parse error otherwise). */
static void nums(const char *p, double *out, int n) {
  if (p == NULL || nums_rec(p, out, n) != n) {
    ++g_parse_errors;
  }
}

/* ----------------------------------------------------------------------- checking */

static int g_failures = 0;
static int g_checks = 0;

static void check(const char *what, const char *field, const double *got, const char *expect,
                  int n, double rtol) {
  double e[32];
  double scale = 1.0;
  int i;
  if (n > 32) {
    n = 32;
  }
  nums(expect, e, n);
  for (i = 0; i < n; ++i) {
    if (fabs(e[i]) > scale) {
      scale = fabs(e[i]);
    }
  }
  for (i = 0; i < n; ++i) {
    double err = fabs(got[i] - e[i]);
    ++g_checks;
    if (!(err <= rtol * scale)) {
      ++g_failures;
      printf("FAIL %s %s[%d]: got %.17g expected %.17g (err %.3g > %.3g)\n", what, field, i,
             got[i], e[i], err, rtol * scale);
    }
  }
}

static void check_int(const char *what, const char *field, int got, const char *expect) {
  int e = (int)num(expect);
  ++g_checks;
  if (got != e) {
    ++g_failures;
    printf("FAIL %s %s: got %d expected %d\n", what, field, got, e);
  }
}

static void expect_true(const char *what, int cond) {
  ++g_checks;
  if (!cond) {
    ++g_failures;
    printf("FAIL %s\n", what);
  }
}

/* ------------------------------------------------------------- JSON -> double structs */

static void read_segment(const char *j, ecca_bezier_segment *s) {
  nums(get(j, "ctrl_pts_ned_m"), &s->ctrl_pts_ned_m[0][0], 3 * ECCA_BEZIER_NUM_CTRL_PTS);
  nums(get(j, "yaw_ctrl_pts_rad"), s->yaw_ctrl_pts_rad, ECCA_BEZIER_NUM_CTRL_PTS);
  s->duration_s = num(get(j, "duration_s"));
}

static void read_state(const char *j, ecca_flat_state *s) {
  nums(get(j, "pos_ned_m"), s->pos_ned_m, 3);
  nums(get(j, "vel_ned_m_s"), s->vel_ned_m_s, 3);
  nums(get(j, "acc_ned_m_s2"), s->acc_ned_m_s2, 3);
  nums(get(j, "jerk_ned_m_s3"), s->jerk_ned_m_s3, 3);
  nums(get(j, "snap_ned_m_s4"), s->snap_ned_m_s4, 3);
  s->yaw_rad = num(get(j, "yaw_rad"));
  s->yaw_rate_rad_s = num(get(j, "yaw_rate_rad_s"));
  s->yaw_acc_rad_s2 = num(get(j, "yaw_acc_rad_s2"));
}

static void read_params(const char *j, ecca_multirotor_params *p) {
  p->mass_kg = num(get(j, "mass_kg"));
  nums(get(j, "inertia_frd_kg_m2"), &p->inertia_frd_kg_m2[0][0], 9);
  p->gravity_m_s2 = num(get(j, "gravity_m_s2"));
  p->hover_thrust = num(get(j, "hover_thrust"));
  p->drag_n_s_m = num(get(j, "drag_n_s_m"));
}

/* ----------------------------------------------------------- double <-> float structs */

static void to_f(const double *x, float *y, int n) {
  int i;
  for (i = 0; i < n; ++i) {
    y[i] = (float)x[i];
  }
}

static void to_d(const float *x, double *y, int n) {
  int i;
  for (i = 0; i < n; ++i) {
    y[i] = (double)x[i];
  }
}

static void segment_f(const ecca_bezier_segment *s, ecca_bezier_segment_f *f) {
  to_f(&s->ctrl_pts_ned_m[0][0], &f->ctrl_pts_ned_m[0][0], 3 * ECCA_BEZIER_NUM_CTRL_PTS);
  to_f(s->yaw_ctrl_pts_rad, f->yaw_ctrl_pts_rad, ECCA_BEZIER_NUM_CTRL_PTS);
  f->duration_s = (float)s->duration_s;
}

static void state_f(const ecca_flat_state *s, ecca_flat_state_f *f) {
  to_f(s->pos_ned_m, f->pos_ned_m, 3);
  to_f(s->vel_ned_m_s, f->vel_ned_m_s, 3);
  to_f(s->acc_ned_m_s2, f->acc_ned_m_s2, 3);
  to_f(s->jerk_ned_m_s3, f->jerk_ned_m_s3, 3);
  to_f(s->snap_ned_m_s4, f->snap_ned_m_s4, 3);
  f->yaw_rad = (float)s->yaw_rad;
  f->yaw_rate_rad_s = (float)s->yaw_rate_rad_s;
  f->yaw_acc_rad_s2 = (float)s->yaw_acc_rad_s2;
}

static void state_d(const ecca_flat_state_f *f, ecca_flat_state *s) {
  to_d(f->pos_ned_m, s->pos_ned_m, 3);
  to_d(f->vel_ned_m_s, s->vel_ned_m_s, 3);
  to_d(f->acc_ned_m_s2, s->acc_ned_m_s2, 3);
  to_d(f->jerk_ned_m_s3, s->jerk_ned_m_s3, 3);
  to_d(f->snap_ned_m_s4, s->snap_ned_m_s4, 3);
  s->yaw_rad = f->yaw_rad;
  s->yaw_rate_rad_s = f->yaw_rate_rad_s;
  s->yaw_acc_rad_s2 = f->yaw_acc_rad_s2;
}

static void params_f(const ecca_multirotor_params *p, ecca_multirotor_params_f *f) {
  f->mass_kg = (float)p->mass_kg;
  to_f(&p->inertia_frd_kg_m2[0][0], &f->inertia_frd_kg_m2[0][0], 9);
  f->gravity_m_s2 = (float)p->gravity_m_s2;
  f->hover_thrust = (float)p->hover_thrust;
  f->drag_n_s_m = (float)p->drag_n_s_m;
}

static void attitude_d(const ecca_attitude_setpoint_f *f, ecca_attitude_setpoint *s) {
  s->thrust_n = f->thrust_n;
  s->thrust_dot_n_s = f->thrust_dot_n_s;
  s->thrust_ddot_n_s2 = f->thrust_ddot_n_s2;
  s->thrust_norm = f->thrust_norm;
  to_d(f->q_wxyz, s->q_wxyz, 4);
  to_d(f->omega_frd_rad_s, s->omega_frd_rad_s, 3);
  to_d(f->omega_dot_frd_rad_s2, s->omega_dot_frd_rad_s2, 3);
  to_d(f->moment_frd_n_m, s->moment_frd_n_m, 3);
  s->flags = f->flags;
  s->singular = f->singular;
}

static void heading_d(const ecca_heading_setpoint_f *f, ecca_heading_setpoint *s) {
  s->yaw_rad = f->yaw_rad;
  s->speed_m_s = f->speed_m_s;
  s->speed_dot_m_s2 = f->speed_dot_m_s2;
  s->yaw_rate_rad_s = f->yaw_rate_rad_s;
  s->yaw_acc_rad_s2 = f->yaw_acc_rad_s2;
  s->singular = f->singular;
}

static void steering_d(const ecca_steering_setpoint_f *f, ecca_steering_setpoint *s) {
  heading_d(&f->heading, &s->heading);
  s->curvature_1_m = f->curvature_1_m;
  s->curvature_rate_1_m_s = f->curvature_rate_1_m_s;
  s->steer_angle_rad = f->steer_angle_rad;
  s->steer_rate_rad_s = f->steer_rate_rad_s;
}

/* ----------------------------------------------------------------- field comparisons */

static void check_state(const char *what, const ecca_flat_state *s, const char *e, double rtol) {
  check(what, "pos_ned_m", s->pos_ned_m, get(e, "pos_ned_m"), 3, rtol);
  check(what, "vel_ned_m_s", s->vel_ned_m_s, get(e, "vel_ned_m_s"), 3, rtol);
  check(what, "acc_ned_m_s2", s->acc_ned_m_s2, get(e, "acc_ned_m_s2"), 3, rtol);
  check(what, "jerk_ned_m_s3", s->jerk_ned_m_s3, get(e, "jerk_ned_m_s3"), 3, rtol);
  check(what, "snap_ned_m_s4", s->snap_ned_m_s4, get(e, "snap_ned_m_s4"), 3, rtol);
  check(what, "yaw_rad", &s->yaw_rad, get(e, "yaw_rad"), 1, rtol);
  check(what, "yaw_rate_rad_s", &s->yaw_rate_rad_s, get(e, "yaw_rate_rad_s"), 1, rtol);
  check(what, "yaw_acc_rad_s2", &s->yaw_acc_rad_s2, get(e, "yaw_acc_rad_s2"), 1, rtol);
}

static void check_attitude(const char *what, const ecca_attitude_setpoint *s, const char *e,
                           double rtol) {
  check(what, "thrust_n", &s->thrust_n, get(e, "thrust_n"), 1, rtol);
  check(what, "thrust_dot_n_s", &s->thrust_dot_n_s, get(e, "thrust_dot_n_s"), 1, rtol);
  check(what, "thrust_ddot_n_s2", &s->thrust_ddot_n_s2, get(e, "thrust_ddot_n_s2"), 1, rtol);
  check(what, "thrust_norm", &s->thrust_norm, get(e, "thrust_norm"), 1, rtol);
  check(what, "q_wxyz", s->q_wxyz, get(e, "q_wxyz"), 4, rtol);
  check(what, "omega_frd_rad_s", s->omega_frd_rad_s, get(e, "omega_frd_rad_s"), 3, rtol);
  check(what, "omega_dot_frd_rad_s2", s->omega_dot_frd_rad_s2, get(e, "omega_dot_frd_rad_s2"),
        3, rtol);
  check(what, "moment_frd_n_m", s->moment_frd_n_m, get(e, "moment_frd_n_m"), 3, rtol);
  check_int(what, "flags", (int)s->flags, get(e, "flags"));
  check_int(what, "singular", s->singular, get(e, "singular"));
}

static void check_heading(const char *what, const ecca_heading_setpoint *s, const char *e,
                          double rtol) {
  check(what, "yaw_rad", &s->yaw_rad, get(e, "yaw_rad"), 1, rtol);
  check(what, "speed_m_s", &s->speed_m_s, get(e, "speed_m_s"), 1, rtol);
  check(what, "speed_dot_m_s2", &s->speed_dot_m_s2, get(e, "speed_dot_m_s2"), 1, rtol);
  check(what, "yaw_rate_rad_s", &s->yaw_rate_rad_s, get(e, "yaw_rate_rad_s"), 1, rtol);
  check(what, "yaw_acc_rad_s2", &s->yaw_acc_rad_s2, get(e, "yaw_acc_rad_s2"), 1, rtol);
  check_int(what, "singular", s->singular, get(e, "singular"));
}

static void check_steering(const char *what, const ecca_steering_setpoint *s, const char *e,
                           double rtol) {
  check_heading(what, &s->heading, e, rtol);
  check(what, "curvature_1_m", &s->curvature_1_m, get(e, "curvature_1_m"), 1, rtol);
  check(what, "curvature_rate_1_m_s", &s->curvature_rate_1_m_s, get(e, "curvature_rate_1_m_s"),
        1, rtol);
  check(what, "steer_angle_rad", &s->steer_angle_rad, get(e, "steer_angle_rad"), 1, rtol);
  check(what, "steer_rate_rad_s", &s->steer_rate_rad_s, get(e, "steer_rate_rad_s"), 1, rtol);
}

#ifndef RTOL_D
#define RTOL_D 1e-12
#endif
#ifndef RTOL_F
#define RTOL_F 1e-4
#endif

static void run_bezier(const char *c, int idx) {
  ecca_bezier_segment seg;
  ecca_bezier_segment_f seg_f;
  ecca_flat_state out, out_fd;
  ecca_flat_state_f out_f;
  char what[64];
  double t = num(get(c, "t_s"));
  read_segment(get(c, "segment"), &seg);
  segment_f(&seg, &seg_f);
  sprintf(what, "bezier[%d] double", idx);
  expect_true(what, ecca_bezier_eval(&seg, t, &out) == ECCA_OK);
  check_state(what, &out, get(c, "expect"), RTOL_D);
  sprintf(what, "bezier[%d] float", idx);
  expect_true(what, ecca_bezier_eval_f(&seg_f, (float)t, &out_f) == ECCA_OK);
  state_d(&out_f, &out_fd);
  check_state(what, &out_fd, get(c, "expect"), RTOL_F);
}

static void run_multirotor(const char *c, int idx) {
  ecca_flat_state st;
  ecca_flat_state_f st_f;
  ecca_multirotor_params pr;
  ecca_multirotor_params_f pr_f;
  ecca_attitude_setpoint out, out_fd;
  ecca_attitude_setpoint_f out_f;
  char what[96];
  const char *name = get(c, "name");
  int len = 0;
  if (name != NULL) {
    len = (int)(skip_value(name) - name) - 2;
    if (len > 40 || len < 0) {
      len = 40;
    }
  }
  read_state(get(c, "state"), &st);
  read_params(get(c, "params"), &pr);
  state_f(&st, &st_f);
  params_f(&pr, &pr_f);
  sprintf(what, "multirotor[%d] %.*s double", idx, len, name != NULL ? name + 1 : "");
  expect_true(what, ecca_multirotor_setpoint(&st, &pr, &out) == ECCA_OK);
  check_attitude(what, &out, get(c, "expect"), RTOL_D);
  sprintf(what, "multirotor[%d] %.*s float", idx, len, name != NULL ? name + 1 : "");
  expect_true(what, ecca_multirotor_setpoint_f(&st_f, &pr_f, &out_f) == ECCA_OK);
  attitude_d(&out_f, &out_fd);
  check_attitude(what, &out_fd, get(c, "expect"), RTOL_F);
}

static void run_rover(const char *c, int idx) {
  ecca_flat_state st;
  ecca_flat_state_f st_f;
  ecca_heading_setpoint out, out_fd;
  ecca_heading_setpoint_f out_f;
  char what[64];
  read_state(get(c, "state"), &st);
  state_f(&st, &st_f);
  sprintf(what, "rover[%d] double", idx);
  expect_true(what, ecca_rover_setpoint(&st, &out) == ECCA_OK);
  check_heading(what, &out, get(c, "expect"), RTOL_D);
  sprintf(what, "rover[%d] float", idx);
  expect_true(what, ecca_rover_setpoint_f(&st_f, &out_f) == ECCA_OK);
  heading_d(&out_f, &out_fd);
  check_heading(what, &out_fd, get(c, "expect"), RTOL_F);
}

static void run_full(const char *c, int idx) {
  ecca_bezier_segment seg;
  ecca_bezier_segment_f seg_f;
  ecca_multirotor_params pr;
  ecca_multirotor_params_f pr_f;
  ecca_flat_state st, st_fd;
  ecca_flat_state_f st_f;
  ecca_attitude_setpoint out, out_fd;
  ecca_attitude_setpoint_f out_f;
  char what[64];
  double t = num(get(c, "t_s"));
  read_segment(get(c, "segment"), &seg);
  read_params(get(c, "params"), &pr);
  segment_f(&seg, &seg_f);
  params_f(&pr, &pr_f);
  sprintf(what, "full[%d] double", idx);
  expect_true(what, ecca_full_setpoint(&seg, t, &pr, &st, &out) == ECCA_OK);
  check_state(what, &st, get(c, "expect_state"), RTOL_D);
  check_attitude(what, &out, get(c, "expect"), RTOL_D);
  sprintf(what, "full[%d] float", idx);
  expect_true(what, ecca_full_setpoint_f(&seg_f, (float)t, &pr_f, &st_f, &out_f) == ECCA_OK);
  state_d(&st_f, &st_fd);
  attitude_d(&out_f, &out_fd);
  check_state(what, &st_fd, get(c, "expect_state"), RTOL_F);
  check_attitude(what, &out_fd, get(c, "expect"), RTOL_F);
}

static void run_ackermann(const char *c, int idx) {
  ecca_flat_state st;
  ecca_flat_state_f st_f;
  ecca_steering_setpoint out, out_fd;
  ecca_steering_setpoint_f out_f;
  char what[64];
  double wheel_base = num(get(c, "wheel_base_m"));
  read_state(get(c, "state"), &st);
  state_f(&st, &st_f);
  sprintf(what, "ackermann[%d] double", idx);
  expect_true(what, ecca_ackermann_setpoint(&st, wheel_base, &out) == ECCA_OK);
  check_steering(what, &out, get(c, "expect"), RTOL_D);
  sprintf(what, "ackermann[%d] float", idx);
  expect_true(what, ecca_ackermann_setpoint_f(&st_f, (float)wheel_base, &out_f) == ECCA_OK);
  steering_d(&out_f, &out_fd);
  check_steering(what, &out_fd, get(c, "expect"), RTOL_F);
}

static void run_full_ackermann(const char *c, int idx) {
  ecca_bezier_segment seg;
  ecca_bezier_segment_f seg_f;
  ecca_flat_state st, st_fd;
  ecca_flat_state_f st_f;
  ecca_steering_setpoint out, out_fd;
  ecca_steering_setpoint_f out_f;
  char what[64];
  double t = num(get(c, "t_s"));
  double wheel_base = num(get(c, "wheel_base_m"));
  read_segment(get(c, "segment"), &seg);
  segment_f(&seg, &seg_f);
  sprintf(what, "full_ackermann[%d] double", idx);
  expect_true(what, ecca_full_ackermann_setpoint(&seg, t, wheel_base, &st, &out) == ECCA_OK);
  check_state(what, &st, get(c, "expect_state"), RTOL_D);
  check_steering(what, &out, get(c, "expect"), RTOL_D);
  sprintf(what, "full_ackermann[%d] float", idx);
  expect_true(what, ecca_full_ackermann_setpoint_f(&seg_f, (float)t, (float)wheel_base, &st_f,
                                                   &out_f) == ECCA_OK);
  state_d(&st_f, &st_fd);
  steering_d(&out_f, &out_fd);
  check_state(what, &st_fd, get(c, "expect_state"), RTOL_F);
  check_steering(what, &out_fd, get(c, "expect"), RTOL_F);
}

/* Ackermann: a bad wheel base or state is refused with the outputs untouched. */
static void run_ackermann_error_paths(const char *vectors) {
  ecca_bezier_segment seg;
  ecca_flat_state st, sentinel_st;
  ecca_steering_setpoint ks, sentinel_ks;
  const double bad[] = {0.0, -0.5, 2e12, HUGE_VAL, -HUGE_VAL, 0.0};
  int i;
  read_segment(get(at(get(vectors, "full_ackermann"), 0), "segment"), &seg);
  read_state(get(at(get(vectors, "ackermann"), 0), "state"), &st);
  memset(&sentinel_st, 0x5a, sizeof sentinel_st);
  memset(&sentinel_ks, 0x5a, sizeof sentinel_ks);
  for (i = 0; i < 6; ++i) {
    double wb = (i == 5) ? nan("") : bad[i];
    ecca_flat_state so = sentinel_st;
    ks = sentinel_ks;
    expect_true("ackermann error: bad wheel base",
                ecca_ackermann_setpoint(&st, wb, &ks) == ECCA_ERR_INPUT &&
                    memcmp(&ks, &sentinel_ks, sizeof ks) == 0);
    expect_true("full ackermann error: bad wheel base",
                ecca_full_ackermann_setpoint(&seg, 0.5, wb, &so, &ks) == ECCA_ERR_INPUT &&
                    memcmp(&ks, &sentinel_ks, sizeof ks) == 0 &&
                    memcmp(&so, &sentinel_st, sizeof so) == 0);
  }
  st.jerk_ned_m_s3[1] = nan("");
  expect_true("ackermann error: NaN jerk",
              ecca_ackermann_setpoint(&st, 0.5, &ks) == ECCA_ERR_INPUT &&
                  memcmp(&ks, &sentinel_ks, sizeof ks) == 0);
  st.jerk_ned_m_s3[1] = 0.0;
  st.jerk_ned_m_s3[2] = nan(""); /* z is not an input */
  expect_true("ackermann ok: z ignored", ecca_ackermann_setpoint(&st, 0.5, &ks) == ECCA_OK);
  seg.duration_s = -1.0;
  ks = sentinel_ks;
  expect_true("full ackermann error: negative duration",
              ecca_full_ackermann_setpoint(&seg, 0.5, 0.5, NULL, &ks) == ECCA_ERR_INPUT &&
                  memcmp(&ks, &sentinel_ks, sizeof ks) == 0);
  expect_true("ackermann error: NULL",
              ecca_ackermann_setpoint(NULL, 0.5, &ks) == ECCA_ERR_NULL &&
                  ecca_ackermann_setpoint(&st, 0.5, NULL) == ECCA_ERR_NULL &&
                  ecca_full_ackermann_setpoint(NULL, 0.5, 0.5, NULL, &ks) == ECCA_ERR_NULL &&
                  ecca_ackermann_setpoint_f(NULL, 0.5f, NULL) == ECCA_ERR_NULL);
}

/* Invalid inputs: an error code and untouched outputs (bit-identical sentinel). */
static void run_error_paths(const char *vectors) {
  ecca_bezier_segment seg;
  ecca_flat_state st, sentinel_st;
  ecca_multirotor_params pr;
  ecca_attitude_setpoint out, sentinel;
  ecca_heading_setpoint hs, sentinel_hs;
  read_segment(get(at(get(vectors, "full"), 0), "segment"), &seg);
  read_params(get(at(get(vectors, "full"), 0), "params"), &pr);
  memset(&sentinel, 0x5a, sizeof sentinel);
  memset(&sentinel_st, 0x5a, sizeof sentinel_st);
  memset(&sentinel_hs, 0x5a, sizeof sentinel_hs);

  out = sentinel;
  st = sentinel_st;
  seg.duration_s = 0.0;
  expect_true("error: zero duration", ecca_full_setpoint(&seg, 0.1, &pr, &st, &out) ==
                                          ECCA_ERR_INPUT);
  expect_true("error: zero duration leaves outputs",
              memcmp(&out, &sentinel, sizeof out) == 0 &&
                  memcmp(&st, &sentinel_st, sizeof st) == 0);
  seg.duration_s = 1e-5; /* snap ~ 1e21: finite (evaluation ok) but no flyable setpoint */
  expect_true("tiny duration: evaluation ok", ecca_bezier_eval(&seg, 0.0, &st) == ECCA_OK);
  st = sentinel_st;
  expect_true("tiny duration: full setpoint refused",
              ecca_full_setpoint(&seg, 0.0, &pr, &st, &out) == ECCA_ERR_INPUT &&
                  memcmp(&out, &sentinel, sizeof out) == 0 &&
                  memcmp(&st, &sentinel_st, sizeof st) == 0);
  seg.duration_s = 1.0;
  expect_true("error: NaN time", ecca_bezier_eval(&seg, nan(""), &st) == ECCA_ERR_INPUT);
  expect_true("error: NaN time leaves outputs", memcmp(&st, &sentinel_st, sizeof st) == 0);
  seg.ctrl_pts_ned_m[3][1] = HUGE_VAL;
  expect_true("error: infinite control point",
              ecca_bezier_eval(&seg, 0.5, &st) == ECCA_ERR_INPUT);
  seg.ctrl_pts_ned_m[3][1] = 0.0;
  expect_true("ok after repair", ecca_bezier_eval(&seg, 0.5, &st) == ECCA_OK);
  st.acc_ned_m_s2[2] = nan("");
  expect_true("error: NaN acceleration", ecca_multirotor_setpoint(&st, &pr, &out) ==
                                             ECCA_ERR_INPUT);
  expect_true("error: NaN acceleration leaves outputs",
              memcmp(&out, &sentinel, sizeof out) == 0);
  expect_true("error: NaN velocity (rover)",
              (st.vel_ned_m_s[0] = nan(""), ecca_rover_setpoint(&st, &hs) == ECCA_ERR_INPUT));
  st.vel_ned_m_s[0] = 0.0;
  st.acc_ned_m_s2[2] = 0.0;
  st.snap_ned_m_s4[1] = 2e12; /* finite but beyond ECCA_INPUT_LIMIT, like the Python path */
  out = sentinel;
  expect_true("error: input beyond limit", ecca_multirotor_setpoint(&st, &pr, &out) ==
                                               ECCA_ERR_INPUT);
  expect_true("error: input beyond limit leaves outputs",
              memcmp(&out, &sentinel, sizeof out) == 0);
  st.snap_ned_m_s4[1] = 0.9e12;
  expect_true("ok just inside the limit", ecca_multirotor_setpoint(&st, &pr, &out) == ECCA_OK);
  st.snap_ned_m_s4[1] = 0.0;
  pr.mass_kg = -1.0;
  expect_true("error: negative mass", ecca_multirotor_setpoint(&st, &pr, &out) ==
                                          ECCA_ERR_INPUT);
  pr.mass_kg = 1.0;
  pr.hover_thrust = 1.5;
  expect_true("error: hover thrust > 1", ecca_multirotor_setpoint(&st, &pr, &out) ==
                                             ECCA_ERR_INPUT);
  pr.hover_thrust = 0.5;
  expect_true("error: NULL", ecca_multirotor_setpoint(&st, &pr, NULL) == ECCA_ERR_NULL &&
                                 ecca_bezier_eval(NULL, 0.0, &st) == ECCA_ERR_NULL &&
                                 ecca_rover_setpoint_f(NULL, NULL) == ECCA_ERR_NULL);
  hs = sentinel_hs;
  expect_true("ok after repair (rover)", ecca_rover_setpoint(&st, &hs) == ECCA_OK &&
                                             memcmp(&hs, &sentinel_hs, sizeof hs) != 0);
  expect_true("casadi version string", strlen(ecca_setpoint_casadi_version()) >= 5);
}

int main(int argc, char **argv) {
  const char *path = argc > 1 ? argv[1] : "vectors.json";
  FILE *f = fopen(path, "rb");
  char *text;
  long size;
  const char *arr;
  int i, n, total = 0;
  if (f == NULL) {
    fprintf(stderr, "cannot open %s\n", path);
    return 2;
  }
  fseek(f, 0, SEEK_END);
  size = ftell(f);
  fseek(f, 0, SEEK_SET);
  text = (char *)malloc((size_t)size + 1);
  if (text == NULL || fread(text, 1, (size_t)size, f) != (size_t)size) {
    fprintf(stderr, "cannot read %s\n", path);
    fclose(f);
    free(text);
    return 2;
  }
  text[size] = '\0';
  fclose(f);
  if (skip_value(text) == NULL) {
    fprintf(stderr, "%s: malformed JSON\n", path);
    free(text);
    return 2;
  }
  if ((int)num(get(text, "bezier_degree")) != ECCA_BEZIER_DEGREE) {
    fprintf(stderr, "%s: vectors are for another Bezier degree\n", path);
    free(text);
    return 2;
  }
  arr = get(text, "bezier");
  n = length(arr);
  for (i = 0; i < n; ++i) {
    run_bezier(at(arr, i), i);
  }
  total += n;
  arr = get(text, "multirotor");
  n = length(arr);
  for (i = 0; i < n; ++i) {
    run_multirotor(at(arr, i), i);
  }
  total += n;
  arr = get(text, "rover");
  n = length(arr);
  for (i = 0; i < n; ++i) {
    run_rover(at(arr, i), i);
  }
  total += n;
  arr = get(text, "full");
  n = length(arr);
  for (i = 0; i < n; ++i) {
    run_full(at(arr, i), i);
  }
  total += n;
  arr = get(text, "ackermann");
  n = length(arr);
  for (i = 0; i < n; ++i) {
    run_ackermann(at(arr, i), i);
  }
  total += n;
  arr = get(text, "full_ackermann");
  n = length(arr);
  for (i = 0; i < n; ++i) {
    run_full_ackermann(at(arr, i), i);
  }
  total += n;
  run_error_paths(text);
  if (get(text, "ackermann") != NULL && get(text, "full_ackermann") != NULL) {
    run_ackermann_error_paths(text);
  } else {
    printf("FAIL no ackermann vectors\n");
    ++g_failures;
  }
  free(text);
  if (g_parse_errors != 0) {
    printf("FAIL %d JSON parse errors\n", g_parse_errors);
    ++g_failures;
  }
  if (total < 4) {
    printf("FAIL only %d cases found\n", total);
    ++g_failures;
  }
  printf("%s: %d cases, %d checks, %d failures\n", g_failures == 0 ? "PASS" : "FAIL", total,
         g_checks, g_failures);
  return g_failures == 0 ? 0 : 1;
}
