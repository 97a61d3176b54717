"""How far an attitude, or a plan, leans the thrust axis from vertical [rad]: the figures the
setpoint quality measure (`companion.flight.report.SetpointQuality`) is fed with. Pure."""

from __future__ import annotations

import math

from companion.control import Reference


def tilt_of_q(q_wxyz: tuple[float, float, float, float]) -> float:
    """Angle between the body z axis of attitude `q_wxyz` (FRD -> NED) and vertical [rad]."""
    _w, x, y, _z = q_wxyz
    return math.acos(max(-1.0, min(1.0, 1.0 - 2.0 * (x * x + y * y))))


def tilt_ne_of_q(q_wxyz: tuple[float, float, float, float]) -> tuple[float, float]:
    """The lean of attitude `q_wxyz`'s thrust axis (-body z, FRD -> NED) toward north and
    east: its tilt from vertical [rad] along the horizontal direction it points to."""
    w, x, y, z = q_wxyz
    return _lean(-2.0 * (x * z + w * y), -2.0 * (y * z - w * x), 1.0 - 2.0 * (x * x + y * y))


def lean_of_reference(ref: Reference, drag_per_kg: float, g: float) -> tuple[float, float]:
    """The lean (as `tilt_ne_of_q`) the plan itself asks for at `ref`: the thrust that gives its
    acceleration against gravity and the linear drag `drag_per_kg` [1/s] at its velocity."""
    a, v = ref.acc_ned, ref.vel_ned
    return _lean(float(a[0]) + drag_per_kg * float(v[0]), float(a[1]) + drag_per_kg * float(v[1]),
                 g - float(a[2]))


def _lean(hx: float, hy: float, up: float) -> tuple[float, float]:
    """The lean [rad, north and east] of an axis with horizontal part (hx, hy) and vertical
    part `up` (any common scale): its angle from vertical along (hx, hy)."""
    s = math.hypot(hx, hy)
    if s < 1e-12:
        return (0.0, 0.0)
    tilt = math.atan2(s, up)
    return (tilt * hx / s, tilt * hy / s)


def lean_residual(a: tuple[float, float], b: tuple[float, float]) -> tuple[float, float]:
    """Lean `a` less lean `b` [rad, north and east]."""
    return (a[0] - b[0], a[1] - b[1])
