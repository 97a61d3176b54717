"""Setpoint sources for every mode: a reference (planned flat outputs over time) plus telemetry
in, one MAVLink setpoint out. Pure: used by `Vehicle.fly` (real time) and by the replay
(simulated time) alike, so both fly exactly the same code.

A source follows the `companion.aio` contract: `source(t_s, telemetry) -> SetpointCommand`,
with `t_s` the flight time [s] and `telemetry.now_s` the local clock of the cycle. The reference
is sampled at `t_s`, except where a source governs its own reference time (a rover's
`ProgressGovernor`; `TrackingSource.reference_time_s`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Literal

import numpy as np

from companion.control import (
    AttitudeCommand,
    Reference,
    RoverController,
    ShapedReference,
    ShapingConfig,
    StateEstimate,
    TrackingConfig,
    TrackingController,
    position_command,
    state_estimate_of_arrays,
)
from companion.flatness import MultirotorParams
from companion.flight.clock import SampleClock
from companion.flight.governor import (
    FEASIBLE_AHEAD_S,
    FEASIBLE_EVERY,
    FEASIBLE_MIN_DIST,
    FEASIBLE_SHARE,
    ProgressGovernor,
    TimeScaler,
    feasible_rate,
    warped,
)
from companion.flight.lean import lean_of_reference, lean_residual, tilt_ne_of_q, tilt_of_q
from companion.flight.report import FlightEstimates, SetpointLimits, SetpointQuality
from companion.flight.touchdown import TOUCHDOWN_FROM_M as TOUCHDOWN_FROM_M
from companion.flight.touchdown import TOUCHDOWN_TIMEOUT_S as TOUCHDOWN_TIMEOUT_S
from companion.flight.touchdown import Touchdown as Touchdown
from companion.mavlink.setpoints import (
    AttitudeSetpoint,
    PositionSetpoint,
    RatesSetpoint,
    SetpointCommand,
)
from companion.mavlink.telemetry import TelemetrySnapshot

SetpointMode = Literal["position", "attitude", "rates", "rover"]
ReferenceFn = Callable[[float], Reference]


#: A rover's path point (`TrackingSource._path_point`): searched from this long [s] before the
#: last one to the reference time, on this many samples, then refined this many times.
PATH_SEARCH_BACK_S = 0.2
PATH_SEARCH_SAMPLES = 8
PATH_SEARCH_REFINE = 4
#: A rover is commanded the planned speed of its path this far [s] ahead of the point beside it
#: (PX4's rover answers a speed command ~0.5 s late).
SPEED_LEAD_S = 0.5




#: The largest round-trip time [s] `estimate_from_telemetry` moves a sample back by (beyond it the
#: controller's extrapolation is capped anyway: `TrackingConfig.max_extrapolation_s`).
MAX_LINK_RTT_S = 0.2




#: The touchdown's tilt limit leaves this much [rad] above the tilt holding still in the
#: estimated wind needs (`TrackingSource._landing_tilt`).
LANDING_TILT_MARGIN_RAD = math.radians(5.0)
#: A vehicle PX4 calls in the air is off the ground once this much [m] above where it stood
#: (`TrackingSource._lift_off`).
LIFTOFF_M = 0.3
#: The handover [s] when attitude or rates setpoints follow position setpoints in OFFBOARD (the
#: flight's first; serve's join after its hold stream): PX4 v1.16's commander republishes
#: vehicle_control_mode only "at 2 Hz or immediately when changed", and a changed offboard
#: setpoint kind is not a change, so for up to 0.5 s its position controller goes on flying
#: the last position setpoint, its attitude setpoints interleaved with ours (real PX4 SITL,
#: serve: our thrust applied 0.5 s after the first attitude setpoint, PX4's own 0.44-0.48 until
#: then). Meanwhile the law holds the vehicle where it is (its reference time stands at 0) and
#: learns nothing from commands PX4 may not apply (integrator, disturbance, hover thrust, drag);
#: then the reference starts from where the vehicle is (BLEND_M). PX4's 0.5 s period plus its
#: commander loop and the link.
HANDOVER_S = 0.6
#: After the handover the reference's clock ramps up from standing still over this long [s] of
#: flight time (`_ramp`: its rate a cubic smoothstep, so no velocity or acceleration step and no
#: thrust step where the plan starts accelerating; it ends RAMP_S / 2 behind). Short: a vehicle
#: still moving after the handover is braked, then pulled back while the reference waits (1 s:
#: 0.44-0.55 m/s back toward the last waypoint on real PX4, 0.3 s: 0.05-0.29).
RAMP_S = 0.3
#: After the handover the reference starts from where the vehicle is, its offset from the
#: reference's start fading out over the first this many metres [m] the reference moves
#: (`TrackingSource._blended`).
BLEND_M = 2.0
#: ... or over this long [s] of reference time, whichever ends first (a plan that hovers).
BLEND_T_S = 4.0


def estimate_from_telemetry(
    snap: TelemetrySnapshot, clock: SampleClock | None = None
) -> StateEstimate | None:
    """Controller input from the latest LOCAL_POSITION_NED/ODOMETRY and ATTITUDE_QUATERNION
    (None until both have arrived); its velocity is `LocalPosition.vel_corrected_ned` (the
    reported one plus the part its own position does not bear out). `t_s` is
    the position's sample time on the local clock when
    a `SampleClock` is given, else its receive time; then moved back by the link's round-trip
    time `snap.link_rtt_s` when it is known (at most MAX_LINK_RTT_S).

    Why the whole round trip: the sample clock finds when a sample was taken only up to the
    link's smallest one-way latency (a constant latency is invisible to it), and a setpoint
    sent now acts one uplink latency later. Sample time minus the downlink latency, minus the
    uplink latency, is the sample time minus the round trip: the controller's extrapolation
    from `t_s` to now then predicts the state at the moment its command takes effect, and
    `t_s` pairs with the commands that acted on the sample. Without it, 30 ms of telemetry
    latency on the mock drove a whirl of up to 45 deg of tilt in attitude mode that grew all
    flight (0.19 m RMS: the report saw nothing); with it the flight is the nominal one."""
    pos, att = snap.position, snap.attitude
    if pos is None or att is None:
        return None
    airborne = snap.extended.in_air if snap.extended is not None else True
    t_s = pos.t_s if clock is None else clock.local_time(pos.time_boot_s, pos.t_s)
    rtt = snap.link_rtt_s
    if rtt > 0.0:  # (NaN: unknown)
        t_s -= min(rtt, MAX_LINK_RTT_S)
    # float tuples of the decoded messages -> float64 arrays: StateEstimate's own conversions
    # would leave them as they are
    return state_estimate_of_arrays(
        t_s,
        np.array(pos.pos_ned, dtype=np.float64),
        np.array(pos.vel_corrected_ned, dtype=np.float64),
        np.array(att.q_wxyz, dtype=np.float64),
        np.array(att.omega_frd, dtype=np.float64),
        airborne,
    )


def vehicle_limited(config: TrackingConfig, limits: SetpointLimits) -> TrackingConfig:
    """`config` with its tilt clamp and body-rate command limits within the vehicle's."""
    ag = config.attitude_gains
    rp = min(ag.max_rate_rp, limits.rate_max_frd[0], limits.rate_max_frd[1])
    yaw = min(ag.max_rate_yaw, limits.rate_max_frd[2])
    tilt = min(config.max_tilt_rad, limits.tilt_max_rad)
    if (rp, yaw, tilt) == (ag.max_rate_rp, ag.max_rate_yaw, config.max_tilt_rad):
        return config
    return replace(config, max_tilt_rad=tilt,
                   attitude_gains=replace(ag, max_rate_rp=rp, max_rate_yaw=yaw))


