"""Rover on real PX4 (built from main, SIH Ackermann rover): which OFFBOARD setpoints it accepts
over MAVLink and how well each tracks one common reference (issue 29).

Each candidate interface is flown on a fresh PX4 (px4_harness.Px4Sitl, build "main", model
sihsim_rover_ackermann, real time), holding the shared flight lock /tmp/ecca-px4-flights.lock
(flock) around the flight only, by a pymavlink client independent of the companion
(bench/rover_link.py):
  1. stream the candidate's "stand still" setpoint at 50 Hz (proof of life), arm in Hold
     (retried: the rover refuses until its estimator is ready), DO_SET_MODE OFFBOARD; the
     last COMMAND_ACK (PX4 acks twice) and the HEARTBEAT say whether it was accepted;
  2. in OFFBOARD, the candidate's tracking loop (below) flies the reference, anchored at the
     rover's position and heading when OFFBOARD began: a straight 20 m leg, a 90 deg right turn
     of radius 3 m (the rover's minimum turning radius: RA_WHEEL_BASE / tan(RA_MAX_STR_ANG) =
     0.56 m), a 10 m leg; speed 2 m/s, smooth 2.5 s ramps up and down (34.7 m, 19.9 s); then
     4 s more with the end point held;
  3. errors from PX4's LOCAL_POSITION_NED (50 Hz, requested) against the path geometry:
     cross-track (distance to the path, RMS and max over the reference's 19.9 s), along-track
     (arc length of the closest path point minus the reference's, + = behind), heading (ATTITUDE
     yaw minus the path tangent at the closest point, while the reference moves > 0.5 m/s),
     the end error (distance to the end point after the 4 s), and the same cross-track and
     along-track errors from PX4's ground truth (HIL_STATE_QUATERNION at 50 Hz, projected to
     PX4's local frame through HOME_POSITION). A candidate that is refused or does not move
     (< 0.5 m in 6 s) is stopped there.

The tracking loop (this script's, 50 Hz, the same law for every interface that takes it): the
closest path point s_c to the latest position; along-track error e_a = s_ref(t) - s_c; speed
u = v_ref(t) + 1.0 e_a + 0.3 * integral(e_a) (clamped 0..RO_SPEED_LIM; the integral, kept only
while the reference moves, takes out PX4's steady speed overshoot); course = pure pursuit
towards the path point u * 1 s (1-10 m, PX4's own PP_LOOKAHD_* defaults) beyond s_c, minus
0.3 * integral(cross-track error) (at most 20 deg: PX4 steers its estimated heading, which was
up to ~10 deg off the true one on the first leg, and pure pursuit alone then keeps a steady
offset). Then per interface:
  position           SET_POSITION_TARGET_LOCAL_NED x, y = the reference point now (mask 3580;
                     no loop: PX4's position control drives to it)
  position_lead      the same, the reference point 1 s ahead
  position_loop      x, y = the path point ahead of s_c by the distance at which PX4's stopping
                     profile allows speed u (v^2 + 4 a^2 / j v = 2 a d, RO_DECEL_LIM,
                     RO_JERK_LIM; at least 0.6 m)
  velocity_ff        vx, vy = the reference velocity, no feedback (mask 3559): PX4 alone
  velocity           vx, vy = u (cos, sin)(course) (mask 3559)
  velocity_yaw       + yaw = course + 90 deg (mask 2535): a yaw PX4 would turn the rover
                     sideways for, if it used it
  velocity_yawrate   + yaw_rate = 0.5 rad/s (mask 1511): a yaw rate that would make it
                     circle, if used (the companion's rover mode sends velocity + yaw rate)
  acceleration       afx, afy = 1 m/s^2 along the course, speed feedback (mask 3135)
  attitude           SET_ATTITUDE_TARGET q = yaw course, thrust = u / RO_MAX_THR_SPEED (mask 7)
  rates              SET_ATTITUDE_TARGET body yaw rate = u * curvature + 2 (course - yaw),
                     roll/pitch rates 0, thrust as above, attitude ignored (mask 128)
  actuator_target    SET_ACTUATOR_CONTROL_TARGET controls[0] steering, [1] throttle (id 139)
  do_set_actuator    COMMAND_LONG MAV_CMD_DO_SET_ACTUATOR (187) p1 steering, p2 throttle, 10 Hz

Run: `.venv/bin/python bench/bench_rover_interfaces.py [--interfaces ...] [--repeat 1]
[--write]` (about 45 s per flight). Do not wrap it in flock: it takes the lock itself.
`--write` replaces the section "Rover on real PX4: offboard interfaces" of BENCHMARKS.md;
`--reuse JSON` rebuilds the section from an earlier run's OUT/rover_interfaces.json.

The reference path and speed profile, and the errors of a drive against them, are in
rover_reference.py.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
for _p in (BENCH, REPO):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from rover_link import HOLD, OFFBOARD, RoverLink, Streamer, mode_name  # noqa: E402
from rover_reference import (  # noqa: E402
    SETTLE_S,
    Path2,
    Projector,
    SpeedProfile,
    errors,
    est_vs_truth,
    stopping_distance,
    wrap_angle,
)

from px4_harness import STARTED_MARK, Px4Sitl, find_px4_sitl, flight_lock  # noqa: E402

SECTION = "Rover on real PX4: offboard interfaces"
MODEL = "sihsim_rover_ackermann"
#: The rover's PX4 parameters that matter for planning (read over PARAM_REQUEST_READ).
PLANNING_PARAMS = (
    ("RA_WHEEL_BASE", "wheel base [m]"),
    ("RA_MAX_STR_ANG", "maximum steering angle [rad]"),
    ("RA_STR_RATE_LIM", "steering rate limit [deg/s]"),
    ("RO_SPEED_LIM", "speed limit [m/s] (also AUTO's default cruise speed)"),
    ("RO_MAX_THR_SPEED", "speed at full throttle [m/s] (speed feed-forward)"),
    ("RO_ACCEL_LIM", "acceleration limit [m/s^2]"),
    ("RO_DECEL_LIM", "deceleration limit [m/s^2]"),
    ("RO_JERK_LIM", "jerk limit [m/s^3]"),
    ("RO_YAW_RATE_LIM", "yaw rate limit [deg/s]"),
    ("RO_YAW_ACCEL_LIM", "yaw acceleration limit [deg/s^2]"),
    ("RO_YAW_P", "yaw P gain (heading error -> yaw rate) [1/s]"),
    ("RO_SPEED_P", "speed P gain"),
    ("RO_SPEED_I", "speed I gain"),
    ("NAV_ACC_RAD", "default waypoint acceptance radius [m]"),
    ("RA_ACC_RAD_MAX", "largest corner acceptance radius in AUTO [m]"),
    ("RA_ACC_RAD_GAIN", "corner acceptance radius gain in AUTO"),
    ("PP_LOOKAHD_GAIN", "pure pursuit look-ahead gain [s]"),
    ("PP_LOOKAHD_MIN", "pure pursuit minimum look-ahead [m]"),
    ("PP_LOOKAHD_MAX", "pure pursuit maximum look-ahead [m]"),
    ("COM_OF_LOSS_T", "offboard loss timeout [s]"),
    ("COM_OBL_RC_ACT", "offboard loss action (0: position mode, falls back without RC)"),
    ("COM_DISARM_PRFLT", "auto-disarm after arming without moving [s]"),
)

# loop gains (see the module doc)
K_ALONG = 1.0
K_ALONG_I = 0.3
K_CROSS_I = 0.3  # course correction per m*s of cross-track error [rad/(m s)]
CROSS_I_MAX = 0.35  # its limit [rad] (20 deg)
LOOKAHEAD_S = 1.0  # pure pursuit look-ahead = speed * 1 s, within [1, 10] m (PX4's PP_* defaults)
LOOKAHEAD_MIN_M = 1.0
LOOKAHEAD_MAX_M = 10.0
K_YAW = 2.0
CRAWL_M_S = 0.3  # slowest speed commanded towards the end point (PX4 stops below ~0.2 m/s)
LOOP_HZ = 50.0
STILL_ABORT_S = 6.0


# ----------------------------------------------------------------------------- interfaces


@dataclass
class LoopState:
    """What the tracking loop knows at one tick."""

    t: float  # reference time [s]
    s_ref: float
    v_ref: float
    n: float
    e: float
    yaw: float
    s_c: float
    cross: float
    u: float  # commanded speed [m/s]
    bearing: float  # commanded course [rad]
    curvature: float


@dataclass(frozen=True)
class Interface:
    name: str
    message: str
    #: sends the setpoint for "stand still here" (proof of life before OFFBOARD)
    hold: Callable[[RoverLink, float, float, float], None]
    #: sends the setpoint for one loop tick
    track: Callable[[RoverLink, LoopState, Path2, SpeedProfile, dict[str, float]], None]
    streamed_hz: float = LOOP_HZ


def _q_yaw(psi: float) -> tuple[float, float, float, float]:
    return math.cos(psi / 2), 0.0, 0.0, math.sin(psi / 2)


def _thr(u: float, p: dict[str, float]) -> float:
    return min(max(u / p.get("RO_MAX_THR_SPEED", 3.2), 0.0), 1.0)


def _pos(lead_s: float) -> Callable[..., None]:
    def track(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
              p: dict[str, float]) -> None:
        n, e = path.point_at(prof.at(st.t + lead_s)[0])
        L.position_target(3580, x=n, y=e)
    return track


def _pos_loop(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
              p: dict[str, float]) -> None:
    """Position setpoint on the path, ahead of the rover by the distance at which PX4 drives at
    the loop's speed u (at least 0.6 m: inside the acceptance radius PX4 stops)."""
    d = stopping_distance(st.u, p.get("RO_DECEL_LIM", 3.0), p.get("RO_JERK_LIM", 10.0))
    n, e = path.point_at(min(st.s_c + max(d, 0.6), path.length_m) if st.u > 0 else st.s_c)
    L.position_target(3580, x=n, y=e)


