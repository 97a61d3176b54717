"""Setpoint quality judged from a flight's tlog alone, as an outsider would: the companion's
SET_ATTITUDE_TARGET frames against the vehicle's own LOCAL_POSITION_NED and
EXTENDED_SYS_STATE. Independent of `companion.flight.report` (which measures the same things
from inside the setpoint source): shared by the replay and the real-PX4 tests."""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from pymavlink import mavutil

#: MAV_LANDED_STATE_IN_AIR
_IN_AIR = 2


@dataclass
class SetpointSeries:
    """What a tlog shows of the attitude/rates setpoints sent and the vehicle at each one."""

    t_s: list[float] = field(default_factory=list)
    thrust: list[float] = field(default_factory=list)
    tilt_deg: list[float | None] = field(default_factory=list)  # None: attitude ignored
    body_rates: list[tuple[float, float, float] | None] = field(default_factory=list)
    in_air: list[bool] = field(default_factory=list)
    height_m: list[float] = field(default_factory=list)  # above the first position sample

    def thrust_steps(self, max_dt_s: float = 0.02, min_height_m: float = 0.5
                     ) -> list[tuple[float, float]]:
        """(time [s], |thrust change|) between consecutive setpoints at most `max_dt_s`
        apart while the vehicle is in the air (PX4's landed state) and more than
        `min_height_m` up, at both of them."""
        out = []
        for i in range(1, len(self.t_s)):
            if self.t_s[i] - self.t_s[i - 1] > max_dt_s:
                continue
            if not (self.in_air[i] and self.in_air[i - 1]):
                continue
            if min(self.height_m[i], self.height_m[i - 1]) <= min_height_m:
                continue
            out.append((self.t_s[i], abs(self.thrust[i] - self.thrust[i - 1])))
        return out

    def max_tilt_deg(self) -> float:
        """Largest commanded tilt (quaternion setpoints) [deg]; 0 without any."""
        return max((t for t in self.tilt_deg if t is not None), default=0.0)

    def max_body_rates(self) -> tuple[float, float, float]:
        """Largest |commanded body rate| per axis (rates setpoints) [rad/s]."""
        rows = [r for r in self.body_rates if r is not None]
        return tuple(max((abs(r[k]) for r in rows), default=0.0) for k in range(3))  # type: ignore[return-value]


def _frames(path: str) -> Iterator[tuple[Any, str, float | None]]:
    """Every frame of the tlog at `path` with its type and the vehicle's height [m] above its
    first LOCAL_POSITION_NED sample then (None before it), or above its first DISTANCE_SENSOR
    reading where that is less: PX4 SIH's downward rangefinder sees the ground, the estimate's
    height drifts (real PX4 in CI, 2026-12-02: the vehicle touched down at 0.85 m by the
    estimate, and the thrust step of the touchdown counted as one in the air)."""
    conn = mavutil.mavlink_connection(path, dialect="common")
    z0: float | None = None
    d0: float | None = None
    est: float | None = None
    rng = math.inf
    try:
        while True:
            msg = conn.recv_match(blocking=False)
            if msg is None:
                break
            kind = msg.get_type()
            if kind == "LOCAL_POSITION_NED":
                if z0 is None:
                    z0 = float(msg.z)
                est = z0 - float(msg.z)
            elif kind == "DISTANCE_SENSOR":
                d = float(msg.current_distance) * 0.01
                if d0 is None:
                    d0 = d
                rng = d - d0 if msg.current_distance < msg.max_distance else math.inf
            yield msg, kind, None if est is None else min(est, rng)
    finally:
        conn.close()


def read_setpoints(path: str) -> SetpointSeries:
    """The SET_ATTITUDE_TARGET frames of the tlog at `path` with the vehicle state then."""
    out = SetpointSeries()
    in_air = False
    for msg, kind, height in _frames(path):
        if kind == "EXTENDED_SYS_STATE":
            in_air = int(msg.landed_state) == _IN_AIR
        elif kind == "SET_ATTITUDE_TARGET":
            mask = int(msg.type_mask)
            _w, x, y, _z = (float(c) for c in msg.q)
            tilt = None
            if not mask & 128:
                c33 = 1.0 - 2.0 * (x * x + y * y)  # z_b . e3 of the commanded attitude
                tilt = math.degrees(math.acos(max(-1.0, min(1.0, c33))))
            rates = None
            if not mask & 3:
                rates = (float(msg.body_roll_rate), float(msg.body_pitch_rate),
                         float(msg.body_yaw_rate))
            out.t_s.append(float(msg._timestamp))
            out.thrust.append(float(msg.thrust))
            out.tilt_deg.append(tilt)
            out.body_rates.append(rates)
            out.in_air.append(in_air)
            out.height_m.append(0.0 if height is None else height)
    return out


def attitude_wobble_deg(path: str, min_height_m: float = 3.0, window_s: float = 0.5) -> float:
    """How much the vehicle rocks, from its own ATTITUDE frames in the tlog at `path`: roll
    and pitch [deg] resampled at 100 Hz on the vehicle's clock (time_boot_ms) while it is more
    than `min_height_m` above its first position sample, less their centred `window_s` moving
    mean (a 1.2 Hz oscillation passes, a corner's lean mostly not); the RMS of the two
    together [deg]. Independent of the companion's own measure
    (`companion.flight.report.SetpointQuality`, which sees the commands)."""
    rows: list[tuple[float, float, float]] = []
    for msg, kind, height in _frames(path):
        if kind == "ATTITUDE" and height is not None and height > min_height_m:
            rows.append((msg.time_boot_ms / 1e3, math.degrees(float(msg.roll)),
                         math.degrees(float(msg.pitch))))
    if len(rows) < 100:
        raise ValueError(f"{path}: {len(rows)} ATTITUDE frames above {min_height_m} m")
    rows.sort()
    t = np.array([r[0] for r in rows])
    grid = np.arange(t[0], t[-1], 0.01)
    n = round(window_s / 0.01) | 1
    half = n // 2
    total = 0.0
    for k in (1, 2):
        y = np.interp(grid, t, np.array([r[k] for r in rows]))
        hp = (y - np.convolve(y, np.ones(n) / n, mode="same"))[half:-half]
        total += float(np.mean(hp * hp))
    return math.sqrt(total)
