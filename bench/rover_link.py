"""A small threaded pymavlink client for real-PX4 rover measurements (bench_rover_interfaces.py,
bench_missions.py's rover flights): independent of the companion's MAVLink code, so what it
measures is PX4's behaviour, not the companion's.

`RoverLink(port, sysid)` listens where PX4's onboard link sends (udpin on 127.0.0.1:port), keeps
PX4's latest HEARTBEAT / LOCAL_POSITION_NED / ATTITUDE / HIL_STATE_QUATERNION / HOME_POSITION,
every COMMAND_ACK and STATUSTEXT (receive time in Unix seconds), and writes every received
message to a .tlog (pymavlink's format: 8-byte big-endian microseconds + the frame). Sending
happens from the caller's thread only (the receiver thread never sends). Every wait is bounded.
"""

from __future__ import annotations

import contextlib
import math
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pymavlink import mavutil

OFFBOARD = 6 << 16
HOLD = (4 << 16) | (3 << 24)
MISSION = (4 << 16) | (4 << 24)
MODE_NAMES = {OFFBOARD: "OFFBOARD", HOLD: "HOLD", MISSION: "MISSION",
              (4 << 16) | (5 << 24): "RTL", (4 << 16) | (6 << 24): "LAND",
              1 << 16: "MANUAL", 3 << 16: "POSCTL", 2 << 16: "ALTCTL", 5 << 16: "ACRO",
              7 << 16: "STABILIZED", (4 << 16) | (2 << 24): "TAKEOFF"}


def _param_value(m: Any) -> float:
    """PARAM_VALUE's value: PX4 sends integer parameters (param_type 1-6, e.g. 6 INT32) as
    their bit pattern in the float field (MAVLink's bytewise encoding)."""
    v = float(m.param_value)
    if 1 <= m.param_type <= 6:
        return float(struct.unpack("<i", struct.pack("<f", v))[0])
    return v


def mode_name(custom_mode: int) -> str:
    return MODE_NAMES.get(custom_mode, f"custom {custom_mode}")


@dataclass
class Sample:
    """One LOCAL_POSITION_NED (t: receive time, Unix s; boot_s: PX4's time_boot)."""

    t: float
    boot_s: float
    x: float
    y: float
    vx: float
    vy: float


