/* ecca_onboard_proto.h: the trajectory upload protocol between the companion and the
 * ecca_onboard PX4 module (hand-written; companion/onboard/protocol.py mirrors these numbers and
 * tests/gen_c/test_onboard_proto.py checks that both agree).
 *
 * Companion -> module: MAVLink DEBUG_FLOAT_ARRAY (id 350; PX4's mavlink_receiver publishes it
 * as uORB debug_array) named "ecca", array_id = an ECCA_OP_* opcode, data[58] float32.
 * Module -> companion: uORB vehicle_command_ack, sent by PX4 as MAVLink COMMAND_ACK to the
 * companion (target system/component from ECCA_OP_BEGIN / ECCA_OP_STATUS):
 *   command ECCA_ACK_CMD: progress = module state (ECCA_STATE_*), result = MAV_RESULT,
 *     result_param2 = (opcode << 24) | value (24 bits: the segment index acknowledged; in a
 *     status report the segments held, or from the start of the flight the trajectory's
 *     clock in ms);
 *   command ECCA_ACK_CRC: the answer to ECCA_OP_COMMIT, result_param2 = the module's CRC-32
 *     of the upload (ACCEPTED: equal to the companion's; DENIED: it differs or a part is
 *     missing), progress = state.
 * One message in flight at a time (debug_array holds one): the companion sends the next part
 * after the previous one's acknowledgement and sends a part again when none came.
 */
#ifndef ECCA_ONBOARD_PROTO_H
#define ECCA_ONBOARD_PROTO_H

#define ECCA_PROTO_VERSION 4
#define ECCA_PROTO_NAME "ecca"
#define ECCA_MAX_SEGMENTS 256

/* opcodes (DEBUG_FLOAT_ARRAY.array_id) */
#define ECCA_OP_BEGIN 1   /* a new upload: header and the law's parameters (ECCA_B_*) */
#define ECCA_OP_SEGMENT 2 /* one degree-7 segment (ECCA_S_*) */
#define ECCA_OP_COMMIT 3  /* data[0], data[1]: low and high 16 bits of the CRC-32 */
#define ECCA_OP_ABORT 4   /* drop the trajectory (refused while flying) */
#define ECCA_OP_STATUS 5  /* data[0], data[1]: the sender's system and component id */

/* module states (COMMAND_ACK.progress) */
#define ECCA_STATE_READY 0     /* running, no trajectory */
#define ECCA_STATE_RECEIVING 1 /* an upload is under way */
#define ECCA_STATE_LOADED 2    /* a verified trajectory: offboard_control_mode is published */
#define ECCA_STATE_FLYING 3    /* armed in OFFBOARD, flying the trajectory */
#define ECCA_STATE_HOLDING 4   /* past the last segment, holding its end point */
#define ECCA_STATE_DONE 5      /* the final action was commanded */
#define ECCA_STATE_STOPPED 6   /* the pilot (or a failsafe) left OFFBOARD: stopped for good */
#define ECCA_STATE_ERROR 7     /* refused to fly (e.g. the vehicle far from the start) */

/* acknowledgement commands (MAV_CMD_USER_1 / _2: commander never sends these) */
#define ECCA_ACK_CMD 31010
#define ECCA_ACK_CRC 31011
#define ECCA_ACK_START 31012 /* with each status report while flying: result_param2 = the
                                trajectory's start on the autopilot's clock [ms since boot,
                                the clock of LOCAL_POSITION_NED.time_boot_ms] */

/* final actions (ECCA_B_FINAL_ACTION) */
#define ECCA_FINAL_HOLD 0
#define ECCA_FINAL_LAND 1
#define ECCA_FINAL_RTL 2

/* ECCA_OP_BEGIN data layout */
#define ECCA_B_VERSION 0
#define ECCA_B_N_SEGMENTS 1
#define ECCA_B_SYSID 2
#define ECCA_B_COMPID 3
#define ECCA_B_FINAL_ACTION 4
#define ECCA_B_HOLD_S 5       /* hold the end point this long before the final action [s] */
#define ECCA_B_START_TOL_M 6  /* refuse to start farther than this from the start point [m] */
#define ECCA_B_KP 7           /* [3] position gain [1/s^2] */
#define ECCA_B_KD 10          /* [3] velocity gain [1/s] */
#define ECCA_B_KI 13          /* [3] integral gain [1/s^3] */
#define ECCA_B_IMAX 16        /* [3] integrator bound [m/s^2] */
#define ECCA_B_HOVER 19       /* hover thrust [normalised] */
#define ECCA_B_DRAG 20        /* linear drag [N/(m/s)] */
#define ECCA_B_MASS 21        /* [kg] */
#define ECCA_B_G 22           /* [m/s^2] */
#define ECCA_B_THRUST_MIN 23  /* [normalised] */
#define ECCA_B_THRUST_MAX 24  /* [normalised] */
#define ECCA_B_TILT_MAX 25    /* [rad] */
#define ECCA_B_DRAG_EST 26    /* 1: drag of the estimated velocity, 0: of the reference's */
#define ECCA_B_LEAD_S 27      /* the feed-forward's lead (attitude_lead_s) [s] */
#define ECCA_B_DIST_BW 28     /* disturbance observer's bandwidth [rad/s] (0: none estimated) */
#define ECCA_B_VCORR_RAD_S 29 /* velocity correction's frequency [rad/s] (0: none) */
#define ECCA_B_UPLOAD_ID 30   /* the segments' CRC-32, low 24 bits: names the upload's content */
#define ECCA_B_COUNT 31       /* values of ECCA_OP_BEGIN covered by the CRC */

/* ECCA_OP_SEGMENT data layout */
#define ECCA_S_INDEX 0
#define ECCA_S_DURATION 1 /* [s] */
#define ECCA_S_CTRL 2     /* [8][3] NED position control points [m] */
#define ECCA_S_YAW 26     /* [8] yaw control points [rad] */
#define ECCA_S_COUNT 34   /* values of ECCA_OP_SEGMENT covered by the CRC */

#endif /* ECCA_ONBOARD_PROTO_H */
