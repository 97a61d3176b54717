/* bench_gen_c.c: ns per call of the generated setpoint library (built and run by
 * bench/bench_gen_c.py). Each loop makes N calls on varying inputs (segment time sweeps
 * [0, h]) and accumulates a result into a volatile sink so nothing is optimised away. Time is
 * this thread's CPU time (CLOCK_THREAD_CPUTIME_ID: the machine is shared); each loop is repeated
 * and the best repetition is reported.
 * Usage: bench_gen_c [calls_per_loop=1000000] [repetitions=5]
 * Output: one line "name ns_per_call" per benchmark.
 */
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>

#include "ecca_setpoint.h"

static volatile double g_sink;

static double now_s(void) {
  struct timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Keeps the best (smallest) ns per call of a loop of n calls started at t0. */
static void record(double *best, double t0, long n) {
  double ns = (now_s() - t0) / (double)n * 1e9;
  if (ns < *best) {
    *best = ns;
  }
}

#define NSTATES 1024
#define NBENCH 7

static const char *const k_names[NBENCH] = {
    "bezier_eval_double",  "multirotor_setpoint_double", "full_setpoint_double",
    "rover_setpoint_double", "bezier_eval_float", "multirotor_setpoint_float",
    "full_setpoint_float"};

int main(int argc, char **argv) {
  long n = argc > 1 ? atol(argv[1]) : 1000000L;
  int reps = argc > 2 ? atoi(argv[2]) : 5;
  double best[NBENCH];
  int b, r;
  ecca_bezier_segment seg;
  ecca_bezier_segment_f seg_f;
  ecca_multirotor_params p = {1.5, {{0.03, 0.001, 0}, {0.001, 0.03, 0}, {0, 0, 0.05}},
                              9.80665, 0.5, 1.0};
  ecca_multirotor_params_f p_f = {1.5f, {{0.03f, 0.001f, 0}, {0.001f, 0.03f, 0}, {0, 0, 0.05f}},
                                  9.80665f, 0.5f, 1.0f};
  static ecca_flat_state states[NSTATES];
  static ecca_flat_state_f states_f[NSTATES];
  ecca_flat_state s;
  ecca_flat_state_f s_f;
  ecca_attitude_setpoint a;
  ecca_attitude_setpoint_f a_f;
  ecca_heading_setpoint hs;
  double t0, acc = 0.0, h = 4.0;
  long i;
  int k;
  /* A smooth 3-D segment with climbing yaw (control points of a lazy S, m / rad). */
  const double cp[8][3] = {{0, 0, -2}, {1, 0.5, -2.2}, {2.5, 1.5, -2.5}, {4, 1, -3},
                           {5, -0.5, -3.2}, {6.5, -1, -3}, {8, 0, -2.8}, {9, 0.5, -2.5}};
  for (k = 0; k < 8; ++k) {
    seg.ctrl_pts_ned_m[k][0] = cp[k][0];
    seg.ctrl_pts_ned_m[k][1] = cp[k][1];
    seg.ctrl_pts_ned_m[k][2] = cp[k][2];
    seg.yaw_ctrl_pts_rad[k] = 0.1 * k;
    seg_f.ctrl_pts_ned_m[k][0] = (float)cp[k][0];
    seg_f.ctrl_pts_ned_m[k][1] = (float)cp[k][1];
    seg_f.ctrl_pts_ned_m[k][2] = (float)cp[k][2];
    seg_f.yaw_ctrl_pts_rad[k] = 0.1f * (float)k;
  }
  seg.duration_s = h;
  seg_f.duration_s = (float)h;
  for (k = 0; k < NSTATES; ++k) {
    ecca_bezier_eval(&seg, h * k / NSTATES, &states[k]);
    ecca_bezier_eval_f(&seg_f, (float)(h * k / NSTATES), &states_f[k]);
  }

  for (b = 0; b < NBENCH; ++b) {
    best[b] = 1e30;
  }
  for (r = 0; r < reps; ++r) {
    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_bezier_eval(&seg, h * (double)(i & 1023) / 1024.0, &s);
      acc += s.snap_ned_m_s4[2];
    }
    record(&best[0], t0, n);

    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_multirotor_setpoint(&states[i & (NSTATES - 1)], &p, &a);
      acc += a.omega_dot_frd_rad_s2[2];
    }
    record(&best[1], t0, n);

    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_full_setpoint(&seg, h * (double)(i & 1023) / 1024.0, &p, &s, &a);
      acc += a.moment_frd_n_m[0];
    }
    record(&best[2], t0, n);

    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_rover_setpoint(&states[i & (NSTATES - 1)], &hs);
      acc += hs.yaw_acc_rad_s2;
    }
    record(&best[3], t0, n);

    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_bezier_eval_f(&seg_f, (float)h * (float)(i & 1023) / 1024.0f, &s_f);
      acc += s_f.snap_ned_m_s4[2];
    }
    record(&best[4], t0, n);

    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_multirotor_setpoint_f(&states_f[i & (NSTATES - 1)], &p_f, &a_f);
      acc += a_f.omega_dot_frd_rad_s2[2];
    }
    record(&best[5], t0, n);

    t0 = now_s();
    for (i = 0; i < n; ++i) {
      ecca_full_setpoint_f(&seg_f, (float)h * (float)(i & 1023) / 1024.0f, &p_f, &s_f, &a_f);
      acc += a_f.moment_frd_n_m[0];
    }
    record(&best[6], t0, n);
  }
  for (b = 0; b < NBENCH; ++b) {
    printf("%s %.2f\n", k_names[b], best[b]);
  }
  g_sink = acc;
  return 0;
}