@dataclass
class RoverLink:
    """See the module doc."""

    port: int
    sysid: int
    tlog: Path | None = None
    source_system: int = 246
    conn: Any = None
    heartbeat: Any = None
    heartbeats: list[tuple[float, int, int]] = field(default_factory=list)  # t, base, custom
    lpos: list[Sample] = field(default_factory=list)
    att: list[tuple[float, float, float]] = field(default_factory=list)  # t, boot_s, yaw [rad]
    # t, lat [deg], lon [deg], alt [m], yaw [rad] (HIL_STATE_QUATERNION: the simulator's truth)
    truth: list[tuple[float, float, float, float, float]] = field(default_factory=list)
    home: Any = None
    acks: list[tuple[float, Any]] = field(default_factory=list)
    texts: list[tuple[float, str]] = field(default_factory=list)
    params: dict[str, float] = field(default_factory=dict)
    mission_msgs: list[Any] = field(default_factory=list)
    reached: list[tuple[float, int]] = field(default_factory=list)  # MISSION_ITEM_REACHED
    messages: dict[str, int] = field(default_factory=dict)
    _stop: threading.Event = field(default_factory=threading.Event)
    _thread: threading.Thread | None = None
    _log: Any = None
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def __enter__(self) -> RoverLink:
        self.conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{self.port}",
                                               source_system=self.source_system,
                                               source_component=191, dialect="common")
        if self.tlog is not None:
            self._log = open(self.tlog, "wb")
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5.0)
        if self.conn is not None:
            self.conn.close()
        if self._log is not None:
            self._log.close()

    # -- receiving ---------------------------------------------------------------------------
    def _run(self) -> None:
        c = self.conn
        while not self._stop.is_set():
            try:
                m = c.recv_match(blocking=True, timeout=0.1)
            except (OSError, ValueError):
                continue
            if m is None:
                continue
            now = time.time()
            kind = m.get_type()
            if kind == "BAD_DATA":
                continue
            if self._log is not None:
                with self._lock:
                    self._log.write(int(now * 1e6).to_bytes(8, "big") + m.get_msgbuf())
            if m.get_srcSystem() != self.sysid:
                continue
            self.messages[kind] = self.messages.get(kind, 0) + 1
            if kind == "STATUSTEXT":
                self.texts.append((now, m.text))
            if m.get_srcComponent() != 1:
                continue
            if kind == "HEARTBEAT":
                self.heartbeat = m
                self.heartbeats.append((now, m.base_mode, m.custom_mode))
            elif kind == "LOCAL_POSITION_NED":
                self.lpos.append(Sample(now, m.time_boot_ms * 1e-3, m.x, m.y, m.vx, m.vy))
            elif kind == "ATTITUDE":
                self.att.append((now, m.time_boot_ms * 1e-3, m.yaw))
            elif kind == "HIL_STATE_QUATERNION":
                w, x, y, z = m.attitude_quaternion
                yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
                self.truth.append((now, m.lat * 1e-7, m.lon * 1e-7, m.alt * 1e-3, yaw))
            elif kind == "HOME_POSITION":
                self.home = m
            elif kind == "COMMAND_ACK":
                self.acks.append((now, m))
            elif kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"):
                self.mission_msgs.append(m)
            elif kind == "MISSION_ITEM_REACHED":
                self.reached.append((now, int(m.seq)))
            elif kind == "PARAM_VALUE":
                self.params[m.param_id] = _param_value(m)

    # -- state -------------------------------------------------------------------------------
    @property
    def armed(self) -> bool:
        return self.heartbeat is not None and bool(self.heartbeat.base_mode & 128)

    @property
    def mode(self) -> int:
        return -1 if self.heartbeat is None else int(self.heartbeat.custom_mode)

    def wait(self, cond: Callable[[], bool], timeout_s: float, poll_s: float = 0.02,
             tick: Callable[[], None] | None = None) -> bool:
        """Poll `cond` (calling `tick`, e.g. a setpoint sender, each time) until it holds or
        `timeout_s` passes; whether it held."""
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            if tick is not None:
                tick()
            if cond():
                return True
            time.sleep(poll_s)
        return cond()

    def wait_heartbeat(self, timeout_s: float = 20.0) -> bool:
        return self.wait(lambda: self.heartbeat is not None and self.conn.address is not None,
                         timeout_s, 0.05)

    # -- sending -----------------------------------------------------------------------------
    @property
    def mav(self) -> Any:
        return self.conn.mav

    def command(self, command: int, *params: float, confirmation: int = 0) -> None:
        p = [*params, *([0.0] * (7 - len(params)))]
        self.mav.command_long_send(self.sysid, 1, command, confirmation, *p)

    def command_ack(self, command: int, *params: float, timeout_s: float = 1.5,
                    settle_s: float = 0.3, tick: Callable[[], None] | None = None) -> int | None:
        """COMMAND_LONG, retried every 0.5 s; the last ACK result for it within `settle_s` of
        the first (PX4 acks DO_SET_MODE twice: receipt, then the commander's verdict); None
        without an ACK."""
        n0 = len(self.acks)
        t_end = time.monotonic() + timeout_s
        sent = 0
        while time.monotonic() < t_end:
            self.command(command, *params, confirmation=sent)
            sent += 1
            if self.wait(lambda: any(a.command == command for _, a in self.acks[n0:]), 0.5,
                         tick=tick):
                self.wait(lambda: False, settle_s, tick=tick)
                res = [a.result for _, a in self.acks[n0:] if a.command == command]
                return int(res[-1])
        return None

    def set_message_interval(self, msg_id: int, hz: float) -> int | None:
        return self.command_ack(511, msg_id, 1e6 / hz)

    def read_param(self, name: str, timeout_s: float = 2.0) -> float:
        """PARAM_REQUEST_READ by name (retried); NaN if PX4 does not answer."""
        self.params.pop(name, None)
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            self.mav.param_request_read_send(self.sysid, 1, name.encode(), -1)
            if self.wait(lambda: name in self.params, 0.4):
                return self.params[name]
        return math.nan

    def set_mode(self, custom_mode: int, tick: Callable[[], None] | None = None
                 ) -> int | None:
        main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
        return self.command_ack(176, 1 | (128 if self.armed else 0), main, sub, tick=tick)

    def arm(self, timeout_s: float = 30.0, tick: Callable[[], None] | None = None
            ) -> tuple[bool, float]:
        """ARM, retried every second until accepted (PX4 main's rover refuses until its
        estimator is ready); (armed, seconds it took)."""
        t0 = time.monotonic()
        t_end = t0 + timeout_s
        while time.monotonic() < t_end:
            res = self.command_ack(400, 1.0, tick=tick, settle_s=0.0)
            if res == 0 and self.wait(lambda: self.armed, 2.0, tick=tick):
                return True, time.monotonic() - t0
            self.wait(lambda: False, 1.0, tick=tick)
        return False, time.monotonic() - t0

    def upload_mission(self, items: list[Any], timeout_s: float = 15.0) -> int:
        """Upload MISSION_ITEM_INTs (objects with seq, frame, command, current, autocontinue,
        param1-4, x, y, z): MISSION_COUNT, answer every MISSION_REQUEST(_INT) with the item,
        until MISSION_ACK; its MAV_MISSION_RESULT (0 accepted), -1 on timeout."""
        self.mission_msgs.clear()
        self.mav.mission_count_send(self.sysid, 1, len(items), 0)
        t_end = time.monotonic() + timeout_s
        handled, last_count = 0, time.monotonic()
        while time.monotonic() < t_end:
            if len(self.mission_msgs) <= handled:
                if handled == 0 and time.monotonic() - last_count > 1.0:  # lost: ask again
                    self.mav.mission_count_send(self.sysid, 1, len(items), 0)
                    last_count = time.monotonic()
                time.sleep(0.01)
                continue
            m = self.mission_msgs[handled]
            handled += 1
            if m.get_type() == "MISSION_ACK":
                return int(m.type)
            it = items[m.seq]
            self.mav.mission_item_int_send(self.sysid, 1, m.seq, it.frame, it.command,
                                           1 if m.seq == 0 else 0, it.autocontinue, it.param1,
                                           it.param2, it.param3, it.param4, it.x, it.y, it.z, 0)
        return -1

    # -- setpoints ---------------------------------------------------------------------------
    def position_target(self, type_mask: int, x: float = 0.0, y: float = 0.0, vx: float = 0.0,
                        vy: float = 0.0, yaw: float = 0.0, yaw_rate: float = 0.0,
                        frame: int = 1, z: float = 0.0, afx: float = 0.0, afy: float = 0.0
                        ) -> None:
        """SET_POSITION_TARGET_LOCAL_NED (frame 1 LOCAL_NED)."""
        self.mav.set_position_target_local_ned_send(
            0, self.sysid, 1, frame, type_mask, x, y, z, vx, vy, 0.0, afx, afy, 0.0, yaw,
            yaw_rate)

    def attitude_target(self, type_mask: int, q_wxyz: tuple[float, float, float, float],
                        thrust: float, yaw_rate: float = 0.0) -> None:
        """SET_ATTITUDE_TARGET (q body FRD -> NED; thrust normalised)."""
        self.mav.set_attitude_target_send(0, self.sysid, 1, type_mask, list(q_wxyz), 0.0, 0.0,
                                          yaw_rate, thrust)

    def actuator_control_target(self, controls: list[float], group: int = 0) -> None:
        """SET_ACTUATOR_CONTROL_TARGET (id 139; deprecated in MAVLink)."""
        self.mav.set_actuator_control_target_send(0, group, self.sysid, 1,
                                                  [*controls, *([0.0] * (8 - len(controls)))])

    # -- helpers -----------------------------------------------------------------------------
    def texts_since(self, t: float) -> list[str]:
        return [s for tt, s in self.texts if tt >= t]

    def heartbeat_modes(self, t0: float, t1: float = math.inf) -> list[tuple[float, str, bool]]:
        """(t, mode, armed) of each HEARTBEAT in [t0, t1]."""
        return [(t, mode_name(c), bool(b & 128)) for t, b, c in self.heartbeats if t0 <= t <= t1]


class Streamer:
    """Calls `send()` at `hz` when ticked (from a wait loop or the caller's own loop)."""

    def __init__(self, send: Callable[[], None], hz: float = 20.0) -> None:
        self.send = send
        self.period = 1.0 / hz
        self._next = 0.0
        self.count = 0

    def __call__(self) -> None:
        now = time.monotonic()
        if now >= self._next:
            with contextlib.suppress(OSError):
                self.send()
                self.count += 1
            self._next = max(self._next + self.period, now - self.period)