def _vel_ff(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
            p: dict[str, float]) -> None:
    h = path.heading_at(st.s_ref)
    L.position_target(3559, vx=st.v_ref * math.cos(h), vy=st.v_ref * math.sin(h))


WRONG_YAW_RAD = math.pi / 2  # velocity_yaw: the yaw sent is the course + 90 deg
WRONG_YAW_RATE = 0.5  # velocity_yawrate: the yaw rate sent [rad/s]


def _vel(mask: int, with_yaw: bool = False, with_rate: bool = False) -> Callable[..., None]:
    def track(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
              p: dict[str, float]) -> None:
        L.position_target(mask, vx=st.u * math.cos(st.bearing), vy=st.u * math.sin(st.bearing),
                          yaw=wrap_angle(st.bearing + WRONG_YAW_RAD) if with_yaw else 0.0,
                          yaw_rate=WRONG_YAW_RATE if with_rate else 0.0)
    return track


def _acc(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
         p: dict[str, float]) -> None:
    a = min(max(st.u - st.v_ref, -1.0), 1.0) + 1.0
    L.position_target(3135, afx=a * math.cos(st.bearing), afy=a * math.sin(st.bearing))


def _att(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
         p: dict[str, float]) -> None:
    L.attitude_target(7, _q_yaw(st.bearing), _thr(st.u, p))


