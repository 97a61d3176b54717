"""The reference clocks a setpoint source can govern: a rover's reference that waits for it
(`ProgressGovernor`), a multirotor's that slows down for it (`TimeScaler`). Pure: every call
takes the flight time."""

from __future__ import annotations

import math

from companion.control import Reference

#: The governed reference counts as standing still below this rate (`ProgressGovernor`).
STALL_RATE = 0.05


class ProgressGovernor:
    """Reference time that waits for a vehicle falling behind it (a rover that cannot drive the
    planned speed: its own speed limit, a slope, a PX4 speed loop that lags).

    `update(t, lag_m)` maps the flight time `t` [s] to the reference time: it advances at
    ``rate = (stop_m - lag_m) / (stop_m - free_m)`` (clamped to [0, 1]) times the flight time,
    where `lag_m` is how far [m] the vehicle is behind the reference along its path (the
    along-track error of the last setpoint). Up to `free_m` of lag it runs with flight time
    (the controller's along-track feedback closes such lags); from `stop_m` on it stops until
    the vehicle has caught up. It never runs backwards nor faster than flight time, so a plan's
    speeds stay its upper bound and the path stays the plan's. ``stalled_s``: how long it has
    stood still (rate below STALL_RATE): a rover that makes no progress (stuck, blocked).
    """

    def __init__(self, free_m: float = 1.0, stop_m: float = 3.0) -> None:
        if not (0.0 <= free_m < stop_m and math.isfinite(stop_m)):
            raise ValueError(f"need 0 <= free_m < stop_m, got {free_m}, {stop_m}")
        self.free_m = free_m
        self.stop_m = stop_m
        self._t: float | None = None  # last flight time [s]
        self.t_ref = 0.0  # reference time [s]
        self.rate = 1.0  # the last rate [0, 1]
        self.stalled_s = 0.0  # how long [s] the reference has (nearly) stood still

    @property
    def started(self) -> bool:
        """`update` has run since the last reset."""
        return self._t is not None

    def reset(self) -> None:
        """Start again: the next `update`'s flight time is taken as the reference time (a new
        OFFBOARD entry starts its flight time at 0)."""
        self._t = None
        self.t_ref = 0.0
        self.rate = 1.0
        self.stalled_s = 0.0

    def _step(self, t_s: float, lag_m: float, cap: float) -> tuple[float, float] | None:
        """(dt [s] since the last call, the lag's rate capped by `cap`); None when no time
        passed, or on the first call (which takes `t_s` as the reference time)."""
        if self._t is None:
            self._t, self.t_ref = t_s, max(t_s, 0.0)
            return None
        dt = t_s - self._t
        self._t = t_s
        if dt <= 0.0 or not math.isfinite(dt):
            return None
        lag = lag_m if math.isfinite(lag_m) else 0.0
        return dt, min(max((self.stop_m - lag) / (self.stop_m - self.free_m), 0.0), 1.0, cap)

    def update(self, t_s: float, lag_m: float, cap: float = 1.0) -> float:
        """Reference time [s] at flight time `t_s` [s] (calls in time order; the first is taken
        as it is), given the lag [m] seen at the previous call; `cap`: an upper bound of the
        rate."""
        step = self._step(t_s, lag_m, cap)
        if step is None:
            return self.t_ref
        dt, self.rate = step
        self.t_ref += self.rate * dt
        self.stalled_s = self.stalled_s + dt if self.rate < STALL_RATE else 0.0
        return self.t_ref


#: A multirotor's reference time (`TimeScaler`, attitude and rates modes): within QUAD_FREE_M [m]
#: of its reference the vehicle flies the plan's clock (nominal flights: 0.02-0.4 m on the mock;
#: real PX4 SIH on this host, 2026-11-29, up to 1.0-1.4 m on a 6 m/s figure-8 with the code of
#: before this clock as well: 1.0 m slowed one such flight by 0.12 s); from QUAD_STOP_M on the
#: reference waits for it. QUAD_RATE_TAU_S: time constant
#: [s] of the rate's low-pass (the rate also scales the feed-forward; unfiltered, 0.05 m of
#: position noise would put ~0.3 m/s of noise on the velocity feed-forward).
QUAD_FREE_M = 1.5
QUAD_STOP_M = 3.0
QUAD_RATE_TAU_S = 0.5
#: The multirotor's reference is also slowed ahead of need (`TrackingSource._feasible_rate`):
#: every FEASIBLE_EVERY setpoints, at the reference time and FEASIBLE_AHEAD_S later, the largest
#: rate s whose horizontal demand |s^2 a_ref + s (D/m) v_ref - d| (d: the estimated
#: disturbance, e.g. wind) stays within FEASIBLE_SHARE of the tilt limit's g tan(tilt) (the
#: rest is the feedback's; where holding still already needs more, 70 % of what holding leaves
#: of the limit; where holding needs the whole limit the reference waits). Checked only while
#: |d| exceeds FEASIBLE_MIN_DIST: the plan itself was timed within the limits, and on real PX4
#: SIH the model's own error reads as up to ~0.6 m/s^2 on a 6 m/s figure-8 (with 0.5 m/s^2 and
#: 80 % there, the cap slowed that flight by 0.4 s for nothing; the lag rule at 1 m by 0.1 s).
FEASIBLE_EVERY = 10
FEASIBLE_AHEAD_S = (0.0, 0.5, 1.0, 1.5)
FEASIBLE_SHARE = 0.9
FEASIBLE_MIN_DIST = 1.5


