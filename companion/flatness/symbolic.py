"""CasADi functions of the flatness maps: the single source of truth fed to the C generator.

casadi is imported when :func:`symbolic` first builds them, not with this module: the numeric
path that flies (``companion.flatness.numeric``) never loads it.

:func:`symbolic` returns two ``casadi.Function`` objects built from CasADi ``SX`` expressions of
:mod:`companion.flatness._formulas`. Vehicle parameters are inputs, so generated C takes them at
run time. Matrices (``inertia``, ``C_eb``) are dense 3x3, column-major in CasADi/C buffers.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import companion.flatness._formulas as fm

if TYPE_CHECKING:
    import casadi as ca

__all__ = [
    "MULTIROTOR_INPUTS",
    "MULTIROTOR_OUTPUTS",
    "ROVER_INPUTS",
    "ROVER_OUTPUTS",
    "SymbolicFlatness",
    "symbolic",
]

#: (name, rows, cols) of the multirotor Function inputs, in order.
MULTIROTOR_INPUTS: tuple[tuple[str, int, int], ...] = (
    ("vel_ned", 3, 1),  # m/s
    ("acc_ned", 3, 1),  # m/s^2
    ("jerk_ned", 3, 1),  # m/s^3
    ("snap_ned", 3, 1),  # m/s^4
    ("yaw", 1, 1),  # rad, 3-2-1 yaw
    ("yaw_rate", 1, 1),  # rad/s, d(yaw)/dt
    ("yaw_acc", 1, 1),  # rad/s^2, d2(yaw)/dt2
    ("mass", 1, 1),  # kg
    ("inertia", 3, 3),  # kg m^2, body FRD
    ("g", 1, 1),  # m/s^2
    ("hover_thrust", 1, 1),  # normalised 0..1
    ("drag", 1, 1),  # N/(m/s)
)
#: (name, rows, cols) of the multirotor Function outputs, in order.
MULTIROTOR_OUTPUTS: tuple[tuple[str, int, int], ...] = (
    ("thrust", 1, 1),  # N
    ("thrust_dot", 1, 1),  # N/s
    ("thrust_ddot", 1, 1),  # N/s^2
    ("thrust_norm", 1, 1),  # 0..1
    ("q_wxyz", 4, 1),  # body FRD -> world NED, w >= 0
    ("C_eb", 3, 3),  # body FRD -> world NED
    ("omega_frd", 3, 1),  # rad/s
    ("omega_dot_frd", 3, 1),  # rad/s^2
    ("moment_frd", 3, 1),  # N m
    ("singular", 1, 1),  # 0 or 1
    ("flags", 1, 1),  # bit set: 1 low thrust, 2 heading singular, 4 inverted
)
ROVER_INPUTS: tuple[tuple[str, int, int], ...] = (
    ("vel_xy", 2, 1),  # m/s, NED north/east
    ("acc_xy", 2, 1),  # m/s^2
    ("jerk_xy", 2, 1),  # m/s^3
    ("wheel_base", 1, 1),  # m, rear to front axle (Ackermann outputs); 0 (default): they are 0
)
ROVER_OUTPUTS: tuple[tuple[str, int, int], ...] = (
    ("yaw", 1, 1),  # rad
    ("speed", 1, 1),  # m/s
    ("speed_dot", 1, 1),  # m/s^2
    ("yaw_rate", 1, 1),  # rad/s
    ("yaw_acc", 1, 1),  # rad/s^2
    ("singular", 1, 1),  # 0 or 1
    ("curvature", 1, 1),  # 1/m, > 0 turning right (clockwise seen from above)
    ("curvature_rate", 1, 1),  # 1/(m s)
    ("steer_angle", 1, 1),  # rad, atan(wheel_base * curvature), > 0 right
    ("steer_rate", 1, 1),  # rad/s
)


@dataclass(frozen=True)
class SymbolicFlatness:
    """The named CasADi functions: ``multirotor`` ("multirotor_setpoint") and ``rover``
    ("rover_setpoint"); inputs/outputs as in ``MULTIROTOR_INPUTS`` ... ``ROVER_OUTPUTS``."""

    multirotor: ca.Function
    rover: ca.Function

    def as_dict(self) -> dict[str, ca.Function]:
        """``{function name: Function}``, e.g. for ``casadi.CodeGenerator``."""
        return {self.multirotor.name(): self.multirotor, self.rover.name(): self.rover}


def _vec(x: ca.SX, n: int) -> tuple[ca.SX, ...]:
    return tuple(x[i] for i in range(n))


def _build_multirotor() -> ca.Function:
    import casadi as ca

    sym = {name: ca.SX.sym(name, r, c) for name, r, c in MULTIROTOR_INPUTS}
    J = sym["inertia"]
    inertia = tuple(tuple(J[i, k] for k in range(3)) for i in range(3))
    out = fm.multirotor(
        fm.CasadiBackend(),
        _vec(sym["vel_ned"], 3),  # type: ignore[arg-type]
        _vec(sym["acc_ned"], 3),  # type: ignore[arg-type]
        _vec(sym["jerk_ned"], 3),  # type: ignore[arg-type]
        _vec(sym["snap_ned"], 3),  # type: ignore[arg-type]
        sym["yaw"],
        sym["yaw_rate"],
        sym["yaw_acc"],
        sym["mass"],
        inertia,  # type: ignore[arg-type]
        sym["g"],
        sym["hover_thrust"],
        sym["drag"],
    )
    exprs = {
        "thrust": out["thrust"],
        "thrust_dot": out["thrust_dot"],
        "thrust_ddot": out["thrust_ddot"],
        "thrust_norm": out["thrust_norm"],
        "q_wxyz": ca.vertcat(*out["q_wxyz"]),
        "C_eb": ca.vertcat(*[ca.horzcat(*row) for row in out["C_eb"]]),
        "omega_frd": ca.vertcat(*out["omega_frd"]),
        "omega_dot_frd": ca.vertcat(*out["omega_dot_frd"]),
        "moment_frd": ca.vertcat(*out["moment_frd"]),
        "singular": out["singular"],
        "flags": out["flags"],
    }
    names_in = [n for n, _, _ in MULTIROTOR_INPUTS]
    names_out = [n for n, _, _ in MULTIROTOR_OUTPUTS]
    return ca.Function(
        "multirotor_setpoint",
        [sym[n] for n in names_in],
        [ca.SX(exprs[n]) for n in names_out],
        names_in,
        names_out,
    )


def _build_rover() -> ca.Function:
    import casadi as ca

    sym = {name: ca.SX.sym(name, r, c) for name, r, c in ROVER_INPUTS}
    out = fm.rover(
        fm.CasadiBackend(),
        _vec(sym["vel_xy"], 2),  # type: ignore[arg-type]
        _vec(sym["acc_xy"], 2),  # type: ignore[arg-type]
        _vec(sym["jerk_xy"], 2),  # type: ignore[arg-type]
        sym["wheel_base"],
    )
    names_in = [n for n, _, _ in ROVER_INPUTS]
    names_out = [n for n, _, _ in ROVER_OUTPUTS]
    return ca.Function(
        "rover_setpoint",
        [sym[n] for n in names_in],
        [ca.SX(out[n]) for n in names_out],
        names_in,
        names_out,
    )


@functools.cache
def symbolic() -> SymbolicFlatness:
    """The flatness maps as named ``casadi.Function`` objects (built once, cached).

    ``multirotor``: inputs ``vel_ned, acc_ned, jerk_ned, snap_ned`` (3x1), ``yaw, yaw_rate,
    yaw_acc, mass`` (1x1), ``inertia`` (3x3), ``g, hover_thrust, drag`` (1x1); outputs ``thrust,
    thrust_dot, thrust_ddot, thrust_norm`` (1x1), ``q_wxyz`` (4x1), ``C_eb`` (3x3), ``omega_frd,
    omega_dot_frd, moment_frd`` (3x1), ``singular, flags`` (1x1).
    ``rover``: inputs ``vel_xy, acc_xy, jerk_xy`` (2x1), ``wheel_base`` (1x1, m; a named call
    may omit it: CasADi's default 0 gives zero steering); outputs ``yaw, speed, speed_dot,
    yaw_rate, yaw_acc, singular, curvature, curvature_rate, steer_angle, steer_rate`` (1x1).
    """
    return SymbolicFlatness(multirotor=_build_multirotor(), rover=_build_rover())