def _rates(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
           p: dict[str, float]) -> None:
    r = st.u * st.curvature + K_YAW * wrap_angle(st.bearing - st.yaw)
    L.attitude_target(128, (1.0, 0.0, 0.0, 0.0), _thr(st.u, p), yaw_rate=r)


def _steer(st: LoopState, p: dict[str, float]) -> float:
    """Normalised steering [-1, 1]: kinematic feed-forward + heading correction."""
    wb, smax = p.get("RA_WHEEL_BASE", 0.321), p.get("RA_MAX_STR_ANG", 0.5236)
    delta = math.atan(wb * st.curvature) + 0.5 * wrap_angle(st.bearing - st.yaw)
    return min(max(delta / smax, -1.0), 1.0)


def _act(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
         p: dict[str, float]) -> None:
    L.actuator_control_target([_steer(st, p), _thr(st.u, p)])


def _do_act(L: RoverLink, st: LoopState, path: Path2, prof: SpeedProfile,
            p: dict[str, float]) -> None:
    L.command(187, _steer(st, p), _thr(st.u, p), 0.0, 0.0, 0.0, 0.0, 0.0)


INTERFACES: dict[str, Interface] = {i.name: i for i in (
    Interface("position", "SET_POSITION_TARGET_LOCAL_NED x, y (mask 3580), the reference now",
              lambda L, n, e, yaw: L.position_target(3580, x=n, y=e), _pos(0.0)),
    Interface("position_lead", "SET_POSITION_TARGET_LOCAL_NED x, y (mask 3580), the reference "
              "1 s ahead", lambda L, n, e, yaw: L.position_target(3580, x=n, y=e), _pos(1.0)),
    Interface("position_loop", "SET_POSITION_TARGET_LOCAL_NED x, y (mask 3580), tracking loop: "
              "the path point where PX4's stopping profile gives the loop's speed",
              lambda L, n, e, yaw: L.position_target(3580, x=n, y=e), _pos_loop),
    Interface("velocity_ff", "SET_POSITION_TARGET_LOCAL_NED vx, vy (mask 3559), the reference "
              "velocity, no feedback", lambda L, n, e, yaw: L.position_target(3559), _vel_ff),
    Interface("velocity", "SET_POSITION_TARGET_LOCAL_NED vx, vy (mask 3559), tracking loop",
              lambda L, n, e, yaw: L.position_target(3559), _vel(3559)),
    Interface("velocity_yaw", "SET_POSITION_TARGET_LOCAL_NED vx, vy, yaw (mask 2535), tracking "
              "loop, yaw = course + 90 deg",
              lambda L, n, e, yaw: L.position_target(2535, yaw=wrap_angle(yaw + WRONG_YAW_RAD)),
              _vel(2535, with_yaw=True)),
    Interface("velocity_yawrate", "SET_POSITION_TARGET_LOCAL_NED vx, vy, yaw_rate (mask 1511), "
              "tracking loop, yaw_rate = 0.5 rad/s",
              lambda L, n, e, yaw: L.position_target(1511, yaw_rate=WRONG_YAW_RATE),
              _vel(1511, with_rate=True)),
    Interface("acceleration", "SET_POSITION_TARGET_LOCAL_NED afx, afy (mask 3135), 1 m/s^2 "
              "along the course", lambda L, n, e, yaw: L.position_target(3135), _acc),
    Interface("attitude", "SET_ATTITUDE_TARGET q (yaw), thrust = speed / RO_MAX_THR_SPEED "
              "(mask 7)", lambda L, n, e, yaw: L.attitude_target(7, _q_yaw(yaw), 0.0), _att),
    Interface("rates", "SET_ATTITUDE_TARGET body yaw rate + thrust, attitude ignored (mask 128)",
              lambda L, n, e, yaw: L.attitude_target(128, (1.0, 0.0, 0.0, 0.0), 0.0), _rates),
    Interface("actuator_target", "SET_ACTUATOR_CONTROL_TARGET controls[0] steering, [1] "
              "throttle", lambda L, n, e, yaw: L.actuator_control_target([0.0, 0.0]), _act),
    Interface("do_set_actuator", "COMMAND_LONG DO_SET_ACTUATOR (187) p1 steering, p2 throttle, "
              "10 Hz", lambda L, n, e, yaw: L.command(187, 0.0, 0.0, 0, 0, 0, 0, 0), _do_act,
              streamed_hz=10.0),
)}