class TimeScaler(ProgressGovernor):
    """A multirotor's reference clock: `ProgressGovernor`'s rate from the distance to the
    reference (`update`'s lag), low-passed (QUAD_RATE_TAU_S), and kept as a delay behind flight
    time: the reference time is flight time minus the delay, so until the vehicle first falls
    behind it is the flight time exactly (the same flight as with no scaler). While the rate is
    below 1 the source scales the reference's derivatives by it (`scaled`): the vehicle flies
    the plan's path, slower, instead of chasing a reference it cannot reach (in wind beyond the
    tilt limit, with a heavier vehicle than planned).
    """

    def __init__(self, free_m: float = QUAD_FREE_M, stop_m: float = QUAD_STOP_M,
                 tau_s: float = QUAD_RATE_TAU_S) -> None:
        super().__init__(free_m, stop_m)
        if not (math.isfinite(tau_s) and tau_s > 0.0):
            raise ValueError(f"tau_s must be positive, got {tau_s}")
        self.tau_s = tau_s
        self.delay_s = 0.0  # flight time minus reference time [s]
        self.min_rate = 1.0  # the slowest rate so far

    def reset(self) -> None:
        super().reset()
        self.delay_s = 0.0
        self.min_rate = 1.0

    def update(self, t_s: float, lag_m: float, cap: float = 1.0) -> float:
        """Reference time [s] at flight time `t_s` [s] given the lag [m] of the previous call;
        `cap`: an upper bound of the rate (what the vehicle can fly, `_feasible_rate`)."""
        step = self._step(t_s, lag_m, cap)
        if step is None:
            return self.t_ref
        dt, target = step
        if target < 1.0 or self.rate < 1.0:
            self.rate += (target - self.rate) * min(dt / self.tau_s, 1.0)
            if self.rate > 1.0 - 1e-9 and target == 1.0:
                self.rate = 1.0
            self.delay_s += (1.0 - self.rate) * dt
            self.min_rate = min(self.min_rate, self.rate)
        self.t_ref = t_s - self.delay_s
        self.stalled_s = self.stalled_s + dt if self.rate < STALL_RATE else 0.0
        return self.t_ref

    def scaled(self, ref: Reference) -> Reference:
        """`ref` flown at the current rate s: derivatives of order k times s^k (the rate's own
        change neglected: it moves on QUAD_RATE_TAU_S)."""
        return ref if self.rate == 1.0 else warped(ref, self.rate, 0.0)


def warped(ref: Reference, rate: float, d_rate: float) -> Reference:
    """`ref` flown on a clock running at `rate` (changing at `d_rate` [1/s]): velocity times
    the rate, acceleration times its square plus velocity times its change (the chain rule;
    jerk and snap by the rate's powers alone)."""
    s, s2 = rate, rate * rate
    return Reference(ref.pos_ned, ref.vel_ned * s, ref.acc_ned * s2 + ref.vel_ned * d_rate,
                     ref.jerk_ned * (s2 * s), ref.snap_ned * (s2 * s2), ref.yaw,
                     ref.yaw_rate * s, ref.yaw_acc * s2 + ref.yaw_rate * d_rate)


def feasible_rate(refs: list[Reference], d_ne: tuple[float, float], drag_per_kg: float,
                  max_tilt_rad: float, g: float, share: float = FEASIBLE_SHARE) -> float:
    """The largest reference rate s in [0, 1] at which every reference in `refs` (the plan at
    and after the reference time, see FEASIBLE_AHEAD_S) keeps its horizontal demand
    |s^2 a + s (D/m) v - d| within `share` of g tan(`max_tilt_rad`) (or 70 % of what
    holding still in the disturbance `d_ne` [m/s^2] leaves of it); 0 where holding still alone
    needs the whole limit."""
    dx, dy = d_ne
    k = drag_per_kg
    full = g * math.tan(max_tilt_rad)
    cap = 1.0
    # a demand need not grow with s (an acceleration that cancels the disturbance): lowering
    # the rate for one reference can take an earlier one out of its limit, so pass again
    # until none is (each pass only lowers it)
    for _ in range(8):
        before = cap
        cap = _feasible_pass(refs, dx, dy, k, full, cap, share)
        if cap == before or cap == 0.0:
            return cap
    return cap


def _feasible_pass(refs: list[Reference], dx: float, dy: float, k: float, full: float,
                   cap: float, share: float) -> float:
    """One pass of `feasible_rate` over `refs` from the rate `cap` down."""
    for r in refs:
        ax, ay = float(r.acc_ned[0]), float(r.acc_ned[1])
        bx, by = k * float(r.vel_ned[0]), k * float(r.vel_ned[1])

        def need(s: float, ax: float = ax, ay: float = ay, bx: float = bx,
                 by: float = by) -> float:
            return math.hypot(s * s * ax + s * bx - dx, s * s * ay + s * by - dy)

        hold = need(0.0)
        if hold >= full:  # not even holding still is within the tilt limit
            return 0.0
        lim = max(share * full, hold + 0.7 * (full - hold))
        if need(cap) <= lim:
            continue
        lo, hi = 0.0, cap
        for _ in range(12):  # bisection: need(lo) <= lim < need(hi)
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if need(mid) <= lim else (lo, mid)
        cap = lo
    return cap
