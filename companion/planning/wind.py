"""Is a planned multirotor flight possible in a given wind? Checked before anything moves the
vehicle (`fly --wind`, `serve` with the wind it estimated while PX4 hovered).

The wind enters as the horizontal force per mass it puts on the vehicle, d [m/s^2, NED north,
east]: with linear drag D (the companion's drag, N/(m/s)) and mass m, air moving at w gives
d = D w / m (`disturbance_of_wind`). At ground velocity v and acceleration a the thrust has to
supply the horizontal acceleration a_h + (D/m) v_h - d against g - a_z vertically, so

    tilt = atan(|a_h + (D/m) v_h - d| / (g - a_z)).

Three verdicts (`WindCheck`):

* holding still needs atan(|d| / g) of tilt: at or above the tilt limit the vehicle cannot even
  hold its position: not flyable;
* along each stretch of the plan that moves (horizontal speed above MOVING_M_S), the fastest
  ground speed the tilt limit allows in that direction: below MIN_PROGRESS_M_S the vehicle
  cannot make progress against the wind there: not flyable;
* otherwise the plan as timed may still need more than the tilt limit somewhere: flyable, but
  the companion will fly it slower there (`companion.flight.governor.TimeScaler`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion.flatness.reference import Reference

#: A stretch whose planned horizontal speed is above this [m/s] is "moving" (checked for
#: progress); the slowest ground speed [m/s] it must still be able to make in the wind.
MOVING_M_S = 0.5
MIN_PROGRESS_M_S = 1.0
#: Sampling step of the plan [s].
STEP_S = 0.1


@dataclass(frozen=True)
class WindCheck:
    """The verdict of `check_wind`.

    flyable: the vehicle can hold still and make MIN_PROGRESS_M_S along every moving stretch;
    slowed: flyable, but the plan as timed needs more tilt than the limit somewhere (it will be
    flown slower there); hold_tilt_deg: tilt to hold still in the wind [deg]; worst_tilt_deg:
    the largest tilt the plan as timed needs [deg] and worst_t_s where [s]; slowest_m_s: the
    lowest of the fastest ground speeds along the moving stretches [m/s] (inf: none);
    reason: why not flyable, or what will happen ("" when the plan flies as timed).
    """

    flyable: bool
    slowed: bool
    hold_tilt_deg: float
    worst_tilt_deg: float
    worst_t_s: float
    slowest_m_s: float
    reason: str


def disturbance_of_wind(wind_m_s: float, from_deg: float, drag: float,
                        mass: float) -> tuple[float, float]:
    """The force per mass [m/s^2, north, east] of a wind of `wind_m_s` [m/s] blowing from
    compass `from_deg` [deg] on a vehicle of linear drag `drag` [N/(m/s)] and mass `mass` [kg]:
    D w / m, w the air's velocity (toward from_deg + 180)."""
    to = math.radians(from_deg + 180.0)
    k = drag / mass
    return (k * wind_m_s * math.cos(to), k * wind_m_s * math.sin(to))


def max_ground_speed(direction_ne: tuple[float, float], d_ne: tuple[float, float],
                     drag_per_kg: float, max_tilt_rad: float, g: float) -> float:
    """The fastest steady ground speed [m/s] along the unit vector `direction_ne` with the
    disturbance `d_ne` [m/s^2] and linear drag `drag_per_kg` [1/s] at the tilt limit: the
    largest s >= 0 with |k s u - d| <= g tan(tilt) (0 if none; inf without drag)."""
    lim = g * math.tan(max_tilt_rad)
    ux, uy = direction_ne
    dx, dy = d_ne
    ud = ux * dx + uy * dy
    disc = ud * ud - (dx * dx + dy * dy) + lim * lim
    if disc < 0.0:
        return 0.0
    if drag_per_kg <= 0.0:
        return math.inf
    return max((ud + math.sqrt(disc)) / drag_per_kg, 0.0)


def check_wind(reference: Callable[[float], Reference], duration_s: float,
               d_ne: tuple[float, float], drag_per_kg: float, max_tilt_rad: float,
               g: float = 9.80665) -> WindCheck:
    """Check the plan `reference` (over [0, `duration_s`] s) against the disturbance `d_ne`
    [m/s^2, north, east] of the wind (`disturbance_of_wind`), for a vehicle of linear drag
    `drag_per_kg` (D/m) [1/s] with the tilt limit `max_tilt_rad` (see the module docstring)."""
    dn = math.hypot(*d_ne)
    hold = math.degrees(math.atan2(dn, g))
    lim_deg = math.degrees(max_tilt_rad)
    if hold >= lim_deg:
        return WindCheck(False, False, hold, math.inf, 0.0, 0.0,
                         f"holding still in this wind needs {hold:.0f} deg of tilt, the limit "
                         f"is {lim_deg:.0f} deg")
    worst, worst_t, slowest, slowest_dir = 0.0, 0.0, math.inf, (1.0, 0.0)
    for t in np.arange(0.0, max(duration_s, 0.0) + 1e-9, STEP_S):
        r = reference(float(t))
        vx, vy = float(r.vel_ned[0]), float(r.vel_ned[1])
        ax, ay, az = (float(c) for c in r.acc_ned)
        hx = ax + drag_per_kg * vx - d_ne[0]
        hy = ay + drag_per_kg * vy - d_ne[1]
        tilt = math.degrees(math.atan2(math.hypot(hx, hy), max(g - az, 1e-6)))
        if tilt > worst:
            worst, worst_t = tilt, float(t)
        speed = math.hypot(vx, vy)
        if speed > MOVING_M_S:
            u = (vx / speed, vy / speed)
            best = max_ground_speed(u, d_ne, drag_per_kg, max_tilt_rad, g)
            if best < slowest:
                slowest, slowest_dir = best, u
    if slowest < MIN_PROGRESS_M_S:
        heading = math.degrees(math.atan2(slowest_dir[1], slowest_dir[0])) % 360.0
        return WindCheck(False, False, hold, worst, worst_t, slowest,
                         f"flying toward {heading:03.0f} deg the tilt limit ({lim_deg:.0f} deg) "
                         f"allows at most {slowest:.1f} m/s against this wind (at least "
                         f"{MIN_PROGRESS_M_S:g} m/s needed)")
    if worst > lim_deg:
        return WindCheck(True, True, hold, worst, worst_t, slowest,
                         f"the plan as timed needs {worst:.0f} deg of tilt in this wind (limit "
                         f"{lim_deg:.0f} deg) at t = {worst_t:.1f} s: it will be flown slower "
                         "there")
    return WindCheck(True, False, hold, worst, worst_t, slowest, "")
