"""The jerk of a limited thrust vector: what the flatness map gets while the tracking law's
thrust limit (tilt, minimum, maximum) acts."""

from __future__ import annotations

from collections.abc import Callable

Vec3 = tuple[float, float, float]


def saturated_jerk(limit: Callable[[Vec3], Vec3], t_vec: Vec3, t_sat: Vec3, j_cmd: Vec3,
                   v_dot: Vec3, mass: float, drag: float, eps: float = 1e-3) -> Vec3:
    """The jerk [m/s^3, NED] of the saturated acceleration a = -(t_sat + D v) / m (+ g
    vertically) while the thrust vector `t_vec` [N] is limited to `t_sat` = `limit(t_vec)`:
    the limit's derivative along the rate of `t_vec` (-m `j_cmd` - D `v_dot`, `v_dot` the
    velocity's rate [m/s^2] in the drag term), as a one-sided difference over `eps` [s].
    Unlimited, it is `j_cmd`. Riding the tilt cone, the thrust axis still turns with the
    commanded acceleration's azimuth; a zero jerk there held rates mode's body-rate
    feed-forward at zero and released it all at once when the limit let go (real PX4: a step
    of 2-4 rad/s where the figure-8 crosses its centre)."""
    m, D = mass, drag
    t2 = limit((t_vec[0] - eps * (m * j_cmd[0] + D * v_dot[0]),
                t_vec[1] - eps * (m * j_cmd[1] + D * v_dot[1]),
                t_vec[2] - eps * (m * j_cmd[2] + D * v_dot[2])))
    return (-((t2[0] - t_sat[0]) / eps + D * v_dot[0]) / m,
            -((t2[1] - t_sat[1]) / eps + D * v_dot[1]) / m,
            -((t2[2] - t_sat[2]) / eps + D * v_dot[2]) / m)
