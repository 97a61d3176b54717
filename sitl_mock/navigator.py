"""AUTO-mode setpoint generation (takeoff, land, loiter/hold, goto, RTL): pure, no clock.

The navigator turns a goal into a smooth, velocity- and acceleration-limited PositionTarget
stream: a reference point ("carrot") moves toward the goal at most at the cruise speed
(MPC_XY_CRUISE horizontally, MPC_Z_VEL_MAX_UP / MPC_Z_VEL_MAX_DN or MPC_TKO_SPEED vertically),
accelerating at most MPC_ACC_HOR and braking so that it stops on the goal. The target carries
the reference position, velocity and acceleration (feed-forward), like PX4's auto flight tasks.

The autopilot core owns modes and mission sequencing and calls these methods; `update(dt, state)`
is called every control period and returns the target for the vehicle. Frame: local NED about
home (home at (0, 0, 0) unless `home_ned` is set), SI units.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from sitl_mock.rover_control import (
    RoverParams,
    arrival_speed,
    corner_acceptance_radius,
    speed_from_distance,
    transition_angle,
)
from sitl_mock.setpoints import NAN3, PositionTarget, RoverPositionTarget, Vec3
from sitl_mock.vehicle_state import VehicleState

_isfinite = math.isfinite
_NAN = math.nan
FACE_WAYPOINT_MIN_DIST_M = 1.0  # below this horizontal distance the heading is held


class Navigator:
    """Target generator for AUTO modes; see the module docstring.

    Phases: "idle", "takeoff", "loiter", "goto", "land", "landed", "rtl_climb", "rtl_return".
    `reached` is True once a takeoff altitude, a goto goal (within the acceptance radius and
    NAV_MC_ALT_RAD vertically), a landing (vehicle landed) or an RTL (landed at home) is done;
    it is always True while loitering.

    ground_vehicle=True (rover, PX4's Ackermann AUTO mode): `update` returns a
    RoverPositionTarget, the leg from the previous waypoint (`start_ned`, else the rover) to the
    goal with the arrival speed and the corner acceptance radius PX4's rover computes from the
    next waypoint (`next_ned`); a goal counts as reached within the larger of that radius and
    the item's (or NAV_ACC_RAD). The cruise speed is RO_SPEED_LIM (DO_CHANGE_SPEED: at most
    that); heights and yaw are ignored; takeoff and land complete at once (phase "landed" =
    stopped); RTL drives home and stops there; while not driving a goal the target is a stop.
    """

    def __init__(
        self,
        params: Mapping[str, float],
        home_ned: Vec3 = (0.0, 0.0, 0.0),
        ground_vehicle: bool = False,
    ) -> None:
        self._p = params
        self.home_ned: Vec3 = home_ned
        self.ground_vehicle = ground_vehicle
        self.phase = "idle"
        self.reached = False
        self._goal: Vec3 = (0.0, 0.0, 0.0)
        self._acc_rad = 2.0
        self._yaw_goal = _NAN
        self._yaw_hold = _NAN
        self._ref_pos: list[float] | None = None
        self._ref_vel = [0.0, 0.0, 0.0]
        self._ref_acc = [0.0, 0.0, 0.0]
        self._up_limit = 0.0
        self._rtl_alt = 0.0
        self._land_xy: tuple[float, float] = (0.0, 0.0)
        self._cruise = math.nan
        self._start_ne: tuple[float, float] = (_NAN, _NAN)  # ground: the leg's start
        self._next_ne: tuple[float, float] | None = None  # ground: the waypoint after the goal
        self._stop_at_goal = True  # ground: arrive at the goal at 0 speed

    def set_cruise_speed(self, speed_m_s: float) -> None:
        """Horizontal cruise speed for goto/RTL [m/s] (DO_CHANGE_SPEED); NaN or <= 0 restores
        MPC_XY_CRUISE. Capped at MPC_XY_VEL_MAX."""
        ok = _isfinite(speed_m_s) and speed_m_s > 0.0
        self._cruise = float(speed_m_s) if ok else math.nan

    @property
    def cruise_speed(self) -> float:
        """Horizontal cruise speed in use [m/s]."""
        if self.ground_vehicle:  # PX4's rover: the item's cruising speed within RO_SPEED_LIM
            lim = self._p["RO_SPEED_LIM"]
            return max(min(self._cruise, lim) if _isfinite(self._cruise) else lim, 0.1)
        c = self._cruise if _isfinite(self._cruise) else self._p["MPC_XY_CRUISE"]
        c = min(c, self._p["MPC_XY_VEL_MAX"])
        return max(c, 0.1)

    # ------------------------------------------------------------------ commands
    def takeoff(self, alt_rel_m: float, state: VehicleState) -> None:
        """Climb vertically to `alt_rel_m` above home (z = -alt) at MPC_TKO_SPEED, then hold."""
        if not _isfinite(alt_rel_m):
            raise ValueError("takeoff altitude must be finite")
        x, y, _ = state.pos_ned
        self._start(state, (x, y, self.home_ned[2] - alt_rel_m), _NAN, 0.0, "takeoff")
        self._up_limit = self._p["MPC_TKO_SPEED"]
        if self.ground_vehicle:
            self.reached = True
            return
        if state.on_ground or state.landed:
            self._ref_pos = None  # the reference starts climbing when the vehicle lifts off

    def land(self, state: VehicleState) -> None:
        """Descend at the current horizontal position (MPC_LAND_SPEED near the ground)."""
        self._begin_hold(state)
        assert self._ref_pos is not None
        self._land_xy = self._stop_point(state)[:2]
        self.phase = "land"
        self.reached = bool(state.landed)
        if self.ground_vehicle:
            self._start(state, self._stop_point(state), _NAN, 0.0, "landed")
            self.reached = True

    def loiter(self, state: VehicleState) -> None:
        """Brake and hold at the stopping point (PX4 Hold / AUTO.LOITER)."""
        stop = self._stop_point(state)
        self._start(state, stop, _NAN, 0.0, "loiter")
        self.reached = True

    def goto(self, pos_ned: Vec3, yaw: float, acceptance_m: float, state: VehicleState,
             start_ned: Vec3 | None = None, next_ned: Vec3 | None = None,
             stop: bool = True) -> None:
        """Fly to `pos_ned` [m NED]; `yaw` [rad] or NaN to face the goal; reached within radius.

        A ground vehicle drives the leg from `start_ned` (the previous waypoint; None: from where
        it is) and, unless `stop`, passes the goal at the corner speed towards `next_ned`."""
        if not all(_isfinite(c) for c in pos_ned):
            raise ValueError("goto position must be finite")
        acc = (
            acceptance_m if _isfinite(acceptance_m) and acceptance_m > 0 else self._p["NAV_ACC_RAD"]
        )
        self._start(state, pos_ned, yaw, acc, "goto")
        self._ground_leg(state, start_ned, None if stop else next_ned)

    def rtl(self, state: VehicleState) -> None:
        """Return: climb to max(RTL_RETURN_ALT, current height), fly home, land."""
        height = self.home_ned[2] - state.pos_ned[2]
        self._rtl_alt = max(self._p["RTL_RETURN_ALT"], height)
        x, y, _ = state.pos_ned
        if self.ground_vehicle:
            hx, hy, _ = self.home_ned
            self._start(state, (hx, hy, state.pos_ned[2]), _NAN, 0.0, "rtl_return")
            self._ground_leg(state, None, None)
            return
        self._start(state, (x, y, self.home_ned[2] - self._rtl_alt), _NAN, 0.0, "rtl_climb")

    def forget_reference(self) -> None:
        """Start the next command's reference at the vehicle (PX4 resets its AUTO trajectory
        when the AUTO flight task is activated, e.g. on entering Hold from OFFBOARD)."""
        self._ref_pos = None
        self._ref_vel = [0.0, 0.0, 0.0]
        self._ref_acc = [0.0, 0.0, 0.0]

    # ------------------------------------------------------------------ internals
    def _stop_point(self, state: VehicleState) -> Vec3:
        """Where the vehicle stops when braking at MPC_ACC_HOR from its current velocity."""
        a = max(self._p["MPC_ACC_HOR"], 0.1)
        (x, y, z), (vx, vy, vz) = state.pos_ned, state.vel_ned
        if state.on_ground:
            return (x, y, z)
        return (x + vx * abs(vx) / (2 * a), y + vy * abs(vy) / (2 * a), z + vz * abs(vz) / (2 * a))

    def _begin_hold(self, state: VehicleState) -> None:
        if self._ref_pos is None or self._dist(self._ref_pos, state.pos_ned) > 3.0:
            self._ref_pos = list(state.pos_ned)
            self._ref_vel = list(state.vel_ned)
        if not _isfinite(self._yaw_hold):
            self._yaw_hold = state.yaw

    @staticmethod
    def _dist(a: list[float] | Vec3, b: Vec3) -> float:
        return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)

    def _start(
        self, state: VehicleState, goal: Vec3, yaw: float, acc_rad: float, phase: str
    ) -> None:
        self._begin_hold(state)
        gz = state.pos_ned[2] if self.ground_vehicle else goal[2]
        self._goal = (float(goal[0]), float(goal[1]), float(gz))
        self._yaw_goal = yaw
        self._acc_rad = acc_rad
        self._up_limit = self._p["MPC_Z_VEL_MAX_UP"]
        self.phase = phase
        self.reached = False

    def _vertical_acc(self, up: bool) -> float:
        p = self._p
        if not up:
            return max(p["MPC_ACC_DOWN_MAX"], 0.1)
        a = p["MPC_ACC_UP_MAX"]
        if self.phase == "takeoff" and self.home_ned[2] - self._ref_z() < p["MPC_LAND_ALT1"]:
            # PX4 emulates the motor ramp near the ground: MPC_TKO_SPEED / MPC_TKO_RAMP_T
            a = min(a, p["MPC_TKO_SPEED"] / max(p["MPC_TKO_RAMP_T"], 0.1))
        return max(a, 0.05)

    def _ref_z(self) -> float:
        return self._ref_pos[2] if self._ref_pos is not None else 0.0

    def _time_stretch(self, state: VehicleState) -> float:
        """Fraction of `dt` the reference advances by (PX4's PositionSmoothing): while the vehicle
        is behind the reference, 1 - (horizontal distance / MPC_XY_ERR_MAX), down to 0, so the
        reference waits for a vehicle that cannot keep up (drag, tilt); 1 when the vehicle is
        ahead of it. The reference's velocity stays the feed-forward. Multicopters only."""
        emax = self._p["MPC_XY_ERR_MAX"]
        ref = self._ref_pos
        if self.ground_vehicle or ref is None or not emax > 0.0:
            return 1.0
        ex, ey = ref[0] - state.pos_ned[0], ref[1] - state.pos_ned[1]
        if ex * self._ref_vel[0] + ey * self._ref_vel[1] < 0.0:
            return 1.0
        return 1.0 - min(math.hypot(ex, ey) / emax, 1.0)

    def _advance_ref(self, dt: float) -> None:
        """Move the reference toward the goal with speed and acceleration limits (`dt` [s] of
        reference time; 0 holds it)."""
        if not dt > 0.0:
            return
        p = self._p
        ref = self._ref_pos
        assert ref is not None
        a_h = max(p["MPC_ACC_HOR"], 0.1)
        dx, dy, dz = self._goal[0] - ref[0], self._goal[1] - ref[1], self._goal[2] - ref[2]
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        rv = self._ref_vel
        if dist < 1e-4 and rv[0] ** 2 + rv[1] ** 2 + rv[2] ** 2 < 1e-6:
            ref[0], ref[1], ref[2] = self._goal
            self._ref_vel = [0.0, 0.0, 0.0]
            self._ref_acc = [0.0, 0.0, 0.0]
            return
        dxy = math.hypot(dx, dy)
        a_v = self._vertical_acc(dz < 0.0)
        # speed along the line: braking distance and per-axis speed limits
        a_line = math.inf
        s = math.inf
        if dxy > 1e-9:
            a_line = a_h * dist / dxy
            s = self.cruise_speed * dist / dxy
        if abs(dz) > 1e-9:
            a_line = min(a_line, a_v * dist / abs(dz))
            vz_lim = self._up_limit if dz < 0.0 else p["MPC_Z_VEL_MAX_DN"]
            s = min(s, max(vz_lim, 0.1) * dist / abs(dz))
        # jerk-limited on the legs (goto, RTL return); takeoff, RTL climb and Hold as before
        # (measured on PX4 SITL: the mock's takeoff to 10 m already took PX4's time, 12.4 s,
        # and a Hold's stopping point assumes the acceleration limit alone)
        jerk = p["MPC_JERK_AUTO"] if self.phase in ("goto", "rtl_return") else 0.0
        if jerk > 0.0:
            # PX4's jerk-limited braking law; the last part at a tenth of the acceleration so
            # the reference reaches the goal in finite time (the law alone tends to v ~ d)
            s = min(s, max(speed_from_distance(jerk, a_line, dist),
                           math.sqrt(0.2 * a_line * dist)))
        else:
            s = min(s, math.sqrt(2.0 * 0.9 * a_line * dist))
        k = s / dist if dist > 1e-9 else 0.0
        ex, ey, ez = dx * k - rv[0], dy * k - rv[1], dz * k - rv[2]
        if jerk > 0.0:
            ex, ey, ez = self._jerk_limited(ex, ey, ez, a_h, dt, jerk)
        else:
            exy = math.hypot(ex, ey)
            if exy > a_h * dt:
                f = a_h * dt / exy
                ex, ey = ex * f, ey * f
            a_vz = self._vertical_acc(ez < 0.0) * dt
            ez = max(-a_vz, min(a_vz, ez))
        nv = [rv[0] + ex, rv[1] + ey, rv[2] + ez]
        step = [0.5 * (rv[i] + nv[i]) * dt for i in range(3)]
        # never step past the goal
        if step[0] ** 2 + step[1] ** 2 + step[2] ** 2 >= dist * dist:
            ref[0], ref[1], ref[2] = self._goal
            nv = [0.0, 0.0, 0.0]
            self._ref_acc = [0.0, 0.0, 0.0]
        else:
            for i in range(3):
                ref[i] += step[i]
            self._ref_acc = [ex / dt, ey / dt, ez / dt]
        self._ref_vel = nv

    def _jerk_limited(self, ex: float, ey: float, ez: float, a_h: float, dt: float, jerk: float
                      ) -> tuple[float, float, float]:
        """Velocity change over `dt` toward the velocity error (ex, ey, ez) [m/s] with the
        acceleration limits and the jerk limit MPC_JERK_AUTO (PX4's AUTO trajectories are
        jerk-limited): the acceleration aims at min(a_max, sqrt(2 jerk |error|)), the most that
        can still be ramped to zero without overshooting, and changes by at most jerk * dt."""
        a0 = self._ref_acc
        jdt = jerk * dt
        h = 0.5 * jdt  # discrete ramp: a / (j dt) steps of dt change v by a^2 / (2 j) + a dt / 2

        def most(err: float) -> float:
            return -h + math.sqrt(h * h + 2.0 * jerk * err)

        exy = math.hypot(ex, ey)
        axy = min(a_h, most(exy))
        tx, ty = (ex / exy * axy, ey / exy * axy) if exy > 1e-9 else (0.0, 0.0)
        a_v = self._vertical_acc(ez < 0.0)
        tz = math.copysign(min(a_v, most(abs(ez))), ez)
        cx, cy = tx - a0[0], ty - a0[1]
        cxy = math.hypot(cx, cy)
        if cxy > jdt:
            cx, cy = cx * jdt / cxy, cy * jdt / cxy
        cz = max(-jdt, min(jdt, tz - a0[2]))
        ax, ay, az = a0[0] + cx, a0[1] + cy, a0[2] + cz
        # never beyond the velocity error itself (no overshoot at the end of a ramp)
        if abs(ax * dt) > abs(ex):
            ax = ex / dt
        if abs(ay * dt) > abs(ey):
            ay = ey / dt
        if abs(az * dt) > abs(ez):
            az = ez / dt
        return ax * dt, ay * dt, az * dt

    def _yaw_target(self, state: VehicleState) -> float:
        if _isfinite(self._yaw_goal):
            self._yaw_hold = self._yaw_goal
            return self._yaw_goal
        if self.phase in ("goto", "rtl_return"):
            dx, dy = self._goal[0] - state.pos_ned[0], self._goal[1] - state.pos_ned[1]
            if math.hypot(dx, dy) > FACE_WAYPOINT_MIN_DIST_M:
                self._yaw_hold = math.atan2(dy, dx)
        if not _isfinite(self._yaw_hold):
            self._yaw_hold = state.yaw
        return self._yaw_hold

    def _land_speed(self, height_m: float) -> float:
        """Descent speed [m/s] at `height_m` above home (PX4 FlightTaskAuto land): MPC_Z_VEL_MAX_DN
        above MPC_LAND_ALT1, MPC_LAND_SPEED below MPC_LAND_ALT2, linear in between, and
        MPC_LAND_CRWL below MPC_LAND_ALT3 while the distance sensor (SIH's, range
        SIH_DISTSNSR_MIN..SIH_DISTSNSR_MAX over flat ground at home height) sees the ground."""
        p = self._p
        if (p["SIH_DISTSNSR_MIN"] <= height_m <= p["SIH_DISTSNSR_MAX"]
                and height_m <= p["MPC_LAND_ALT3"]):
            return p["MPC_LAND_CRWL"]
        slow, fast = p["MPC_LAND_SPEED"], max(p["MPC_Z_VEL_MAX_DN"], p["MPC_LAND_SPEED"])
        alt1, alt2 = p["MPC_LAND_ALT1"], p["MPC_LAND_ALT2"]
        if height_m <= alt2:
            return slow
        if height_m >= alt1 or alt1 <= alt2:
            return fast
        return slow + (fast - slow) * (height_m - alt2) / (alt1 - alt2)

    # ------------------------------------------------------------------ ground vehicle
    def _ground_leg(self, state: VehicleState, start_ned: Vec3 | None,
                    next_ned: Vec3 | None) -> None:
        x, y, _ = state.pos_ned
        self._start_ne = (start_ned[0], start_ned[1]) if start_ned is not None else (x, y)
        self._next_ne = (next_ned[0], next_ned[1]) if next_ned is not None else None
        self._stop_at_goal = next_ned is None

    def ground_leg(self) -> RoverPositionTarget:
        """The rover's target for the current leg (PX4's AckermannAutoMode: corner acceptance
        radius and arrival speed from the waypoint transition angle)."""
        p = RoverParams.read(self._p)
        goal = (self._goal[0], self._goal[1])
        angle = transition_angle(self._start_ne, goal, self._next_ne)
        cruise = self.cruise_speed
        return RoverPositionTarget(
            goal, self._start_ne, cruise, arrival_speed(cruise, angle, self._stop_at_goal, p),
            corner_acceptance_radius(angle, p))

    def _update_ground(self, state: VehicleState) -> RoverPositionTarget:
        if self.phase not in ("goto", "rtl_return"):
            if self.phase in ("loiter", "landed", "takeoff"):
                self.reached = True
            return RoverPositionTarget((_NAN, _NAN))
        tgt = self.ground_leg()
        gx, gy = tgt.position_ne
        dist = math.hypot(state.pos_ned[0] - gx, state.pos_ned[1] - gy)
        if self.phase == "goto":
            self.reached = dist <= max(self._acc_rad, tgt.acceptance_radius_m)
        elif dist <= tgt.acceptance_radius_m:  # RTL: home reached, stop there
            self._land_xy = (gx, gy)
            self.phase = "landed"
            self.reached = True
            return RoverPositionTarget((_NAN, _NAN))
        return tgt

    # ------------------------------------------------------------------ update
    def update(self, dt: float, state: VehicleState) -> PositionTarget | RoverPositionTarget:
        """Advance by dt [s] and return the target for the vehicle."""
        if not dt > 0.0:
            raise ValueError("navigator dt must be positive")
        if self.phase == "idle":
            self.loiter(state)
        if self.ground_vehicle:
            return self._update_ground(state)
        if self._ref_pos is None:
            if self.phase == "takeoff" and (state.on_ground or state.landed):
                # ask for a climb; the vehicle's takeoff ramp shapes the lift-off
                x, y, _ = self._goal
                self._yaw_target(state)
                return PositionTarget(
                    pos_ned=(x, y, _NAN),
                    vel_ned=(_NAN, _NAN, -self._p["MPC_TKO_SPEED"]),
                    yaw=self._yaw_hold,
                )
            self._ref_pos = list(state.pos_ned)
            self._ref_vel = list(state.vel_ned)
        if self.phase in ("land", "landed") and not self.ground_vehicle:
            return self._update_land(state)
        self._advance_ref(dt * self._time_stretch(state))
        ref = self._ref_pos
        gx, gy, gz = self._goal
        px, py, pz = state.pos_ned
        at_ref_goal = ref[0] == gx and ref[1] == gy and ref[2] == gz
        if self.phase == "takeoff":
            self.reached = at_ref_goal and abs(pz - gz) <= 0.5
        elif self.phase == "goto":
            self.reached = (
                math.hypot(px - gx, py - gy) <= self._acc_rad
                and abs(pz - gz) <= self._p["NAV_MC_ALT_RAD"]
            )
        elif self.phase in ("loiter", "landed"):
            self.reached = True
        elif self.phase == "rtl_climb":
            if abs(pz - gz) <= self._p["NAV_MC_ALT_RAD"] and at_ref_goal:
                hx, hy, _ = self.home_ned
                self._goal = (hx, hy, gz)
                self.phase = "rtl_return"
        elif self.phase == "rtl_return" and at_ref_goal and math.hypot(px - gx, py - gy) < 1.0:
            self._land_xy = (gx, gy)
            self.phase = "landed" if self.ground_vehicle else "land"
            self.reached = self.ground_vehicle
        yaw = self._yaw_target(state)
        return PositionTarget(
            pos_ned=(ref[0], ref[1], ref[2]),
            vel_ned=(self._ref_vel[0], self._ref_vel[1], self._ref_vel[2]),
            acc_ned=(self._ref_acc[0], self._ref_acc[1], self._ref_acc[2]),
            yaw=yaw,
        )

    def _update_land(self, state: VehicleState) -> PositionTarget:
        height = self.home_ned[2] - state.pos_ned[2]
        if state.landed:
            self.phase = "landed"
            self.reached = True
        self._ref_pos = [self._land_xy[0], self._land_xy[1], state.pos_ned[2]]
        self._ref_vel = [0.0, 0.0, 0.0]
        yaw = self._yaw_target(state)
        return PositionTarget(
            pos_ned=(self._land_xy[0], self._land_xy[1], _NAN),
            vel_ned=(_NAN, _NAN, self._land_speed(height)),
            acc_ned=NAN3,
            yaw=yaw,
        )
