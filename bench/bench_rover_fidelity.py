"""Rover fidelity (issue 29, part 4): the same inputs flown on the mock rover
(`python -m sitl_mock serve --vehicle rover`) and on the real PX4 built from main driving SIH's
Ackermann rover (airframe 10045 `sihsim_rover_ackermann`), in one run, measured the same way from
each autopilot's own telemetry (pymavlink, no companion code in the loop).

Measured on the vehicle's true motion: HIL_STATE_QUATERNION, which PX4 SITL streams on request
(its simulator's state) and so does the mock (its truth; `--mock-estimator ekf2` gives the mock
rover EKF2-like estimate errors it then steers by, `serve --estimator ekf2`). Each autopilot's
estimate is recorded too (the traces: LOCAL_POSITION_NED, ATTITUDE; bench/rover_estimate_error.py
reads its error against the truth): PX4's standing still reads up to 0.4 m/s, which would turn
"stopped" into a matter of the estimator.

Flights (each on a fresh autopilot; real PX4 only while holding /tmp/ecca-px4-flights.lock):
- "offboard": SET_POSITION_TARGET_LOCAL_NED velocity setpoints (LOCAL_NED, type_mask 3527:
  vx, vy, vz) at 20 Hz; arm (retried: PX4 main's rover is armable ~6 s after start), OFFBOARD
  after 2 s of zero-velocity setpoints, then
  - speed step: 0 -> STEP_SPEED along the rover's heading for STEP_S: time from the command to
    0.1 m/s (PX4's link and loops, the slewed throttle overcoming static friction), rise time
    10-90 % of the steady speed, peak acceleration (speed differences over 0.1 s), overshoot
    of the setpoint (peak / STEP_SPEED - 1: PX4's rover runs on its throttle feed-forward,
    SIH's drag decides where it settles), steady speed (mean over the last 3 s);
  - stop: velocity 0: stopping distance (path length from the command until the speed stays
    below 0.1 m/s) and stopping time;
  - turn at full steering: STEP_SPEED towards the rover's heading + 90 deg (the direction is
    re-aimed at every setpoint, so the yaw error stays 90 deg and the steering saturates) for
    TURN_S: over the last TURN_JUDGE_S, mean speed, mean |yaw rate| and the radius of the
    least-squares circle through the positions.
- "mission": examples/missions/rover_square.plan (a 30 m square from home, plain waypoints)
  uploaded, arm, AUTO.MISSION: armed time (arm COMMAND_ACK to the rover standing still,
  speed < 0.1 m/s, after the last waypoint's MISSION_ITEM_REACHED; or to a disarm; neither
  autopilot disarms at the end: both hold), closest approach to each waypoint (after the
  previous one's: the start at home is not the last waypoint's) and cross-track RMS from the
  square's legs (positions about the plan's home) while driving (> 0.3 m/s).

Table: mock / PX4 - 1 per row, median over --repeat flights (each side's range beside it), the
goal |ratio - 1| <= 25 %. The path rows (closest approaches, cross-track) carry each side's
estimate error, one realisation per flight: `--stagger S` arms repeat i i x S s later after
boot (PX4 SIH's noise repeats at the same time since boot) and the mock's repeat i runs
`serve --seed i`, so the repeats sample different realisations.
Both in real time. Run (the script takes the PX4 flight lock itself; do not wrap it in flock):
`.venv/bin/python bench/bench_rover_fidelity.py [--target mock px4] [--repeat 1] [--stagger S]
[--mock-estimator ideal|ekf2] [--write]`
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
from pymavlink import mavutil
from pymavlink.dialects.v20 import common as mavlink

BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from px4_harness import STARTED_MARK, Px4Sitl, find_px4_sitl, flight_lock  # noqa: E402

FloatArray = npt.NDArray[np.float64]
PLAN = REPO / "examples" / "missions" / "rover_square.plan"
SECTION = "Rover fidelity: mock vs real PX4 main"
BOUND = 0.25
STREAM_HZ = 20.0
VEL_ONLY = 0b110111000111  # 3527 + yaw ignore bits: vx, vy, vz only (PX4 ignores vz on a rover)
VEL_NE = VEL_ONLY
STEP_SPEED = 2.0  # [m/s]
HOLD_S = 3.0
STEP_S = 10.0
STOP_S = 6.0
TURN_S = 10.0
TURN_JUDGE_S = 5.0
MOVING_M_S = 0.3
STOPPED_M_S = 0.1
EARTH_RADIUS_M = 6371000.0
HOME = (47.397742, 8.545594)  # PX4 SITL's home (and the mock's): the frame of the truth rows


# ----------------------------------------------------------------------------- launching


@dataclass(frozen=True)
class Endpoint:
    """Where to listen for the autopilot and its MAVLink system id."""

    kind: str
    url: str
    sysid: int




MOCK_ESTIMATOR = "ideal"  # `sitl_mock serve --estimator` of the mock flights (main sets it)
#: [s] repeat i of a target waits i x STAGGER_S after the autopilot's first HEARTBEAT before it
#: arms (main sets it): PX4 SIH's noise, and so EKF2's error, repeats at the same time since
#: boot (two starts armed alike erred alike within 0.01 m), so the repeats of a run sample
#: different stretches of it; the mock's repeat i runs `serve --seed i` for the same reason
STAGGER_S = 0.0


@contextlib.contextmanager
def launch(kind: str, folder: Path, seed: int = 0) -> Iterator[Endpoint]:
    """A fresh autopilot in real time: the mock rover (`serve --estimator MOCK_ESTIMATOR
    --seed SEED`) or PX4 main's SIH Ackermann rover (under the flight lock)."""
    folder.mkdir(parents=True, exist_ok=True)
    if kind == "px4":
        loc, why = find_px4_sitl("main")
        if loc is None:
            raise RuntimeError(f"no PX4 main SITL: {why}")
        with flight_lock() as waited:
            if waited > 1.0:
                print(f"  (waited {waited:.0f} s for the PX4 flight lock)", flush=True)
            sitl = Px4Sitl(location=loc, model="sihsim_rover_ackermann",
                           ready_mark=STARTED_MARK, log=folder / "px4-console.log")
            with sitl:
                yield Endpoint("px4", f"udpin:127.0.0.1:{sitl.port}", sitl.target_system)
        return
    if kind != "mock":
        raise ValueError(f"unknown target {kind!r}")
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = int(s.getsockname()[1])
    with open(folder / "mock-stderr.log", "w") as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "sitl_mock", "serve", "--vehicle", "rover", "--bind",
             "127.0.0.1:0", "--remote", f"127.0.0.1:{port}", "--no-gcs", "--speed", "1",
             "--estimator", MOCK_ESTIMATOR, "--seed", str(seed)],
            stdout=subprocess.PIPE, stderr=err, text=True, cwd=REPO)
        try:
            assert proc.stdout is not None
            line = proc.stdout.readline()
            if not line.startswith("sitl_mock ready"):
                raise RuntimeError(f"mock did not start: {line!r}")
            yield Endpoint("mock", f"udpin:127.0.0.1:{port}", 1)
        finally:
            proc.terminate()
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
            if proc.stdout is not None:
                proc.stdout.close()


