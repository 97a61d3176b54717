"""Pure summary of a flown trajectory: waypoints reached, tracking error, duration, and the
quality of the setpoints sent (:class:`SetpointQuality`, every flight: replay, fly, serve).

Shared by `fly` and `serve` (replay has its own, richer report from its lockstep log). Inputs are
position samples (NED, m) and the reference each was compared with; nothing here reads a clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.mission.px4_params import Px4PlanningParams

FloatArray = NDArray[np.float64]

#: Commanded normalised thrust may change by at most this much over 10 ms while airborne
#: (the setpoint-smoothness goal; a step above it is counted in the report).
THRUST_STEP_GOAL = 0.05
#: A thrust change over 10 ms above this is chatter (a motor jolt: half of a 0.5 hover thrust)
#: and the flight's result is not "ok". Steps between the goal and this are counted only: a lossy
#: link (10 % loss, 50 ms latency) makes steps of ~0.15 where a late sample arrives.
THRUST_STEP_FAIL = 0.25
#: A commanded tilt above the vehicle's limit by more than this fails the flight [deg].
TILT_MARGIN_DEG = 0.5
#: A commanded body rate above the vehicle's limit by more than this share fails the flight.
RATE_MARGIN = 0.02


@dataclass(frozen=True)
class SetpointLimits:
    """What the vehicle allows a setpoint to command: tilt of the thrust axis from vertical
    [rad] (PX4's MPC_TILTMAX_AIR) and body rates [rad/s], FRD (MC_ROLLRATE_MAX,
    MC_PITCHRATE_MAX, MC_YAWRATE_MAX). The defaults are PX4 v1.16's."""

    tilt_max_rad: float = math.radians(45.0)
    rate_max_frd: tuple[float, float, float] = (
        math.radians(220.0), math.radians(220.0), math.radians(200.0))

    def __post_init__(self) -> None:
        if not 0.0 < self.tilt_max_rad < math.radians(89.0):
            raise ValueError(f"tilt limit must be in (0, 89) deg, got "
                             f"{math.degrees(self.tilt_max_rad):g}")
        if not all(math.isfinite(r) and r > 0.0 for r in self.rate_max_frd):
            raise ValueError(f"body rate limits must be > 0, got {self.rate_max_frd}")

    @classmethod
    def of_px4(cls, px4: Px4PlanningParams) -> SetpointLimits:
        """The limits in the vehicle's PX4 parameters (deg, deg/s)."""
        return cls(math.radians(px4.MPC_TILTMAX_AIR),
                   (math.radians(px4.MC_ROLLRATE_MAX), math.radians(px4.MC_PITCHRATE_MAX),
                    math.radians(px4.MC_YAWRATE_MAX)))


class SetpointQuality:
    """Running figures of the attitude/rates setpoints a flight sent (pure; O(1) memory).

    `add` each setpoint with its local time [s]: normalised thrust, the commanded tilt (the
    thrust axis from vertical [rad]: from the quaternion sent, or in rates mode the attitude the
    controller steers to), the commanded body rates FRD [rad/s] (rates mode; attitude mode: only
    the yaw-rate feed-forward), and whether the vehicle is in the air. The thrust step is the
    change from the command in force 10 ms earlier, counted only while airborne and not across
    a gap (the first setpoint after arming, or after position setpoints, has none). Time over a
    limit adds each setpoint's period (at most 0.1 s) while over it."""

    def __init__(self, limits: SetpointLimits | None = None) -> None:
        self.limits = limits or SetpointLimits()
        self.setpoints = 0
        self.max_thrust_step = 0.0
        self.thrust_steps_over_goal = 0
        self.max_tilt_rad = 0.0
        self.over_tilt_s = 0.0
        self.max_rate_frd = [0.0, 0.0, 0.0]
        self.over_rate_s = 0.0
        self._hist: deque[tuple[float, float]] = deque(maxlen=32)
        self._t_last: float | None = None

    def gap(self) -> None:
        """A setpoint of another kind went out (e.g. a position setpoint while priming): the
        next thrust has no predecessor to step from."""
        self._hist.clear()
        self._t_last = None

    def add(self, t_s: float, thrust: float, tilt_rad: float,
            rates_frd: tuple[float, float, float], airborne: bool) -> None:
        """Record one setpoint (see the class docstring)."""
        if not (math.isfinite(t_s) and math.isfinite(thrust)):
            return
        self.setpoints += 1
        dt = 0.0 if self._t_last is None else min(max(t_s - self._t_last, 0.0), 0.1)
        self._t_last = t_s
        lim = self.limits
        if airborne:
            hist = self._hist
            before = None
            for t_i, u_i in reversed(hist):
                if t_i <= t_s - 0.01 + 1e-6:
                    before = (t_i, u_i)
                    break
            if before is None and hist:
                before = hist[0]  # setpoints slower than 100 Hz: the one before
            if before is not None and t_s - before[0] <= 0.03:
                step = abs(thrust - before[1])
                self.max_thrust_step = max(self.max_thrust_step, step)
                if step > THRUST_STEP_GOAL:
                    self.thrust_steps_over_goal += 1
            hist.append((t_s, thrust))
        else:
            self._hist.clear()
        if math.isfinite(tilt_rad):
            self.max_tilt_rad = max(self.max_tilt_rad, tilt_rad)
            if tilt_rad > lim.tilt_max_rad + 1e-6:  # (a command clamped at it: round-off)
                self.over_tilt_s += dt
        over = False
        for i in range(3):
            r = abs(rates_frd[i])
            if math.isfinite(r):
                self.max_rate_frd[i] = max(self.max_rate_frd[i], r)
                over = over or r > lim.rate_max_frd[i] + 1e-6
        if over:
            self.over_rate_s += dt

    def report(self) -> dict[str, Any]:
        """The figures for a flight report (keys carry units)."""
        lim = self.limits
        return {
            "setpoints": self.setpoints,
            "max_thrust_step_10ms": round(self.max_thrust_step, 4),
            "thrust_steps_over_goal": self.thrust_steps_over_goal,
            "thrust_step_goal": THRUST_STEP_GOAL,
            "max_tilt_cmd_deg": round(math.degrees(self.max_tilt_rad), 2),
            "tilt_limit_deg": round(math.degrees(lim.tilt_max_rad), 2),
            "time_over_tilt_limit_s": round(self.over_tilt_s, 3),
            "max_body_rate_cmd_rad_s": [round(r, 3) for r in self.max_rate_frd],
            "body_rate_limit_rad_s": [round(r, 3) for r in lim.rate_max_frd],
            "time_over_body_rate_limit_s": round(self.over_rate_s, 3),
        }

    def failure(self) -> str | None:
        """Why the setpoints make the flight not "ok" (None: they do not): a commanded tilt or
        body rate over the vehicle's limit by more than its margin, or thrust chatter."""
        lim = self.limits
        if math.degrees(self.max_tilt_rad - lim.tilt_max_rad) > TILT_MARGIN_DEG:
            return (f"commanded tilt {math.degrees(self.max_tilt_rad):.1f} deg over the "
                    f"vehicle's limit {math.degrees(lim.tilt_max_rad):.1f} deg "
                    f"for {self.over_tilt_s:.2f} s")
        for i, axis in enumerate(("roll", "pitch", "yaw")):
            if self.max_rate_frd[i] > lim.rate_max_frd[i] * (1.0 + RATE_MARGIN):
                return (f"commanded {axis} rate {self.max_rate_frd[i]:.2f} rad/s over the "
                        f"vehicle's limit {lim.rate_max_frd[i]:.2f} rad/s")
        if self.max_thrust_step > THRUST_STEP_FAIL:
            return (f"thrust chatter: the commanded thrust changed by {self.max_thrust_step:.2f} "
                    f"within 10 ms in the air")
        return None