# ----------------------------------------------------------------------------- one flight




def _latest(L: RoverLink) -> tuple[float, float, float]:
    s = L.lpos[-1]
    return s.x, s.y, (L.att[-1][2] if L.att else 0.0)


def fly(iface: Interface, folder: Path) -> dict[str, Any]:
    """One flight of `iface` on a fresh PX4 main rover (see the module doc)."""
    loc, why = find_px4_sitl("main")
    if loc is None:
        raise RuntimeError(f"no PX4 main SITL: {why}")
    shutil.rmtree(folder, ignore_errors=True)
    folder.mkdir(parents=True)
    out: dict[str, Any] = {"interface": iface.name, "message": iface.message}
    with flight_lock() as waited:
        out["lock_wait_s"] = waited
        with Px4Sitl(location=loc, model=MODEL, ready_mark=STARTED_MARK,
                     log=folder / "px4-console.log") as px4, \
                RoverLink(px4.port, px4.target_system, tlog=folder / "flight.tlog") as L:
            if not L.wait_heartbeat(20.0):
                raise RuntimeError("no HEARTBEAT from PX4")
            out["truth_interval_ack"] = L.set_message_interval(115, 50.0)
            L.set_message_interval(32, 50.0)
            L.wait(lambda: bool(L.lpos) and bool(L.att), 10.0)
            params = {name: L.read_param(name) for name, _ in PLANNING_PARAMS}
            out["params"] = params
            n0, e0, yaw0 = _latest(L)
            hold = Streamer(lambda: iface.hold(L, n0, e0, yaw0), iface.streamed_hz)
            armed, t_arm = L.arm(40.0, tick=hold)
            out["armed"], out["arm_s"] = armed, t_arm
            if not armed:
                out["outcome"] = "did not arm"
                return out
            L.wait(lambda: False, 1.5, tick=hold)  # > 1 s of proof of life
            t_req = time.time()
            out["offboard_ack"] = L.set_mode(OFFBOARD, tick=hold)
            entered = L.wait(lambda: L.mode == OFFBOARD, 2.5, tick=hold)
            out["entered_offboard"] = entered
            out["texts"] = L.texts_since(t_req - 2.0)
            out["mode_after"] = mode_name(L.mode)
            drive = run_loop(L, iface, out, params, entered)
            if iface.name == "do_set_actuator":  # the command's own verdict
                out["command_ack"] = L.command_ack(187, 0.0, 0.0, 0, 0, 0, 0, 0)
            L.set_mode(HOLD)
            out["messages"] = dict(L.messages)
    if drive is not None:  # the link is closed: its records no longer grow
        path, prof, proj, t0u = drive
        out["estimate"] = errors(L, path, prof, proj, t0u, truth=False)
        out["truth"] = errors(L, path, prof, proj, t0u, truth=True)
        out["est_vs_truth"] = est_vs_truth(L, t0u, t0u + prof.duration_s + SETTLE_S)
    return out