# ----------------------------------------------------------------------------- the link


@dataclass
class Record:
    """What the autopilot sent, by receive time [s since the flight's start]."""

    # the estimate: t, x, y, vx, vy, time since boot [s] (time_boot_ms)
    lpos: list[tuple[float, ...]] = field(default_factory=list)
    att: list[tuple[float, ...]] = field(default_factory=list)  # t, yaw, yawspeed, boot [s]
    # the estimate in latitude/longitude (GLOBAL_POSITION_INT): t, north, east [m about HOME],
    # time since boot [s]; unlike LOCAL_POSITION_NED it does not depend on the EKF's origin
    gpos: list[tuple[float, ...]] = field(default_factory=list)
    # the true motion (HIL_STATE_QUATERNION): t, north, east [m about HOME], v north, v east
    # [m/s], yaw, yaw rate, its time_usec [s]
    truth: list[tuple[float, ...]] = field(default_factory=list)
    reached: list[tuple[float, int]] = field(default_factory=list)
    acks: list[tuple[float, int, int]] = field(default_factory=list)  # t, command, result
    heartbeats: list[tuple[float, int, int]] = field(default_factory=list)  # t, base, custom
    texts: list[tuple[float, str]] = field(default_factory=list)
    marks: dict[str, float] = field(default_factory=dict)