def closest_approach(points: FloatArray, wps: FloatArray) -> FloatArray:
    """Smallest distance [m] of `points` (N, 3) to each waypoint of `wps` (K, 3); inf if no
    points."""
    if len(points) == 0 or len(wps) == 0:
        return np.full(len(wps), math.inf)
    out = np.empty(len(wps))
    for i, w in enumerate(wps):
        out[i] = float(np.min(np.linalg.norm(points - w, axis=1)))
    return out


@dataclass
class TrackRecorder:
    """Collects (time [s], flown position NED [m], reference position NED [m]) samples."""

    t_s: list[float] = field(default_factory=list)
    pos_ned: list[tuple[float, float, float]] = field(default_factory=list)
    ref_ned: list[tuple[float, float, float]] = field(default_factory=list)

    def add(self, t_s: float, pos_ned: Sequence[float] | FloatArray,
            ref_ned: Sequence[float] | FloatArray) -> None:
        """Record one sample."""
        self.t_s.append(float(t_s))
        self.pos_ned.append((float(pos_ned[0]), float(pos_ned[1]), float(pos_ned[2])))
        self.ref_ned.append((float(ref_ned[0]), float(ref_ned[1]), float(ref_ned[2])))

    def summary(
        self,
        waypoints_ned: FloatArray | None,
        acceptance_m: Sequence[float],
        *,
        duration_s: float,
        planned_duration_s: float,
    ) -> dict[str, Any]:
        """Report dict (keys carry units): duration, RMS/max error of flown vs reference,
        closest approach to and reached flag of every waypoint (within its acceptance radius)."""
        pos = np.asarray(self.pos_ned, dtype=np.float64).reshape(-1, 3)
        ref = np.asarray(self.ref_ned, dtype=np.float64).reshape(-1, 3)
        err = np.linalg.norm(pos - ref, axis=1)
        wps = (np.zeros((0, 3)) if waypoints_ned is None
               else np.asarray(waypoints_ned, dtype=np.float64).reshape(-1, 3))
        acc = np.asarray(list(acceptance_m), dtype=np.float64)
        if len(acc) != len(wps):
            raise ValueError(f"{len(wps)} waypoints but {len(acc)} acceptance radii")
        closest = closest_approach(pos, wps)
        return {
            "duration_s": round(float(duration_s), 3),
            "planned_duration_s": round(float(planned_duration_s), 3),
            "samples": len(err),
            "rms_error_m": float(np.sqrt(np.mean(err**2))) if len(err) else None,
            "max_error_m": float(np.max(err)) if len(err) else None,
            "waypoints": [
                {"north_m": float(w[0]), "east_m": float(w[1]), "down_m": float(w[2]),
                 "acceptance_radius_m": float(a),
                 "closest_approach_m": float(c) if math.isfinite(c) else None,
                 "reached": bool(c <= a)}
                for w, a, c in zip(wps, acc, closest, strict=True)
            ],
            "waypoints_reached": int(np.count_nonzero(closest <= acc)),
        }
