/* ecca_onboard_core.h: the onboard module's logic without PX4 (hand-written): the upload
 * protocol's receiving end, the trajectory, the flight's state machine and the law
 * (ecca_tracking_core). ecca_onboard.c wires it to uORB inside PX4; the tests and the mock call
 * the same C through ctypes (gen_c.onboard_native). C99, no allocation, no globals: all state
 * is in one ecca_onboard struct the caller owns (~35 KB).
 */
#ifndef ECCA_ONBOARD_CORE_H
#define ECCA_ONBOARD_CORE_H

#include <stdint.h>

#include "ecca_onboard_proto.h"

#ifdef __cplusplus
extern "C" {
#endif

/** An acknowledgement to send as COMMAND_ACK (to peer_sys / peer_comp). */
typedef struct {
  uint32_t command; /**< ECCA_ACK_CMD or ECCA_ACK_CRC */
  uint8_t result;   /**< MAV_RESULT */
  uint8_t state;    /**< ECCA_STATE_* (COMMAND_ACK.progress) */
  int32_t value;    /**< COMMAND_ACK.result_param2 */
} ecca_onboard_ack;

/* ecca_onboard_output.event */
#define ECCA_EV_NONE 0
#define ECCA_EV_FLYING 1        /* the trajectory's clock started */
#define ECCA_EV_HOLDING 2       /* past the last segment */
#define ECCA_EV_DONE 3          /* the final action is due (final_action) */
#define ECCA_EV_STOPPED 4       /* OFFBOARD left while flying */
#define ECCA_EV_START_REFUSED 5 /* too far from the start (start_error_m): final_action is due */

/** What one step asks the PX4 side to do. */
typedef struct {
  int publish_mode;     /**< publish offboard_control_mode (attitude) now */
  int publish_setpoint; /**< publish vehicle_attitude_setpoint from the fields below */
  float q_d[4];         /**< desired attitude, body FRD -> NED (w, x, y, z) */
  float thrust;         /**< normalised thrust (thrust_body[2] = -thrust) */
  float yaw_rate;       /**< yaw rate feed-forward [rad/s] */
  int final_action;     /**< -1, or ECCA_FINAL_* to command now (once) */
  int event;            /**< ECCA_EV_* */
  double start_error_m; /**< distance from the start point when the start was refused */
  float dist_ne[2];     /**< the disturbance estimate in use, north, east [m/s^2] */
} ecca_onboard_output;

typedef struct {
  float duration;
  float ctrl[8][3];
  float yaw[8];
} ecca_onboard_segment;

/** All the module's state. */
typedef struct {
  int state;
  int n_expected;
  int n_received;
  uint8_t have[ECCA_MAX_SEGMENTS];
  float begin[ECCA_B_COUNT];
  ecca_onboard_segment seg[ECCA_MAX_SEGMENTS];
  double t_start_seg[ECCA_MAX_SEGMENTS + 1];
  uint32_t crc;
  uint8_t peer_sys;
  uint8_t peer_comp;
  double t0;
  double t_hold;
  double t_last;
  double integ[3];
  double progress;
  double t_final; /* when the final action was last commanded */
  /* the disturbance observer (ecca_disturbance_step): velocity and disturbance estimate
   * north, east; the time of the last velocity sample fused; the last commanded thrust */
  double v_hat[2];
  double d_hat[2];
  double t_sample;
  int have_sample;
  double u_last;
  /* the velocity correction (ecca_velocity_correction_step): its frequency in use [rad/s]
   * (ECCA_VCORR_DEFAULT_RAD_S until a BEGIN is accepted, then that upload's); the filtered
   * position, the last sample's reported velocity and the correction north, east; the time of
   * the last position sample fused */
  double vc_w;
  double vc_p[2];
  double vc_v[2];
  double vc_c[2];
  double vc_t;
  int vc_have;
} ecca_onboard;

/* The disturbance observer's tuning besides its bandwidth (ECCA_B_DIST_BW, uploaded):
 * companion.control.estimation.DisturbanceConfig's defaults: bound of the estimate [m/s^2],
 * no update below this commanded thrust [normalised]. */
#define ECCA_DIST_MAX_ACC 8.0
#define ECCA_DIST_MIN_THRUST 0.05

/* The velocity correction (companion.mavlink.velocity_correction's constants): its frequency
 * before an upload brings one (ECCA_B_VCORR_RAD_S) [rad/s], the bound of each axis of the
 * correction [m/s], the innovation that is an estimator reset [m]. */
#define ECCA_VCORR_DEFAULT_RAD_S 4.0
#define ECCA_VCORR_MAX_M_S 1.0
#define ECCA_VCORR_RESET_M 1.0

/* The law compares a position sample with the reference at the sample's time: the module steps
 * at its own rate (PX4: every 4 ms) on the latest vehicle_local_position, 4-8 ms old on the SIH
 * (mean ~5 ms), and comparing it with the reference at the step's time made the vehicle fly
 * that much ahead of the trajectory. A sample older than this [s] counts as this old. */
#define ECCA_SAMPLE_AGE_MAX_S 0.1

/** A fresh module: ECCA_STATE_READY, no trajectory, no peer. */
void ecca_onboard_init(ecca_onboard *m);

/** Take one protocol message (opcode `op`, 58 floats); 1 if `ack` is to be sent. */
int ecca_onboard_message(ecca_onboard *m, int op, const float *data, ecca_onboard_ack *ack);

/** The periodic status report (an ECCA_OP_STATUS acknowledgement). */
void ecca_onboard_status(const ecca_onboard *m, ecca_onboard_ack *ack);

/** The start report (ECCA_ACK_START) to send with a status report; 0 while not flown. The
 *  step clock must be the autopilot's (seconds since boot). */
int ecca_onboard_start_report(const ecca_onboard *m, ecca_onboard_ack *ack);

/** One control step at `now_s` [s, any monotonic clock]: `offboard` = armed in OFFBOARD,
 *  `pos_ok` = position and velocity valid, `pos` / `vel` the estimate [m, m/s NED] sampled at
 *  `sample_s` [s, the same clock; a sample is fused into the velocity correction and the
 *  disturbance observer once; the law takes its errors against the reference at that time],
 *  `q_wxyz` the estimated attitude (body FRD -> NED; NULL or not
 *  a unit quaternion: the observer does not learn). In every state, each new valid sample
 *  updates the horizontal velocity correction (ecca_velocity_correction_step, the companion's:
 *  what to add to `vel` for a velocity that agrees with how `pos` moves) at the frequency
 *  ECCA_VCORR_DEFAULT_RAD_S, or the last accepted upload's (ECCA_B_VCORR_RAD_S; 0: off, no
 *  correction); it carries on across flights, so it has converged before OFFBOARD. The
 *  corrected velocity is what the observer and the law get. While flying, the disturbance
 *  observer (ecca_disturbance_step) runs on the horizontal velocity with the model's
 *  acceleration -(u g / h) z_b,h - (D / m) v_h (u: the thrust commanded by the previous step)
 *  and its estimate is the tracking core's disturbance feed-forward; it starts from zero with
 *  each flight, like the integrator. */
void ecca_onboard_step(ecca_onboard *m, double now_s, int offboard, int pos_ok,
                       const double pos[3], const double vel[3], double sample_s,
                       const double q_wxyz[4], ecca_onboard_output *out);

/** sizeof(ecca_onboard), for callers that allocate it (ctypes). */
unsigned long ecca_onboard_size(void);

#ifdef __cplusplus
}
#endif

#endif /* ECCA_ONBOARD_CORE_H */