class Link:
    """One pymavlink connection, read and written from one thread (no threads at all): `pump`
    drains what arrived and streams the current setpoint at STREAM_HZ."""

    def __init__(self, ep: Endpoint) -> None:
        self.ep = ep
        self.conn: Any = mavutil.mavlink_connection(ep.url, source_system=255,
                                                    source_component=190, dialect="common")
        self.t0 = time.monotonic()
        self.rec = Record()
        self.setpoint: Callable[[], tuple[float, float] | None] = lambda: None
        self._next_sp = 0.0
        self.yaw = math.nan
        self.speed = 0.0  # true speed [m/s]
        self.mode_main = -1
        self.mode_sub = -1
        self.armed = False
        self.hil = False  # the autopilot streams HIL_STATE_QUATERNION (its truth)
        self._asked_hil = -math.inf

    def now(self) -> float:
        return time.monotonic() - self.t0

    def close(self) -> None:
        self.conn.close()

    def pump(self, duration_s: float) -> None:
        """Receive and stream for `duration_s` [s]."""
        end = self.now() + duration_s
        while True:
            t = self.now()
            if t >= end:
                return
            if t >= self._next_sp:
                self._next_sp = t + 1.0 / STREAM_HZ
                v = self.setpoint()
                if v is not None:
                    self.conn.mav.set_position_target_local_ned_send(
                        int(t * 1000) & 0xFFFFFFFF, self.ep.sysid, 1, 1, VEL_NE,
                        0, 0, 0, v[0], v[1], 0, 0, 0, 0, 0, 0)
            m = self.conn.recv_match(blocking=True, timeout=min(0.01, max(end - t, 0.001)))
            while m is not None:
                self._on(m, self.now())
                m = self.conn.recv_match(blocking=False)

    def _on(self, m: Any, t: float) -> None:
        if m.get_srcSystem() != self.ep.sysid or m.get_srcComponent() != 1:
            return
        k = m.get_type()
        r = self.rec
        if k == "LOCAL_POSITION_NED":
            r.lpos.append((t, m.x, m.y, m.vx, m.vy, m.time_boot_ms * 1e-3))
        elif k == "ATTITUDE":
            r.att.append((t, m.yaw, m.yawspeed, m.time_boot_ms * 1e-3))
            self.yaw = m.yaw
        elif k == "GLOBAL_POSITION_INT":
            ne = _ne(np.array([m.lat * 1e-7]), np.array([m.lon * 1e-7]), *HOME)[0]
            r.gpos.append((t, float(ne[0]), float(ne[1]), m.time_boot_ms * 1e-3))
        elif k == "HIL_STATE_QUATERNION":
            self.hil = True
            w, x, y, z = m.attitude_quaternion
            yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
            ne = _ne(np.array([m.lat * 1e-7]), np.array([m.lon * 1e-7]), *HOME)[0]
            r.truth.append((t, float(ne[0]), float(ne[1]), m.vx * 0.01, m.vy * 0.01, yaw,
                            m.yawspeed, m.time_usec * 1e-6))
            self.speed = math.hypot(m.vx, m.vy) * 0.01
        elif k == "MISSION_ITEM_REACHED":
            r.reached.append((t, m.seq))
        elif k == "COMMAND_ACK":
            r.acks.append((t, m.command, m.result))
        elif k == "HEARTBEAT":
            r.heartbeats.append((t, m.base_mode, m.custom_mode))
            self.mode_main = (m.custom_mode >> 16) & 0xFF
            self.mode_sub = (m.custom_mode >> 24) & 0xFF
            self.armed = bool(m.base_mode & 128)
        elif k == "STATUSTEXT":
            r.texts.append((t, m.text))

    def wait_heartbeat(self, timeout_s: float = 30.0) -> None:
        """The autopilot's first HEARTBEAT; then it is asked for its ground truth (50 Hz)."""
        end = self.now() + timeout_s
        while not self.rec.heartbeats:
            if self.now() > end:
                raise RuntimeError(f"{self.ep.kind}: no HEARTBEAT in {timeout_s:g} s")
            self.pump(0.1)
        for _ in range(50):
            self.command(511, 115.0, 20000.0)  # SET_MESSAGE_INTERVAL HIL_STATE_QUATERNION
            self.command(511, 33.0, 20000.0)  # GLOBAL_POSITION_INT at 50 Hz too
            self.pump(0.5)
            if self.hil:
                break
        if not self.hil:
            raise RuntimeError(f"{self.ep.kind}: no HIL_STATE_QUATERNION (ground truth) stream")

    def command(self, cmd: int, *params: float) -> None:
        p = [*params, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][:7]
        self.conn.mav.command_long_send(self.ep.sysid, 1, cmd, 0, *p)

    def arm(self, timeout_s: float = 40.0) -> float:
        """Arm, retried every second (PX4 main's rover refuses until its estimator is ready);
        the time of the accepting COMMAND_ACK."""
        end = self.now() + timeout_s
        while self.now() < end:
            n = len(self.rec.acks)
            self.command(400, 1.0)
            for _ in range(10):
                self.pump(0.1)
                ok = [a for a in self.rec.acks[n:] if a[1] == 400 and a[2] == 0]
                if ok:
                    return ok[0][0]
        raise RuntimeError(f"{self.ep.kind}: arming refused for {timeout_s:g} s")

    def set_mode(self, main: int, sub: int = 0, timeout_s: float = 10.0) -> None:
        end = self.now() + timeout_s
        while self.now() < end:
            self.command(176, float(1 | (128 if self.armed else 0)), float(main), float(sub))
            for _ in range(10):
                self.pump(0.1)
                if self.mode_main == main and (sub == 0 or self.mode_sub == sub):
                    return
        raise RuntimeError(f"{self.ep.kind}: mode {main}/{sub} not entered")

    def upload(self, items: list[Any], timeout_s: float = 20.0) -> None:
        """Mission upload (MISSION_COUNT, answer each request, MISSION_ACK accepted)."""
        end = self.now() + timeout_s
        self.conn.mav.mission_count_send(self.ep.sysid, 1, len(items), 0)
        last_count = self.now()
        while self.now() < end:
            m = self.conn.recv_match(type=["MISSION_REQUEST", "MISSION_REQUEST_INT",
                                           "MISSION_ACK"], blocking=True, timeout=0.2)
            if m is None:
                if self.now() - last_count > 1.0:
                    self.conn.mav.mission_count_send(self.ep.sysid, 1, len(items), 0)
                    last_count = self.now()
                continue
            if m.get_srcSystem() != self.ep.sysid:
                continue
            if m.get_type() == "MISSION_ACK":
                if m.type != 0:
                    raise RuntimeError(f"{self.ep.kind}: mission refused ({m.type})")
                return
            it = items[m.seq]
            it.target_system = self.ep.sysid
            self.conn.mav.send(it)
        raise RuntimeError(f"{self.ep.kind}: mission upload timed out")