def run_loop(L: RoverLink, iface: Interface, out: dict[str, Any], params: dict[str, float],
             entered: bool) -> tuple[Path2, SpeedProfile, Projector, float] | None:
    """The tracking loop; what the analysis needs when the rover drove (else None)."""
    n0, e0, yaw0 = _latest(L)
    path = Path2(start=(n0, e0), heading=yaw0)
    prof = SpeedProfile(path.length_m)
    proj = Projector(path)
    speed_lim = params.get("RO_SPEED_LIM", 3.0)
    if not math.isfinite(speed_lim):
        speed_lim = 3.0
    duration = prof.duration_s + SETTLE_S
    t0u = time.time()
    t0 = time.monotonic()
    s_c, integ, integ_c = 0.0, 0.0, 0.0
    period = 1.0 / iface.streamed_hz
    next_t = t0
    moved = 0.0
    while True:
        now = time.monotonic()
        t = now - t0
        if t > duration:
            break
        n, e, yaw = _latest(L)
        moved = max(moved, math.hypot(n - n0, e - e0))
        if t > STILL_ABORT_S and moved < 0.5:
            break
        s_ref, v_ref = prof.at(t)
        s_c, cross = proj.closest(n, e, near=s_c)
        e_a = s_ref - s_c
        if v_ref > 0.5:
            integ = min(max(integ + K_ALONG_I * e_a * period, -0.8), 0.8)
        # the integral only while the reference moves: at the end, stop on the end point
        u = v_ref + K_ALONG * e_a + (integ if v_ref > 0.0 else 0.0)
        if t >= prof.duration_s:  # the reference stopped: crawl onto the end point
            u = max(u, CRAWL_M_S) if path.length_m - s_c > 0.1 else 0.0
        u = min(max(u, 0.0), speed_lim)
        look = min(max(LOOKAHEAD_S * u, LOOKAHEAD_MIN_M), LOOKAHEAD_MAX_M)
        cn, ce = path.point_at(s_c + look)
        if u > CRAWL_M_S:  # PX4's heading estimate can be several degrees off: integrate
            integ_c = min(max(integ_c + cross * period, -CROSS_I_MAX / K_CROSS_I),
                          CROSS_I_MAX / K_CROSS_I)
        # pure pursuit: aim at the path point ahead; minus the cross-track integral
        bearing = math.atan2(ce - e, cn - n) - K_CROSS_I * integ_c
        st = LoopState(t, s_ref, v_ref, n, e, yaw, s_c, cross, u, bearing,
                       path.curvature_at(s_c + 0.5 * look))
        with contextlib.suppress(OSError):
            iface.track(L, st, path, prof, params)
        next_t += period
        time.sleep(max(0.0, next_t - time.monotonic()))
    out["moved_m"] = moved
    out["modes_during"] = sorted({m for _, m, _a in L.heartbeat_modes(t0u, time.time())})
    out["path"] = {"start": [n0, e0], "heading_deg": math.degrees(yaw0),
                   "length_m": path.length_m, "duration_s": prof.duration_s}
    if not entered or moved < 0.5:
        out["outcome"] = (f"stayed in {mode_name(L.mode)}" if not entered
                          else "OFFBOARD, stood still")
        return None
    out["outcome"] = "drove"
    return path, prof, proj, t0u


# ----------------------------------------------------------------------------- table