def _level_q(q_wxyz: np.ndarray) -> tuple[float, float, float, float]:
    """The level attitude (roll = pitch = 0) with the yaw of `q_wxyz` (3-2-1), as (w, x, y, z)."""
    w, x, y, z = (float(c) for c in q_wxyz)
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return (math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw))


def _tuple3(v: np.ndarray) -> tuple[float, float, float] | None:
    x, y, z = (float(c) for c in v.tolist())
    if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
        return None
    return (x, y, z)


def _opt(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


def _ramp(t_s: float) -> tuple[float, tuple[float, float] | None]:
    """The reference time at flight time `t_s` [s] after the handover, and while it ramps up
    (the first RAMP_S) (its rate, the rate's derivative [1/s]): rate 3u^2 - 2u^3 of
    u = t_s / RAMP_S; after it, flight time less RAMP_S / 2 and None."""
    T = RAMP_S
    if t_s >= T:
        return t_s - 0.5 * T, None
    u = max(t_s / T, 0.0)
    return T * (u**3 - 0.5 * u**4), (3.0 * u * u - 2.0 * u**3, 6.0 * u * (1.0 - u) / T)


class TrackingSource:
    """Setpoints that follow `reference(t_s)` in one of the modes:

    - "position": SET_POSITION_TARGET_LOCAL_NED with position, velocity, acceleration, yaw and
      yaw-rate feed-forward (PX4 closes the loop);
    - "attitude": quaternion + normalised thrust + yaw-rate feed-forward (type_mask 3) from the
      companion's tracking controller and the drag-aware flatness map;
    - "rates": body rates + thrust (type_mask 128) from the geometric attitude loop with the
      flatness rates as feed-forward;
    - "rover": horizontal velocity + yaw rate from rover flatness with track correction.

    The controller's tilt clamp and body-rate command limits are held within `limits` (the
    vehicle's: PX4's MPC_TILTMAX_AIR and MC_*RATE_MAX, default PX4's defaults), and every
    attitude/rates setpoint sent is measured against them in `quality`
    (:class:`companion.flight.report.SetpointQuality`).

    Until telemetry has both position and attitude, and in position mode, it sends the
    reference as a position setpoint (a rover: zero velocity). In attitude and rates mode it
    also does so while priming (`t_s <= 0` before the first call with `t_s > 0`): the vehicle
    is not flying these setpoints yet (or, right after the OFFBOARD switch, PX4 holds the
    start point with them), so the controller does not run and its integrator and hover-thrust
    estimator learn nothing from thrust commands the vehicle never applied. The controller is
    reset on the first call with `t_s > 0`; in the HANDOVER_S that follows, while PX4 may still
    fly its own position control, it holds the vehicle where it is and learns nothing, and the
    reference time (`reference_time_s`) is flight time minus that wait.
    """

    def __init__(
        self,
        reference: ReferenceFn,
        mode: SetpointMode,
        params: MultirotorParams | None = None,
        *,
        tracking: TrackingConfig | None = None,
        max_tilt_rad: float = math.radians(45.0),
        touchdown: Touchdown | None = None,
        limits: SetpointLimits | None = None,
        time_scaling: bool = True,
        handover_s: float = HANDOVER_S,
    ) -> None:
        if mode not in ("position", "attitude", "rates", "rover"):
            raise ValueError(f"unknown setpoint mode {mode!r}")
        if mode in ("attitude", "rates") and params is None and tracking is None:
            raise ValueError(f"{mode} mode needs the vehicle parameters (mass, inertia, drag)")
        self.reference = reference
        self.mode = mode
        self.controller: TrackingController | None = None
        self.limits = limits or SetpointLimits()
        self.quality = SetpointQuality(self.limits)
        if mode in ("attitude", "rates"):
            cfg = tracking or TrackingConfig(params=params, max_tilt_rad=max_tilt_rad)  # type: ignore[arg-type]
            self.controller = TrackingController(vehicle_limited(cfg, self.limits))
        # the reference bent within the tilt limit ahead of time (see `ShapedReference`)
        self.shaper: ShapedReference | None = None
        c = self.controller.config if self.controller is not None else None
        if c is not None and c.shape_reference:
            shaping = (ShapingConfig() if c.shape_margin_rad is None
                       else ShapingConfig(margin_rad=c.shape_margin_rad))
            self.shaper = ShapedReference(reference, shaping, max_tilt_rad=c.max_tilt_rad,
                                          g=c.params.g)
        self.rover = RoverController() if mode == "rover" else None
        # a rover's reference waits for it (ProgressGovernor), a multirotor's slows down for it
        # (TimeScaler, with `time_scaling`); position mode flies the clock (PX4 flies it)
        self.governor: ProgressGovernor | None = (
            ProgressGovernor() if mode == "rover"
            else TimeScaler() if mode in ("attitude", "rates") and time_scaling else None)
        self._lag_m = 0.0  # a multirotor: distance to its reference at the last call [m]
        self._dist_sum = [0.0, 0.0]  # sum of the disturbance estimates in the air [m/s^2]
        self._dist_n = 0
        self._path_t = 0.0  # a rover: reference time of the path point beside it [s]
        # position mode: the drag PX4 does not model goes into the acceleration feed-forward
        known = params if params is not None else tracking.params if tracking is not None else None
        self.drag_per_kg = known.drag / known.mass if known is not None else 0.0
        self._ref_key: float | None = None
        self._ref: Reference | None = None
        self.calls = 0
        self.clock = SampleClock()
        # the controller's clock: the local clock less this [s], run at the autopilot's rate
        # (see `_vehicle_time`); its last local time [s]
        self._ctrl_lag = 0.0
        self._ctrl_last: float | None = None
        # local time [s] the tracking law's current run of hover fallbacks began (None: it
        # flies its regular command), and of the last call
        self._blind_since: float | None = None
        self._blind_now = 0.0
        self._engaged = False  # the controller runs (a call with t_s > 0 was seen)
        self._ground_z: float | None = None  # the height [m, NED z] it last stood at
        self._lifted = False  # off the ground (see `_lift_off`)
        self.handover_s = handover_s
        self._handover_end: float | None = None  # local time the handover ends [s]
        self._hold_s = 0.0  # flight time [s] the reference stood still for the handover
        self._t_ref: float | None = None  # reference time [s] of the last call, when shifted
        # after the handover: (horizontal offset [m] of the vehicle from the reference's start,
        # that start [m], the reference time [s] then), see `_blended`
        self._blend: tuple[np.ndarray, np.ndarray, float] | None = None
        self._blend_pending = False
        self._flown: Reference | None = None  # the reference the last call flew
        # the last estimate and the (immutable) telemetry values it was built from
        self._est_key: tuple[object, object, bool, float] | None = None
        self._est: StateEstimate | None = None
        self.touchdown = touchdown
        self.contact_s: float | None = None  # local time ground contact was detected [s]
        self._still_since: float | None = None
        self._contact_thrust = 0.0
        self._last_thrust = 0.0

    def estimates(self) -> FlightEstimates | None:
        """What the tracking law has estimated so far (None: position and rover modes): the
        disturbance and the wind as their means over the setpoints flown in the air."""
        ctl = self.controller
        if ctl is None:
            return None
        n = self._dist_n
        dx, dy = (self._dist_sum[0] / n, self._dist_sum[1] / n) if n else ctl.disturbance.acc_ne
        D = ctl.drag
        m = ctl.config.params.mass
        wind = wind_from = None
        if D > 0.0:
            wn, we = dx * m / D, dy * m / D
            wind = math.hypot(wn, we)
            # the wind blows from the opposite of where the air moves
            wind_from = math.degrees(math.atan2(-we, -wn)) % 360.0 if wind > 0.0 else 0.0
        gov = self.governor
        slowed = gov.delay_s if isinstance(gov, TimeScaler) else 0.0
        return FlightEstimates(
            wind_m_s=wind, wind_from_deg=wind_from, disturbance_m_s2=math.hypot(dx, dy),
            mass_ratio=ctl.hover_thrust / ctl.config.params.hover_thrust, slowed_s=slowed,
            min_rate=gov.min_rate if isinstance(gov, TimeScaler) else 1.0)

    @property
    def last_reference(self) -> Reference | None:
        """The reference the most recent call flew (for status displays and a hold)."""
        return self._flown if self._flown is not None else self._ref

    @property
    def touching_down(self) -> bool:
        """The last call was past the plan, in the :class:`Touchdown` descent."""
        td = self.touchdown
        return td is not None and self._ref_key is not None and self._ref_key > td.from_s

    def reset(self) -> None:
        """Forget controller state (call when OFFBOARD is (re-)entered)."""
        if self.controller is not None:
            self.controller.reset()
        if self.governor is not None:
            self.governor.reset()
        if self.shaper is not None:
            self.shaper.reset()
        self._path_t = 0.0
        self.contact_s = self._still_since = None

    @property
    def arrived(self) -> bool:
        """A rover has reached (or passed) the stop its reference is at."""
        return self.rover is not None and self.rover.arrived

    @property
    def stalled_s(self) -> float:
        """How long [s] a governed reference has stood still waiting for the vehicle (0 for a
        reference on flight time)."""
        return 0.0 if self.governor is None else self.governor.stalled_s

    @property
    def blind_s(self) -> float:
        """How long [s] the law has flown its hover fallback without a break (see `_blind`)."""
        return 0.0 if self._blind_since is None else max(0.0, self._blind_now - self._blind_since)

    def _blind(self, now: float, fallback: bool, telemetry: TelemetrySnapshot) -> None:
        """Count the run of fallbacks (`fallback`: this call's command is one) while position
        samples keep arriving (received within the law's stale age): a silent link is a link
        loss, left to the link monitor and PX4's offboard failsafe."""
        pos, ctl = telemetry.position, self.controller
        if not fallback or ctl is None or pos is None or not now - pos.t_s <= (
                ctl.config.stale_after_s):
            self._blind_since = None
        elif self._blind_since is None and math.isfinite(now):
            self._blind_since = now
        if math.isfinite(now):
            self._blind_now = now

    @property
    def reference_time_s(self) -> float | None:
        """The reference's own time [s] of the last setpoint when this source governs it (a
        rover's waits for it, a multirotor's slows down for it); None: the flight time it was
        given (also before the first setpoint of the flight)."""
        gov = self.governor
        if gov is not None and gov.started:
            return gov.t_ref
        return self._t_ref

    @property
    def start_delay_s(self) -> float:
        """How far [s] the reference's clock runs behind the flight time once the handover is
        over (its HANDOVER_S hold plus half the RAMP_S ramp; 0 without one): the plan's clock
        of this flight is the flight time less this, before any slowing for the vehicle."""
        return self._hold_s + RAMP_S / 2.0 if self._hold_s > 0.0 else 0.0

    def ref(self, t_s: float) -> Reference:
        """The reference at `t_s` (cached for repeated calls at the same time)."""
        if self._ref is None or self._ref_key != t_s:
            self._ref = self._reference_at(t_s)
            self._ref_key = t_s
        return self._ref

    def _reference_at(self, t_s: float) -> Reference:
        """The reference at `t_s`: the plan's, or past `touchdown.from_s` the touchdown's."""
        td = self.touchdown
        if td is not None and t_s > td.from_s:
            end = self._plan(td.from_s)
            dz, vz, az = td.offset(t_s - td.from_s)
            return Reference(end.pos_ned + np.array([0.0, 0.0, dz]),
                             np.array([0.0, 0.0, vz]), np.array([0.0, 0.0, az]), yaw=end.yaw)
        return self._plan(max(t_s, 0.0))

    def _plan(self, t_s: float) -> Reference:
        """The plan's reference at `t_s`, bent within the tilt limit (see `shaper`)."""
        return self.reference(t_s) if self.shaper is None else self.shaper(t_s)

    def _disturbance(self) -> tuple[float, float]:
        """The horizontal disturbance [m/s^2, NE] the controller estimates (0 when it does not)."""
        ctl = self.controller
        assert ctl is not None
        return ctl.disturbance.acc_ne if ctl.config.estimate_disturbance else (0.0, 0.0)

    def _shape(self, t_s: float) -> None:
        """Bring the shaper to reference time `t_s` with the controller's estimates (the
        drag per mass and the disturbance the tilt must also carry, the limit in force)."""
        ctl = self.controller
        sh = self.shaper
        assert ctl is not None and sh is not None
        p = ctl.config.params
        sh.drag_per_kg = ctl.drag / p.mass
        sh.disturbance_ne = self._disturbance()
        gov = self.governor
        sh.rate = gov.rate if isinstance(gov, TimeScaler) else 1.0
        # wind the tilt limit cannot carry at the plan's pace is the time scaler's: a bend
        # there fought its slowing (campaign, rates mode in 5 m/s of wind: 0.17 -> 0.26 m)
        sh.enabled = sh.rate >= 1.0 and math.hypot(*sh.disturbance_ne) <= FEASIBLE_MIN_DIST
        sh.advance(t_s)

    def _lift_off(self, est: StateEstimate) -> None:
        """Latch `_lifted` once the vehicle is off the ground: PX4 says it is in the air and it
        is LIFTOFF_M above the height it last stood at (at once if it never stood: a join in the
        air). PX4's land detector says "in air" as soon as the motors spin up in OFFBOARD, 0.4 s
        before the handover ends (real PX4 SIH): the setpoint figures start at liftoff, not at
        the spin-up, where the handover's end stepped the thrust of a vehicle still standing
        (by 0.04-0.12, its height reference back at the plan's start, EKF2's height having risen
        0.1-0.25 m since it was planned)."""
        z = float(est.pos_ned[2])
        if not est.airborne:
            self._ground_z = z
        elif self._ground_z is None or self._ground_z - z > LIFTOFF_M:
            self._lifted = True

    def _plan_lean(self, ref: Reference) -> tuple[float, float]:
        """`lean_of_reference` with the controller's drag: what `quality` subtracts from the
        commanded lean, so that its oscillation measure sees the feedback, not the plan."""
        ctl = self.controller
        assert ctl is not None
        p = ctl.config.params
        return lean_of_reference(ref, ctl.drag / p.mass, p.g)

    def _touched_down(self, t_s: float, now: float, est: StateEstimate,
                      ref: Reference) -> bool:
        """Ground contact (see :class:`Touchdown`), latched once seen."""
        td = self.touchdown
        if self.contact_s is not None:
            return True
        if td is None or t_s < td.from_s + td.ramp_in_s:
            return False
        gap = float(ref.pos_ned[2]) - float(est.pos_ned[2])  # > 0: reference below (NED)
        if gap > td.gap_m and abs(float(est.vel_ned[2])) < td.still_m_s:
            if self._still_since is None:
                self._still_since = now
            if now - self._still_since >= td.contact_s:
                self.contact_s = now
                self._contact_thrust = self._last_thrust
                return True
        else:
            self._still_since = None
        return False

    def _landing_tilt(self, td: Touchdown) -> float:
        """The touchdown's tilt limit [rad]: PX4's MPC_TILTMAX_LND, raised to what holding
        against the estimated disturbance needs plus LANDING_TILT_MARGIN_RAD (in 5.7 m/s of wind
        the landing limit cut the thrust from 0.76 to 0.50 in one step, 0.5 m up; held at 12 deg
        the vehicle would drift with the wind instead of landing where planned)."""
        ctl = self.controller
        assert ctl is not None
        dx, dy = self._disturbance()
        hold = math.atan2(math.hypot(dx, dy), ctl.config.params.g) + LANDING_TILT_MARGIN_RAD
        return min(max(td.max_tilt_rad, hold), ctl.config.max_tilt_rad)

    def _feasible_rate(self, t_ref: float) -> float:
        """The largest reference rate in [0, 1] the multirotor can fly from `t_ref` on, given
        the disturbance and the drag its controller estimates (see FEASIBLE_EVERY); 1 while the
        disturbance, plus the drag above the configured one at the reference's speed, is small.
        Re-evaluated every FEASIBLE_EVERY calls."""
        ctl = self.controller
        td = self.touchdown
        if (ctl is None or not ctl.config.estimate_disturbance
                or (td is not None and t_ref >= td.from_s)):  # the touchdown: not the plan
            return 1.0
        dx, dy = ctl.disturbance.acc_ne
        d = math.hypot(dx, dy)
        p = ctl.config.params
        # a drag per mass estimated above the configured one (a lighter vehicle than told) is
        # what the disturbance read before the drag estimator took it: it counts toward the gate
        excess = max(ctl.drag - p.drag, 0.0) / p.mass
        if d <= FEASIBLE_MIN_DIST and excess == 0.0:
            self._cap, self._cap_age = 1.0, 0
            return 1.0
        self._cap_age -= 1
        if self._cap_age > 0:
            return self._cap
        self._cap_age = FEASIBLE_EVERY
        if excess > 0.0 and d + excess * float(
                np.linalg.norm(self._reference_at(t_ref).vel_ned[:2])) <= FEASIBLE_MIN_DIST:
            self._cap = 1.0
            return 1.0
        refs = [self._reference_at(t_ref + a) for a in FEASIBLE_AHEAD_S]
        sh = self.shaper
        # while the bend is in charge: the bent reference against the bend's own limit less
        # half its margin (two limits apart slowed flights the bend flew: control.md, 7)
        tilt, share = ((ctl.config.max_tilt_rad - 0.5 * sh.config.margin_rad, 1.0)
                       if sh is not None and sh.in_charge
                       else (ctl.config.max_tilt_rad, FEASIBLE_SHARE))
        cap = feasible_rate(refs, (dx, dy), ctl.drag / p.mass, tilt, p.g, share)
        self._cap = cap
        return cap

    _cap = 1.0  # the last `_feasible_rate`
    _cap_age = 0  # calls until it is re-evaluated

    def _path_point(self, t_s: float, est: StateEstimate) -> Reference:
        """The reference where its path passes closest to the vehicle, searched forward from
        the last one up to ``t_s`` (a rover steers by the path beside it: the reference time's
        point may lie a few metres ahead, round a corner the rover has not reached)."""
        lo = max(self._path_t - PATH_SEARCH_BACK_S, 0.0)
        hi = max(t_s, lo)
        here = est.pos_ned[:2]

        def dist(t: float) -> float:
            return float(np.linalg.norm(self._reference_at(t).pos_ned[:2] - here))

        ts = np.linspace(lo, hi, PATH_SEARCH_SAMPLES)
        ds = [dist(float(t)) for t in ts]
        i = int(np.argmin(ds))
        a, b = float(ts[max(i - 1, 0)]), float(ts[min(i + 1, len(ts) - 1)])
        for _ in range(PATH_SEARCH_REFINE):  # golden section on the bracket
            c = b - 0.618 * (b - a)
            d = a + 0.618 * (b - a)
            if dist(c) <= dist(d):
                b = d
            else:
                a = c
        self._path_t = max(self._path_t, 0.5 * (a + b)) if hi >= self._path_t else hi
        return self._reference_at(self._path_t)

    def _estimate(self, telemetry: TelemetrySnapshot) -> StateEstimate | None:
        """`estimate_from_telemetry` with this source's clock, reused while the position and
        attitude samples are the same objects (telemetry arrives slower than setpoints go out;
        a repeated sample adds nothing to the clock's window, so the result is identical)."""
        ext = telemetry.extended
        key = (telemetry.position, telemetry.attitude, ext.in_air if ext is not None else True,
               telemetry.link_rtt_s)
        old = self._est_key
        if (
            self._est is not None
            and old is not None
            and key[0] is old[0]
            and key[1] is old[1]
            and key[2] == old[2]
            and (key[3] == old[3] or (key[3] != key[3] and old[3] != old[3]))  # (NaN == NaN)
        ):
            return self._est
        est = estimate_from_telemetry(telemetry, self.clock)
        self._est_key, self._est = key, est
        return est

    def _vehicle_time(self, now: float, est: StateEstimate,
                      rtt_s: float) -> tuple[float, StateEstimate, float]:
        """(`now`, `est`, the link's round trip `rtt_s`) with their times on a clock that runs
        at the autopilot's rate (the sample clock's drift b: 1 / (1 + b) autopilot seconds per
        local second). The controller's dynamics (its extrapolation, estimators, integrator
        and thrust history) are the vehicle's: PX4 SITL at 0.7x real time otherwise saw its
        accelerations estimated 0.7x as large and the latency predicted 1.4x as long. With
        no drift, the times as given (on a real autopilot the two clocks agree)."""
        b = self.clock.drift
        last, self._ctrl_last = self._ctrl_last, now
        if last is not None and b != 0.0 and now > last:
            self._ctrl_lag += (now - last) * (b / (1.0 + b))
        if b == 0.0 and self._ctrl_lag == 0.0:
            return now, est, rtt_s
        now_c = now - self._ctrl_lag
        k = 1.0 / (1.0 + b)
        return (now_c, replace(est, t_s=now_c - (now - est.t_s) * k), rtt_s * k)

    def _handover(self, t_s: float, now: float) -> bool:
        """Engage the controller on the first call with flight time `t_s` > 0 and run the
        handover after it: True while it lasts (the vehicle is held where it is, `_hold_s`
        counts the flight time the reference stood); the controller learns nothing meanwhile
        (integrator, disturbance, hover thrust, drag: `TrackingController.learning`)."""
        ctl = self.controller
        assert ctl is not None
        if not self._engaged:
            self._engaged = True
            ctl.reset()
            ok = math.isfinite(now) and self.handover_s > 0.0
            self._handover_end = now + self.handover_s if ok else None
            ctl.learning = not ok
        end = self._handover_end
        if end is None:
            return False
        if now < end:
            self._hold_s = t_s
            return True
        self._handover_end = None
        self._blend_pending = True
        ctl.learning = True
        return False

    def _blended(self, ref: Reference, t_s: float, est: StateEstimate | None,
                 ahead: bool = False) -> Reference:
        """`ref` (at reference time `t_s`) moved by the vehicle's horizontal offset from the
        reference's start at the end of the handover, the offset fading out with a quintic
        smoothstep of the distance the reference has moved from its start (over BLEND_M) and
        of the time since (over BLEND_T_S), combined as u_d + u_t - u_d u_t (its velocity and
        acceleration added): the flight begins where the vehicle stopped rather than pulling
        it back to where it stood when the plan was made (EKF2's estimate moves by tenths of a
        metre in that time on SIH), and fades mostly as the plan moves, so the reference does
        not run backward for it (a fade over 2 s did: 0.5 m/s back toward the last waypoint,
        real PX4); a plan that hovers still loses it. The height is not blended: the vehicle
        may have sunk while PX4 was not flying the thrust (a wrong hover thrust)."""
        if self._blend is None:
            self._blend_pending = False
            if est is None:
                return ref
            offset = est.pos_ned - ref.pos_ned
            offset[2] = 0.0
            if not np.all(np.isfinite(offset)) or float(np.linalg.norm(offset)) < 1e-3:
                return ref
            self._blend = (offset, ref.pos_ned.copy(), t_s)
        offset, p0, t0 = self._blend
        D = BLEND_M
        dp = ref.pos_ned - p0
        r = float(np.linalg.norm(dp))
        u_t = (t_s - t0) / BLEND_T_S
        if r >= D or u_t >= 1.0:  # faded out: done (a path back past its start must not get
            if not ahead:  # it again; the lead feed-forward's reference gets there first)
                self._blend = None
            return ref
        v, a = ref.vel_ned, ref.acc_ned
        # u = a smooth "either": u_d + u_t - u_d u_t of distance and time (>= both, 1 at either)
        u_d = r / D
        if r > 1e-9:
            dr = float(dp @ v) / r  # d|dp|/dt
            du_d, ddu_d = dr / D, (float(dp @ a) + float(v @ v) - dr * dr) / (r * D)
        else:
            du_d = ddu_d = 0.0
        u_t, du_t = max(u_t, 0.0), 1.0 / BLEND_T_S
        u = u_d + u_t - u_d * u_t
        du = du_d * (1.0 - u_t) + du_t * (1.0 - u_d)
        ddu = ddu_d * (1.0 - u_t) - 2.0 * du_d * du_t
        w = 1.0 - u**3 * (10.0 - 15.0 * u + 6.0 * u * u)
        w1 = -30.0 * u * u * (1.0 - u) ** 2  # dw/du
        w2 = -60.0 * u * (1.0 - u) * (1.0 - 2.0 * u)  # d2w/du2
        return replace(ref, pos_ned=ref.pos_ned + w * offset,
                       vel_ned=v + (w1 * du) * offset,
                       acc_ned=a + (w2 * du * du + w1 * ddu) * offset)

    def position_setpoint(self, t_s: float) -> PositionSetpoint:
        """The reference as a PX4 position setpoint (also used for priming)."""
        pc = position_command(self.ref(t_s), feedforward=t_s > 0.0,
                              drag_per_kg=self.drag_per_kg if self.mode == "position" else 0.0)
        return PositionSetpoint(
            pos_ned=_tuple3(pc.pos_ned),
            vel_ned=_tuple3(pc.vel_ned),
            acc_ned=_tuple3(pc.acc_ned),
            yaw=_opt(pc.yaw),
            yaw_rate=_opt(pc.yaw_rate),
        )

    def __call__(self, t_s: float, telemetry: TelemetrySnapshot) -> SetpointCommand:
        self.calls += 1
        now = telemetry.now_s
        gov = self.governor
        standing = False
        ramp: tuple[float, float] | None = None
        t_flown = t_s  # flight time since the handover [s]
        if self.controller is not None and t_s > 0.0:
            standing = self._handover(t_s, now)
            t_s -= self._hold_s
            t_flown = t_s
            if self._hold_s > 0.0 and not standing:
                t_s, ramp = _ramp(t_s)
            self._t_ref = t_s if self._hold_s > 0.0 else None
        if gov is not None and t_s > 0.0:
            if self.rover is not None:
                t_s = gov.update(t_s, self.rover.last_lag_m)
            else:
                t_s = gov.update(t_s, self._lag_m, self._feasible_rate(gov.t_ref))
        if self.shaper is not None and self._engaged and t_s > 0.0 and not standing and (
                self.touchdown is None or t_s < self.touchdown.from_s):
            self._shape(t_s)
        ref = self.ref(t_s)
        est = self._estimate(telemetry)
        if est is not None and not self._lifted:
            self._lift_off(est)
        if standing:  # the vehicle, stopped where it is (see HANDOVER_S)
            ref = Reference(ref.pos_ned if est is None else est.pos_ned, yaw=ref.yaw)
        else:
            if gov is not None and gov.rate != 1.0 and isinstance(gov, TimeScaler):
                ref = gov.scaled(ref)
            if ramp is not None:
                ref = warped(ref, *ramp)
            if self._blend is not None or self._blend_pending:
                ref = self._blended(ref, t_s, est)
        self._flown = ref
        if self.controller is not None and not self._engaged:
            # priming: PX4 is not applying our thrust commands yet
            return self.position_setpoint(t_s)
        if self.mode == "position" or est is None or not math.isfinite(now):
            if self.mode == "rover":
                return PositionSetpoint(vel_ned=(0.0, 0.0, 0.0), yaw_rate=0.0)
            self.quality.gap()
            if self.mode != "position":  # no state to fly on
                self._blind(now, True, telemetry)
            return self.position_setpoint(t_s)
        if self.mode == "rover":
            assert self.rover is not None
            beside = self._path_point(t_s, est)
            cmd = self.rover.update(now, est, ref, beside,
                                    self._reference_at(self._path_t + SPEED_LEAD_S))
            return PositionSetpoint(
                vel_ned=(float(cmd.vel_ned[0]), float(cmd.vel_ned[1]), 0.0),
                yaw_rate=_opt(float(cmd.yaw_rate)),
            )
        assert self.controller is not None
        rp, ep = ref.pos_ned.tolist(), est.pos_ned.tolist()
        self._lag_m = math.dist(rp, ep)
        if est.airborne:
            dx, dy = self.controller.disturbance.acc_ne
            self._dist_sum[0] += dx
            self._dist_sum[1] += dy
            self._dist_n += 1
        quality = self.quality
        td = self.touchdown
        if td is not None:
            self.controller.limit_tilt(self._landing_tilt(td) if t_s > td.from_s else None)
        touched = td is not None and self._touched_down(t_s, now, est, ref)
        # in the air for the setpoint figures: PX4 says so, and the vehicle has not stopped
        # under a touchdown reference that goes on down (its first contact with the ground:
        # the velocity feedback then lowers the thrust at once, as it should)
        airborne = self._lifted and not touched and not (
            td is not None and t_s > td.from_s + td.ramp_in_s
            and abs(float(est.vel_ned[2])) < td.still_m_s)
        if touched:
            assert self.contact_s is not None and self.touchdown is not None
            fade = max(0.0, 1.0 - (now - self.contact_s) / self.touchdown.ramp_s)
            thrust = self._contact_thrust * fade
            self._blind(now, False, telemetry)
            quality.add(now, thrust, 0.0, (0.0, 0.0, 0.0), airborne)
            if self.mode == "attitude":
                return AttitudeSetpoint(_level_q(est.q_wxyz), thrust, 0.0)
            return RatesSetpoint((0.0, 0.0, 0.0), thrust)
        if self.mode == "attitude":
            # the lead feed-forward sampled from the reference itself (never a Taylor step:
            # the plan's snap spikes where a short speed ramp starts)
            lead = self.controller.config.attitude_lead_s
            if standing:
                ahead = ref
            elif ramp is not None:  # the ramp's clock, `lead` of flight time ahead
                t_ahead, r_ahead = _ramp(t_flown + lead)
                ahead = self._reference_at(t_ahead)
                if r_ahead is not None:
                    ahead = warped(ahead, *r_ahead)
                if self._blend is not None:
                    ahead = self._blended(ahead, t_ahead, est, ahead=True)
            elif self._blend is not None:
                ahead = self._blended(self._reference_at(t_s + lead), t_s + lead, est,
                                      ahead=True)
            elif gov is not None and gov.rate != 1.0 and isinstance(gov, TimeScaler):
                ahead = gov.scaled(self._reference_at(t_s + lead * gov.rate))
            else:
                ahead = self._reference_at(t_s + lead)
            now_c, est_c, _ = self._vehicle_time(now, est, telemetry.link_rtt_s)
            out = self.controller.attitude_values(now_c, est_c, ref, ahead)
            if isinstance(out, AttitudeCommand):  # a hover fallback
                qw, qx, qy, qz = out.q_wxyz.tolist()
                thrust, rate_ff = out.thrust_norm, out.yaw_rate_ff
            else:  # the regular command as floats (no arrays on the way)
                (qw, qx, qy, qz), thrust, rate_ff, _sat = out
            self._blind(now, isinstance(out, AttitudeCommand), telemetry)
            self._last_thrust = float(thrust)
            q = (float(qw), float(qx), float(qy), float(qz))
            quality.add(now, self._last_thrust, tilt_of_q(q), (0.0, 0.0, float(rate_ff)),
                        airborne, lean_residual(tilt_ne_of_q(q), self._plan_lean(ahead)))
            return AttitudeSetpoint(q, float(thrust), _opt(float(rate_ff)))
        now_c, est_c, self.controller.link_rtt_s = self._vehicle_time(now, est,
                                                                     telemetry.link_rtt_s)
        r = self.controller.rates(now_c, est_c, ref)
        self._blind(now, r.fallback, telemetry)
        w = r.omega_frd
        self._last_thrust = float(r.thrust_norm)
        rates = (float(w[0]), float(w[1]), float(w[2]))
        q_des = _level_q(est.q_wxyz) if r.fallback else self.controller.last_q_des
        quality.add(now, self._last_thrust, tilt_of_q(q_des), rates, airborne,
                    lean_residual(tilt_ne_of_q(q_des), self._plan_lean(ref)))
        return RatesSetpoint(rates, float(r.thrust_norm))