# ----------------------------------------------------------------------------- flights


def offboard_flight(ep: Endpoint, hold_s: float = 0.0) -> Record:
    """Speed step, stop and full-steering turn in OFFBOARD (see the module docstring), armed
    `hold_s` later than the first repeat (see STAGGER_S)."""
    link = Link(ep)
    try:
        link.wait_heartbeat()
        link.setpoint = lambda: (0.0, 0.0)
        link.pump(2.0 + hold_s)
        link.rec.marks["arm"] = link.arm()
        link.pump(2.0)  # the setpoint stream is the proof of life OFFBOARD needs
        link.set_mode(6)
        link.pump(HOLD_S)
        heading = link.yaw if math.isfinite(link.yaw) else 0.0
        step = (STEP_SPEED * math.cos(heading), STEP_SPEED * math.sin(heading))
        link.setpoint = lambda: step
        link.rec.marks["step"] = link.now()
        link.pump(STEP_S)
        link.setpoint = lambda: (0.0, 0.0)
        link.rec.marks["stop"] = link.now()
        link.pump(STOP_S)

        def turn() -> tuple[float, float]:
            d = link.yaw + math.pi / 2.0
            return (STEP_SPEED * math.cos(d), STEP_SPEED * math.sin(d))

        link.setpoint = turn
        link.rec.marks["turn"] = link.now()
        link.pump(TURN_S)
        link.setpoint = lambda: (0.0, 0.0)
        link.rec.marks["end"] = link.now()
        link.pump(3.0)
        return link.rec
    finally:
        link.close()


def plan_items(plan: Path) -> tuple[list[Any], tuple[float, float], list[tuple[float, float]]]:
    """MISSION_ITEM_INT messages of a .plan of SimpleItems, its home (lat, lon) and its
    waypoints (lat, lon)."""
    doc = json.loads(plan.read_text())
    mission = doc["mission"]
    items, wps = [], []
    for seq, it in enumerate(mission["items"]):
        p = [math.nan if v is None else float(v) for v in it["params"]]
        items.append(mavlink.MAVLink_mission_item_int_message(
            0, 1, seq, int(it["frame"]), int(it["command"]), 1 if seq == 0 else 0,
            1 if it.get("autoContinue", True) else 0, p[0], p[1], p[2], p[3],
            round(p[4] * 1e7), round(p[5] * 1e7), p[6], 0))
        if int(it["command"]) == 16:
            wps.append((p[4], p[5]))
    home = mission["plannedHomePosition"]
    return items, (float(home[0]), float(home[1])), wps