def _cell(runs: list[dict[str, Any]], key: str, sub: str, fmt: str = ".2f") -> str:
    vals = [float(r[key][sub]) for r in runs
            if isinstance(r.get(key), dict) and isinstance(r[key].get(sub), (int, float))
            and math.isfinite(r[key][sub])]
    if not vals:
        return "-"
    if len(vals) == 1:
        return format(vals[0], fmt)
    return f"{np.median(vals):{fmt}} ({min(vals):{fmt}}-{max(vals):{fmt}})"


def _pair(runs: list[dict[str, Any]], key: str, a: str, b: str, fmt: str = ".2f") -> str:
    x, y = _cell(runs, key, a, fmt), _cell(runs, key, b, fmt)
    return "-" if x == "-" else f"{x} / {y}"


def _accepted(runs: list[dict[str, Any]]) -> tuple[str, str]:
    acks = sorted({str(r.get("offboard_ack")) for r in runs})
    entered = sorted({"yes" if r.get("entered_offboard") else "no" for r in runs})
    names = {"0": "0 ACCEPTED", "1": "1 TEMPORARILY_REJECTED", "2": "2 DENIED",
             "None": "no ACK"}
    return ", ".join(names.get(a, a) for a in acks), "/".join(entered)


def table(results: dict[str, list[dict[str, Any]]]) -> str:
    lines = [
        "| interface | message, mask | DO_SET_MODE OFFBOARD (last ACK) | in OFFBOARD | what "
        "the rover did | cross-track RMS / max [m] | along-track RMS / max [m] (mean, + = "
        "behind) | heading RMS / max [deg] | end error, estimate / truth [m] | truth: "
        "cross-track RMS / max [m] | truth: along-track RMS / max [m] | leg-1 speed / 2 m/s "
        "(truth) |",
        "| --- | --- | --- | --- | --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: |"]
    for name, runs in results.items():
        ok = [r for r in runs if "error" not in r]
        if not ok:
            lines.append(f"| {name} | {INTERFACES[name].message} | error: "
                         f"{runs[0].get('error', '?')} | | | | | | | | | |")
            continue
        ack, entered = _accepted(ok)
        did = "; ".join(sorted({r.get("outcome", "?") for r in ok}))
        if did != "drove":
            moved = max(float(r.get("moved_m", math.nan)) for r in ok)
            did += f" (the estimate moved <= {moved:.1f} m in {STILL_ABORT_S:g} s)"
        acks = sorted({str(r["command_ack"]) for r in ok if "command_ack" in r})
        if acks:
            did += f"; its COMMAND_ACK: {', '.join(acks)}"
        along = _pair(ok, "estimate", "along_rms_m", "along_max_m")
        if along != "-":
            along += f" ({_cell(ok, 'estimate', 'along_mean_m')})"
        lines.append(
            f"| {name} | {ok[0]['message']} | {ack} | {entered} | {did} | "
            f"{_pair(ok, 'estimate', 'cross_rms_m', 'cross_max_m')} | {along} | "
            f"{_pair(ok, 'estimate', 'heading_rms_deg', 'heading_max_deg', '.1f')} | "
            f"{_cell(ok, 'estimate', 'end_m')} / {_cell(ok, 'truth', 'end_m')} | "
            f"{_pair(ok, 'truth', 'cross_rms_m', 'cross_max_m')} | "
            f"{_pair(ok, 'truth', 'along_rms_m', 'along_max_m')} | "
            f"{_cell(ok, 'truth', 'speed_ratio_leg1')} |")
    return "\n".join(lines) + "\n"


def params_table(params: dict[str, float]) -> str:
    lines = ["| parameter | meaning | value (PARAM_REQUEST_READ) |", "| --- | --- | ---: |"]
    for name, what in PLANNING_PARAMS:
        v = params.get(name, math.nan)
        lines.append(f"| `{name}` | {what} | {_param_text(name, v)} |")
    return "\n".join(lines) + "\n"


def _param_text(name: str, v: float) -> str:
    return "-" if not math.isfinite(v) else f"{v:.4g}"