def mission_flight(ep: Endpoint, plan: Path, timeout_s: float, hold_s: float = 0.0) -> Record:
    """The plan under AUTO.MISSION until the last waypoint is reached and the rover stands;
    armed `hold_s` later than the first repeat (see STAGGER_S)."""
    items, _home, _wps = plan_items(plan)
    link = Link(ep)
    try:
        link.wait_heartbeat()
        link.pump(1.0 + hold_s)
        link.upload(items)
        link.rec.marks["arm"] = link.arm()
        link.set_mode(4, 4)
        link.rec.marks["mission"] = link.now()
        end = link.now() + timeout_s
        last = len(items) - 1
        still_since = math.inf
        while link.now() < end:
            link.pump(0.2)
            if not link.armed and link.now() > link.rec.marks["arm"] + 2.0:
                link.rec.marks["end"] = link.now()
                break
            if any(s == last for _t, s in link.rec.reached):
                if link.speed < STOPPED_M_S:
                    still_since = min(still_since, link.now())
                    if link.now() - still_since > 1.0:
                        link.rec.marks["end"] = still_since
                        break
                else:
                    still_since = math.inf
        return link.rec
    finally:
        link.close()


# ----------------------------------------------------------------------------- metrics


def _arr(rows: list[tuple[float, ...]]) -> FloatArray:
    return np.asarray(rows, dtype=np.float64).reshape(len(rows), -1)


def step_metrics(rec: Record) -> dict[str, float]:
    """Rise time 10-90 % of the steady speed, overshoot, steady speed; stopping distance/time."""
    tr = _arr(rec.truth)
    t, speed = tr[:, 0], np.hypot(tr[:, 3], tr[:, 4])
    t_step, t_stop = rec.marks["step"], rec.marks["stop"]
    sel = (t >= t_step) & (t < t_stop)
    ts, vs = t[sel] - t_step, speed[sel]
    steady = float(np.mean(vs[ts >= ts[-1] - 3.0]))
    rise = (float(ts[np.argmax(vs >= 0.9 * steady)]) - float(ts[np.argmax(vs >= 0.1 * steady)]))
    grid = np.arange(0.0, 3.0, 0.1)  # the speed every 0.1 s: finite-difference acceleration
    acc = np.diff(np.interp(grid, ts, vs)) / 0.1
    out = {"dead_s": float(ts[np.argmax(vs >= STOPPED_M_S)]), "rise_s": rise,
           "overshoot": float(np.max(vs)) / STEP_SPEED - 1.0, "steady_m_s": steady,
           "peak_acc_m_s2": float(np.max(acc))}
    sel = (t >= t_stop) & (t < t_stop + STOP_S)
    tt, vv, ne = t[sel] - t_stop, speed[sel], tr[sel, 1:3]
    moving = np.nonzero(vv >= STOPPED_M_S)[0]
    k = min(int(moving[-1]) + 1 if len(moving) else 0, len(tt) - 1)
    out["stop_s"] = float(tt[k])
    out["stop_m"] = float(np.sum(np.hypot(*np.diff(ne[: k + 1], axis=0).T)))
    return out


def circle_fit(xy: FloatArray) -> tuple[float, float, float]:
    """Least-squares circle (centre x, centre y, radius) through points (Kasa's algebraic fit)."""
    x, y = xy[:, 0], xy[:, 1]
    a = np.column_stack([x, y, np.ones_like(x)])
    b = x * x + y * y
    sol, *_ = np.linalg.lstsq(a, b, rcond=None)
    cx, cy = sol[0] / 2.0, sol[1] / 2.0
    return float(cx), float(cy), float(math.sqrt(sol[2] + cx * cx + cy * cy))


def turn_metrics(rec: Record) -> dict[str, float]:
    """Speed, |yaw rate| and circle radius over the turn's last TURN_JUDGE_S."""
    tr = _arr(rec.truth)
    t1 = rec.marks["end"]
    sel = (tr[:, 0] >= t1 - TURN_JUDGE_S) & (tr[:, 0] < t1)
    return {"turn_speed_m_s": float(np.mean(np.hypot(tr[sel, 3], tr[sel, 4]))),
            "turn_yaw_rate_rad_s": float(np.mean(np.abs(tr[sel, 6]))),
            "turn_radius_m": circle_fit(tr[sel, 1:3])[2]}


def _ne(lat: FloatArray, lon: FloatArray, lat0: float, lon0: float) -> FloatArray:
    """(north, east) [m] about (lat0, lon0), equirectangular (plenty for a 30 m square)."""
    n = np.radians(lat - lat0) * EARTH_RADIUS_M
    e = np.radians(lon - lon0) * EARTH_RADIUS_M * math.cos(math.radians(lat0))
    return np.column_stack([n, e])