def section(argv: str, data: dict[str, Any], load: tuple[float, float], reused: str) -> str:
    results = data["results"]
    params = data.get("params", {})
    ld = data.get("load") or ([] if reused.startswith("Figures of that run") else load)
    load_text = (f", 1-min load {ld[0]:.1f} at the start, {ld[1]:.1f} at the end" if ld
                 else "")
    head = (f"## {SECTION}\n\nCommand: `.venv/bin/python bench/bench_rover_interfaces.py "
            f"{data['command']}` ({data['date']}, git {data['git']}, {platform.machine()}, "
            f"{os.cpu_count()} cores shared with other jobs{load_text}). {reused}PX4 built from "
            "main (02e73e3b6f48, "
            "../shared/px4_main_sitl), SIH `sihsim_rover_ackermann` (airframe 10045) with its "
            "default parameters, real time; one fresh PX4 per flight, under the flight lock. "
            "Reference: 20 m straight along the rover's heading, 90 deg right turn of radius "
            "3 m, 10 m straight, 2 m/s with 2.5 s smooth ramps (34.7 m, 19.9 s), anchored where "
            "OFFBOARD began; errors over those 19.9 s against the path geometry (see the "
            "script's doc for the tracking loop, the same law for every interface that "
            "takes it); end error 4 s after the reference stopped. Estimate: "
            "LOCAL_POSITION_NED at 50 Hz; truth: HIL_STATE_QUATERNION at 50 Hz. Cells: median "
            "(min-max) of the repeats.\n")
    notes = (
        "\nReading it (PX4 main's rover offboard code, see docs/guides/px4-sitl.md): the "
        "Ackermann rover turns SET_POSITION_TARGET_LOCAL_NED into either a position setpoint "
        "(any x/y used: it drives there at up to RO_SPEED_LIM and stops within the acceptance "
        "radius, slowing down early with its jerk/decel limits) or a velocity setpoint "
        "(speed = |(vx, vy)|, course = atan2(vy, vx), always forwards); the yaw and yaw_rate "
        "fields are ignored: velocity_yaw (a yaw 90 deg off the course) and velocity_yawrate (a "
        "steady 0.5 rad/s) drive like velocity, within flight-to-flight noise. "
        "SET_ATTITUDE_TARGET (attitude or rates) and an acceleration-only setpoint are proof "
        "of life and enter OFFBOARD, but the rover module uses only "
        "position and velocity setpoints in OFFBOARD: the rover stands still. "
        "SET_ACTUATOR_CONTROL_TARGET is not handled by this build (no proof of life, OFFBOARD "
        "refused); DO_SET_ACTUATOR is acknowledged but drives PX4's \"Offboard Actuator Set\" "
        "outputs, which this airframe does not map to its steering servo or motor (remapped "
        "with PWM_MAIN_FUNC1/2 = 301/302 at boot, the rover did not move either: one flight "
        "by hand, not in this table).\n")
    floor = _floor_text(results)
    return (head + "\n" + table(results) + notes + floor
            + "\n### The rover's PX4 parameters for planning (read over MAVLink)\n\n"
            + params_table(params))


def _floor_text(results: dict[str, list[dict[str, Any]]]) -> str:
    rms = [r["est_vs_truth"]["rms_m"] for runs in results.values() for r in runs
           if r.get("est_vs_truth", {}).get("rms_m") is not None]
    mx = [r["est_vs_truth"]["max_m"] for runs in results.values() for r in runs
          if r.get("est_vs_truth", {}).get("max_m") is not None]
    if not rms:
        return ""
    yr = [r["est_vs_truth"]["yaw_rms_deg"] for runs in results.values() for r in runs
          if r.get("est_vs_truth", {}).get("yaw_rms_deg") is not None]
    ym = [r["est_vs_truth"]["yaw_max_deg"] for runs in results.values() for r in runs
          if r.get("est_vs_truth", {}).get("yaw_max_deg") is not None]
    yaw = (f" Its heading (ATTITUDE yaw) was {min(yr):.1f}-{max(yr):.1f} deg RMS off the "
           f"simulator's (max {max(ym):.1f} deg), worst before the first turn: PX4 steers that "
           "estimate, so a course command is off by as much until the loop corrects it."
           if yr else "")
    still = [r["est_vs_truth"] for runs in results.values() for r in runs
             if r.get("est_vs_truth", {}).get("end_true_travel_m", math.inf) < 0.05]
    if still:
        ee = [v["end_est_travel_m"] for v in still]
        yaw += (f" In the {len(still)} flights where the rover truly stood still over the last "
                f"3 s (truth moved < 0.05 m), its estimate still moved {min(ee):.2f}-"
                f"{max(ee):.2f} m: judge the end point from the truth.")
    return ("\nThe floor: PX4's estimate (LOCAL_POSITION_NED) differed from the truth by "
            f"{min(rms):.2f}-{max(rms):.2f} m RMS (max {max(mx):.2f} m) horizontally over "
            "these drives (SIH's GPS noise through EKF2). The reference is anchored at the "
            "estimate, so the truth columns carry that error too, and an estimate figure below "
            f"it does not mean the rover is closer to the path than that.{yaw}\n")


def _git_rev() -> str:
    try:
        r = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                           text=True, timeout=10, check=True)
        return r.stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="rover offboard interfaces on real PX4 main")
    ap.add_argument("--interfaces", nargs="+", choices=list(INTERFACES), default=list(INTERFACES))
    ap.add_argument("--repeat", type=int, default=1, help="flights per interface (~45 s each)")
    ap.add_argument("--out", default="bench_out/rover_interfaces", help="logs and JSON")
    ap.add_argument("--reuse", default=None, metavar="JSON",
                    help="rebuild the section from an earlier run's rover_interfaces.json")
    ap.add_argument("--refly", nargs="+", choices=list(INTERFACES), default=[],
                    help="with --reuse: fly these interfaces again (--repeat times) and "
                         "replace their rows")
    ap.add_argument("--write", action="store_true", help=f'update "## {SECTION}"')
    args = ap.parse_args(argv)
    if args.repeat < 1:
        ap.error("--repeat must be >= 1")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    load0 = os.getloadavg()
    argv_s = shlex.join(sys.argv[1:] if argv is None else argv)
    reused = ""
    if args.refly and not args.reuse:
        ap.error("--refly needs --reuse")
    if args.reuse and not args.refly:
        data = json.loads(Path(args.reuse).read_text())
        reused = ("Figures of that run, read from its JSON by `.venv/bin/python "
                  f"bench/bench_rover_interfaces.py {argv_s}`. ")
        rf = data.get("refly")
        if rf:
            reused += (f"Rows {', '.join(rf['interfaces'])} flown again by `.venv/bin/python "
                       f"bench/bench_rover_interfaces.py {rf['command']}` ({rf['date']}, git "
                       f"{rf['git']}). ")
    else:
        old = json.loads(Path(args.reuse).read_text()) if args.reuse else None
        names = args.refly or args.interfaces
        results: dict[str, list[dict[str, Any]]] = {n: [] for n in names}
        params: dict[str, float] = {}
        for i in range(args.repeat):
            for name in names:
                t0 = time.perf_counter()
                try:
                    r = fly(INTERFACES[name], out / f"{name}-{i}")
                except Exception as exc:  # one failed flight must not lose the run
                    r = {"interface": name, "error": f"{type(exc).__name__}: {exc}"}
                r["wall_s"] = time.perf_counter() - t0
                if not params and r.get("params"):
                    params = r["params"]
                results[name].append(r)
                (out / "rover_interfaces.partial.json").write_text(json.dumps(
                    {"results": results, "params": params}, indent=1, default=float))
                est = r.get("estimate", {})
                print(f"{name} #{i}: {r.get('outcome', r.get('error'))}; ack "
                      f"{r.get('offboard_ack')}, cross RMS {est.get('cross_rms_m', math.nan):.2f}"
                      f" m, along RMS {est.get('along_rms_m', math.nan):.2f} m, end "
                      f"{est.get('end_m', math.nan):.2f} m ({r['wall_s']:.0f} s wall)",
                      flush=True)
        data = {"date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()), "command": argv_s,
                "git": _git_rev(), "results": results, "params": params,
                "load": [load0[0], os.getloadavg()[0]]}
        if old is not None:  # the other rows from the earlier run, in its order
            data = {**old, "results": {n: results.get(n, r) for n, r in old["results"].items()},
                    "refly": {"command": argv_s, "date": data["date"], "git": data["git"],
                              "interfaces": names}}
            for n in names:
                data["results"].setdefault(n, results[n])
            reused = (f"Rows {', '.join(names)} flown again by `.venv/bin/python "
                      f"bench/bench_rover_interfaces.py {argv_s}` ({data['refly']['date']}, git "
                      f"{data['refly']['git']}), the others from the run above. ")
        (out / "rover_interfaces.json").write_text(json.dumps(data, indent=1, default=float))
    text = section(argv_s, data, (load0[0], os.getloadavg()[0]), reused)
    print(text)
    if args.write:
        from benchmarks_md import write_section

        write_section(SECTION, text)
        print(f"updated BENCHMARKS.md ## {SECTION}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