def _seg_dist(p: FloatArray, a: FloatArray, b: FloatArray) -> FloatArray:
    ab = b - a
    u = np.clip(((p - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.asarray(np.hypot(*(p - (a + u[:, None] * ab)).T), dtype=np.float64)


def mission_metrics(rec: Record, plan: Path) -> dict[str, Any]:
    """Armed time, closest approach per waypoint, cross-track RMS from the legs while moving."""
    _items, home, wps = plan_items(plan)
    tr = _arr(rec.truth)
    t0, t1 = rec.marks["arm"], rec.marks.get("end", math.nan)
    sel = (tr[:, 0] >= t0) & (tr[:, 0] <= (t1 if math.isfinite(t1) else math.inf))
    shift = _ne(np.array([home[0]]), np.array([home[1]]), *HOME)[0]  # plan home in HOME's frame
    p = tr[sel, 1:3] - shift
    speed = np.hypot(tr[sel, 3], tr[sel, 4])
    corners = np.vstack([[0.0, 0.0], _ne(np.array([w[0] for w in wps]),
                                         np.array([w[1] for w in wps]), *home)])
    closest, k0 = [], 0  # each waypoint after the previous one's closest approach
    for c in corners[1:]:
        d_c = np.hypot(*(p[k0:] - c).T)
        k = int(np.argmin(d_c))
        closest.append(float(d_c[k]))
        k0 += k
    d = np.min(np.column_stack([_seg_dist(p, corners[i], corners[i + 1])
                                for i in range(len(corners) - 1)]), axis=1)
    moving = speed > MOVING_M_S
    each = {f"closest_wp{i + 1}_m": c for i, c in enumerate(closest)}
    return {"armed_s": t1 - t0, "closest_m": closest, **each, "closest_max_m": max(closest),
            "xtrack_rms_m": float(np.sqrt(np.mean(d[moving] ** 2))),
            "xtrack_max_m": float(np.max(d[moving])), "finished": math.isfinite(t1)}


# ----------------------------------------------------------------------------- table

NOTE = ("The mock rover (`sitl_mock serve --vehicle rover`, defaults) against PX4 main "
        "(02e73e3b6f48, SIH rover, airframe 10045), the same MAVLink inputs in one run, judged on "
        "the true motion (HIL_STATE_QUATERNION; the mock's ideal estimate is its truth). Goal: "
        "|mock / PX4 - 1| <= 25 %.")
AFTER = ("PX4 steers by EKF2's estimate, which on SIH wanders 0.15-0.25 m per axis (std) and "
         "1-3 deg in heading (median; PX4's ULogs) off the truth; the mock rover steers by its "
         "truth: the decimetre path figures (closest approaches, cross-track) carry "
         "EKF2's error on PX4's side; see docs/guides/mock.md, \"The rover measured against real "
         "PX4 main\".")
SUB_EKF2 = "The mock with EKF2-like estimate errors (`--mock-estimator ekf2`)"


def run_stamp() -> str:
    """'YYYY-MM-DD HH:MM UTC, git <short sha>' (+ ' with uncommitted changes' when dirty)."""
    def git(*a: str) -> str:
        return subprocess.run(["git", *a], cwd=REPO, capture_output=True, text=True,
                              check=False).stdout.strip()

    dirty = git("status", "--porcelain", "--untracked-files=no")
    stamp = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    sha = git("rev-parse", "--short", "HEAD")
    return f"{stamp}, git {sha}" + (" with uncommitted changes" if dirty else "")


def note_estimator(out: Path) -> str:
    """What the subsection's run changed, the preset's values and (if `out` holds
    rover_estimate_error.py's result for PX4) what they were measured from."""
    from sitl_mock.__main__ import ROVER_ESTIMATOR_PRESETS

    pre = ROVER_ESTIMATOR_PRESETS["ekf2"]
    vals = ", ".join(f"{k} {v:g}" for k, v in pre.items())
    text = ("The mock rover as above but with `serve --estimator ekf2` (" + vals + "): it "
            "steers by an estimate with EKF2-like Gauss-Markov errors (horizontal position, "
            "velocity, heading), a heading bias per start and a position lead along the motion, "
            "and both autopilots are judged on their truth "
            "(HIL_STATE_QUATERNION, which the mock now streams on request too).")
    meas = out / "estimate-error-px4.json"
    if meas.exists():
        m = json.loads(meas.read_text())
        d, s = m.get("driving", {}), m.get("standing", {})
        md = m.get("by_flight", {}).get("mission", {})
        text += (f" The preset's measurement (bench/rover_estimate_error.py over PX4 flights "
                 f"flown before this run, {m['flights']} traces; per flight mean removed): "
                 f"driving, position std N/E {d.get('pos_std_ne_m')} m, velocity "
                 f"{d.get('vel_std_ne_m_s')} m/s, heading {d.get('yaw_std_deg')} deg (rover_square "
                 f"alone {md.get('driving', {}).get('yaw_std_deg')} deg, tau "
                 f"{md.get('yaw_tau_s')} s); standing, position {s.get('pos_std_ne_m')} m, "
                 f"velocity {s.get('vel_std_ne_m_s')} m/s, heading {s.get('yaw_std_deg')} deg; "
                 f"time constants (the model's autocorrelation fitted) position "
                 f"{m.get('pos_tau_s')} s, velocity {m.get('vel_tau_s')} s.")
        lh = m.get("lead_and_heading", {})
        if lh:
            legs = lh.get("legs", {})
            text += (f" From GLOBAL_POSITION_INT (geodetic, free of the EKF's origin): the "
                     f"estimate leads the truth by {lh['lead_s']} s of travel (by speed "
                     f"{lh['lead_s_by_speed']}), {lh['residual']['pos_std_ne_m']} m (N / E std) "
                     f"left after it, tau {lh['residual']['tau_s']} s; rover_square's legs: "
                     f"heading error per flight {legs.get('heading_mean_by_flight_deg')} deg "
                     f"(RMS {legs.get('heading_rms_of_flight_means_deg')}), the estimate "
                     f"{legs.get('offset_rms_m')} m RMS beside the leg, "
                     f"{legs.get('offset_gain_k_m')} m x tan(heading error).")
    return text


ROWS: tuple[tuple[str, str, str], ...] = (
    ("dead_s", "speed step 0 -> 2 m/s: command to 0.1 m/s", "s"),
    ("rise_s", "speed step: rise time 10-90 %", "s"),
    ("peak_acc_m_s2", "speed step: peak acceleration (0.1 s differences)", "m/s^2"),
    ("overshoot", "speed step: overshoot (peak / setpoint - 1)", ""),
    ("steady_m_s", "speed step: steady speed", "m/s"),
    ("stop_m", "stop from the step's speed: distance", "m"),
    ("stop_s", "stop: time to below 0.1 m/s", "s"),
    ("turn_speed_m_s", "turn at full steering: speed", "m/s"),
    ("turn_yaw_rate_rad_s", "turn at full steering: yaw rate", "rad/s"),
    ("turn_radius_m", "turn at full steering: radius", "m"),
    ("armed_s", "rover_square AUTO.MISSION: armed time", "s"),
    ("closest_wp1_m", "rover_square: closest approach to waypoint 1 (corner)", "m"),
    ("closest_wp2_m", "rover_square: closest approach to waypoint 2 (corner)", "m"),
    ("closest_wp3_m", "rover_square: closest approach to waypoint 3 (corner)", "m"),
    ("closest_wp4_m", "rover_square: closest approach to waypoint 4 (the end, home)", "m"),
    ("xtrack_rms_m", "rover_square: cross-track RMS while driving", "m"),
)


def fly(kind: str, out: Path, repeat: int, timeout_s: float, reuse: bool = False,
        first: int = 0) -> list[dict[str, Any]]:
    """`repeat` offboard and mission flights on `kind`; their metrics (and traces on disk).
    `reuse`: no flights, the metrics of the traces a previous run left in `out`."""
    runs = []
    for i in range(first, first + repeat):
        res: dict[str, Any] = {}
        folder = out / f"{kind}-{i}"
        for name in ("offboard", "mission"):
            t_wall = time.perf_counter()
            trace = folder / f"{name}-trace.json"
            try:
                if reuse:
                    rec = Record(**json.loads(trace.read_text()))
                else:
                    with launch(kind, folder / name, seed=i) as ep:
                        rec = (offboard_flight(ep, i * STAGGER_S) if name == "offboard"
                               else mission_flight(ep, PLAN, timeout_s, i * STAGGER_S))
                    trace.write_text(json.dumps(rec.__dict__))
                if name == "offboard":
                    res.update(step_metrics(rec))
                    res.update(turn_metrics(rec))
                else:
                    res.update(mission_metrics(rec, PLAN))
            except Exception as exc:  # a failed flight is a row of NaN, not a lost run
                res[f"{name}_error"] = f"{type(exc).__name__}: {exc}"
            print(f"  {kind} {name} {i}: {time.perf_counter() - t_wall:.0f} s wall "
                  f"{ {k: v for k, v in res.items() if not isinstance(v, list)} }", flush=True)
        runs.append(res)
    return runs


def _values(runs: list[dict[str, Any]], key: str) -> list[float]:
    return [float(r[key]) for r in runs if key in r and isinstance(r[key], (int, float))]


def median(runs: list[dict[str, Any]], key: str) -> float:
    vals = _values(runs, key)
    return float(np.median(vals)) if vals else math.nan


def spread(runs: list[dict[str, Any]], key: str) -> str:
    """` (min-max)` of a row over the repeats ('' for fewer than two)."""
    vals = _values(runs, key)
    return f" ({min(vals):.3g}-{max(vals):.3g})" if len(vals) > 1 else ""


def table(results: dict[str, list[dict[str, Any]]]) -> str:
    """The fidelity table: per row the median over each target's repeats (their range in
    brackets) and mock / PX4 - 1 of the medians against BOUND."""
    lines = ["| row | mock | real PX4 main | mock / PX4 - 1 | within 25 % |",
             "|---|---|---|---|---|"]
    mock, px4 = results.get("mock", []), results.get("px4", [])
    for key, label, unit in ROWS:
        m, p = median(mock, key), median(px4, key)
        r = m / p - 1.0 if math.isfinite(m) and math.isfinite(p) and p != 0 else math.nan
        ok = "yes" if abs(r) <= BOUND else ("no" if math.isfinite(r) else "-")
        u = f" {unit}" if unit else ""
        lines.append(f"| {label} | {m:.3g}{u}{spread(mock, key)} | {p:.3g}{u}{spread(px4, key)} "
                     f"| {r:+.0%} | {ok} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--target", nargs="+", choices=("mock", "px4"), default=["mock", "px4"])
    ap.add_argument("--repeat", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=150.0, help="mission flight bound [s]")
    ap.add_argument("--out", type=Path, default=Path("/tmp/ecca-bench-rover-fidelity"))
    ap.add_argument("--write", action="store_true", help="write the table to BENCHMARKS.md")
    ap.add_argument("--reuse", action="store_true",
                    help="fly nothing: recompute the table from the traces in --out")
    ap.add_argument("--stagger", type=float, default=0.0,
                    help="repeat i arms i x STAGGER s later after boot, and the mock's runs "
                         "`serve --seed i` (independent estimate-error realisations)")
    ap.add_argument("--first", type=int, default=0,
                    help="number the repeats from FIRST (folders, seeds and stagger): more "
                         "independent samples in a second run")
    ap.add_argument("--mock-estimator", choices=("ideal", "ekf2"), default="ideal",
                    help="`sitl_mock serve --estimator` of the mock flights (ekf2: the estimate "
                         "errors measured on PX4 main's rover; --write then writes a subsection)")
    args = ap.parse_args(argv)
    global MOCK_ESTIMATOR, STAGGER_S
    MOCK_ESTIMATOR = args.mock_estimator
    STAGGER_S = args.stagger
    t0 = time.perf_counter()
    results = {k: fly(k, args.out, args.repeat, args.timeout, args.reuse, args.first)
               for k in args.target}
    (args.out / "results.json").write_text(json.dumps(results, indent=1))
    text = table(results)
    print(text)
    if args.write:
        if set(args.target) != {"mock", "px4"}:
            ap.error("--write needs both targets")
        from benchmarks_md import write_section

        given = list(argv if argv is not None else sys.argv[1:])
        words = [w for i, w in enumerate(given) if w not in ("--write", "--reuse", "--out")
                 and (i == 0 or given[i - 1] != "--out")]
        cmd = " ".join(["python bench/bench_rover_fidelity.py", *words, "--write"])
        how = ("recomputed with --reuse from the traces of that run" if args.reuse
               else f"{time.perf_counter() - t0:.0f} s wall")
        if args.mock_estimator != "ideal":
            from benchmarks_md import write_subsection

            write_subsection(SECTION, SUB_EKF2, f"### {SUB_EKF2}\n\n`{cmd}` ({args.repeat} "
                             f"flight(s) per target, medians; {how}; {run_stamp()}). "
                             f"{note_estimator(args.out)}\n\n{text}\n")
            return 0
        write_section(SECTION, f"## {SECTION}\n\n`{cmd}` ({args.repeat} flight(s) per target, "
                      f"medians; {how}). {NOTE}\n\n{text}\n\n{AFTER}\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
