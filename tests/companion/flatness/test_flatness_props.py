"""Hypothesis properties of the flatness maps over random flat states, including extremes.

Each example is a random degree-6 polynomial flat output around t = 0 (position and yaw), so the
derivatives fed to the map are exact and finite differences of the returned attitude/thrust are
an independent oracle.
"""

from __future__ import annotations

import math

import numpy as np
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from companion.flatness import (
    FLAG_HEADING_SINGULAR,
    FLAG_LOW_THRUST,
    MultirotorParams,
    multirotor_setpoint,
    rover_setpoint,
    symbolic,
)

G = 9.80665
SETTINGS = settings(max_examples=80, deadline=None)

comp = st.one_of(
    st.floats(-30.0, 30.0, allow_nan=False),
    st.sampled_from([0.0, G, -G, 1e-12, -1e-9, 1e3]),
)
vec3 = st.tuples(comp, comp, comp)
yaw_st = st.one_of(
    st.floats(-10.0, 10.0, allow_nan=False), st.sampled_from([0.0, np.pi, -np.pi / 2])
)
params_st = st.builds(
    lambda m, jx, jy, jz, d, h: MultirotorParams(m, [jx, jy, jz], drag=d, hover_thrust=h),
    st.floats(0.2, 5.0),
    st.floats(0.005, 0.1),
    st.floats(0.005, 0.1),
    st.floats(0.005, 0.2),
    st.sampled_from([0.0, 0.3, 1.0]),
    st.floats(0.1, 1.0),
)


def _poly(c: list[np.ndarray], t: float, n: int) -> np.ndarray:
    """n-th derivative at t of sum_k c_k t^k / k!."""
    out = np.zeros_like(c[0])
    for k in range(n, len(c)):
        out = out + c[k] * t ** (k - n) / math.factorial(k - n)
    return out


@SETTINGS
@given(vec3, vec3, vec3, vec3, vec3, yaw_st, yaw_st, yaw_st, params_st)
def test_multirotor_state_invariants_and_casadi(
    v: tuple[float, ...],
    a: tuple[float, ...],
    j: tuple[float, ...],
    s: tuple[float, ...],
    c5: tuple[float, ...],
    psi: float,
    dpsi: float,
    ddpsi: float,
    P: MultirotorParams,
) -> None:
    sp = multirotor_setpoint(v, a, j, s, psi, dpsi, ddpsi, P)
    vals = [
        sp.thrust,
        sp.thrust_dot,
        sp.thrust_ddot,
        sp.thrust_norm,
        sp.q_wxyz,
        sp.C_eb,
        sp.omega_frd,
        sp.omega_dot_frd,
        sp.moment_frd,
    ]
    assert all(np.all(np.isfinite(x)) for x in vals)
    q = sp.q_wxyz
    assert abs(np.linalg.norm(q) - 1.0) < 1e-15 and q[0] >= 0.0
    C = sp.C_eb
    np.testing.assert_allclose(C @ C.T, np.eye(3), atol=1e-14)
    np.testing.assert_allclose(Rotation.from_quat(q, scalar_first=True).as_matrix(), C, atol=1e-14)
    assert 0.0 <= sp.thrust_norm <= 1.0
    # Newton, unless there is no thrust direction at all
    t_vec = P.mass * (G * np.array([0, 0, 1.0]) - np.asarray(a)) - P.drag * np.asarray(v)
    t_norm = float(np.linalg.norm(t_vec))
    assert abs(sp.thrust - t_norm) <= 1e-14 * max(t_norm, 1.0)
    if t_norm > P.mass * G * 1e-9:
        np.testing.assert_allclose(sp.thrust * C[:, 2], t_vec, atol=1e-12 * max(t_norm, 1.0))
    # heading: x_b is normal to y_c and points forward, so the 3-2-1 yaw is psi
    if (
        not (sp.flags & (FLAG_HEADING_SINGULAR | FLAG_LOW_THRUST))
        and np.hypot(C[0, 0], C[1, 0]) > 1e-6
    ):
        d = math.atan2(C[1, 0], C[0, 0]) - psi
        assert abs(math.atan2(math.sin(d), math.cos(d))) < 1e-9
    # CasADi function, same inputs: agreement to 1e-12 (relative to the output scale)
    out = symbolic().multirotor(
        vel_ned=v,
        acc_ned=a,
        jerk_ned=j,
        snap_ned=s,
        yaw=psi,
        yaw_rate=dpsi,
        yaw_acc=ddpsi,
        mass=P.mass,
        inertia=P.inertia_matrix,
        g=P.g,
        hover_thrust=P.hover_thrust,
        drag=P.drag,
    )
    for key in (
        "thrust",
        "thrust_dot",
        "thrust_ddot",
        "thrust_norm",
        "q_wxyz",
        "omega_frd",
        "omega_dot_frd",
        "moment_frd",
    ):
        ref = np.asarray(out[key]).ravel()
        mine = np.ravel(getattr(sp, key))
        assert np.max(np.abs(mine - ref)) <= 1e-12 * max(1.0, float(np.max(np.abs(ref)))), key
    np.testing.assert_allclose(np.asarray(out["C_eb"]), C, atol=1e-12)
    assert int(float(out["flags"])) == sp.flags


@SETTINGS
@given(
    st.lists(
        st.tuples(st.floats(-8, 8), st.floats(-8, 8), st.floats(-4, 4)), min_size=7, max_size=7
    ),
    st.lists(st.floats(-2, 2), min_size=5, max_size=5),
    params_st,
)
def test_multirotor_rates_match_finite_differences(
    coefs: list[tuple[float, float, float]], ycoefs: list[float], P: MultirotorParams
) -> None:
    c = [np.asarray(x) for x in coefs]
    yc = [np.asarray(x) for x in ycoefs]
    h = 1e-5

    def at(t: float):  # type: ignore[no-untyped-def]
        return multirotor_setpoint(
            *(_poly(c, t, n) for n in (1, 2, 3, 4)), *(float(_poly(yc, t, n)) for n in (0, 1, 2)), P
        )

    s0, sm, spl = at(0.0), at(-h), at(h)
    assume(not (s0.singular or sm.singular or spl.singular))
    assume(s0.thrust > 0.05 * P.mass * G)
    # |cos(roll)| well away from 0 so that the O(h^2) error term stays small
    y_c = np.array([-math.sin(float(yc[0])), math.cos(float(yc[0])), 0.0])
    assume(abs(y_c @ s0.C_eb[:, 1]) > 0.05)
    omega_fd = Rotation.from_matrix(sm.C_eb.T @ spl.C_eb).as_rotvec() / (2 * h)
    scale = max(1.0, float(np.max(np.abs(s0.omega_frd))))
    assert np.max(np.abs(omega_fd - s0.omega_frd)) < 1e-5 * scale
    domega_fd = (spl.omega_frd - sm.omega_frd) / (2 * h)
    scale = max(1.0, float(np.max(np.abs(s0.omega_dot_frd))))
    assert np.max(np.abs(domega_fd - s0.omega_dot_frd)) < 1e-5 * scale
    assert abs((spl.thrust - sm.thrust) / (2 * h) - s0.thrust_dot) < 1e-5 * max(
        1.0, abs(s0.thrust_dot)
    )
    assert abs((spl.thrust_dot - sm.thrust_dot) / (2 * h) - s0.thrust_ddot) < 1e-5 * max(
        1.0, abs(s0.thrust_ddot)
    )


@SETTINGS
@given(
    st.tuples(st.floats(-20, 20), st.floats(-20, 20)),
    st.tuples(st.floats(-20, 20), st.floats(-20, 20)),
    st.tuples(st.floats(-50, 50), st.floats(-50, 50)),
)
def test_rover_finite_and_consistent(
    v: tuple[float, float], a: tuple[float, float], j: tuple[float, float]
) -> None:
    sp = rover_setpoint(v, a, j)
    vals = [sp.yaw, sp.speed, sp.speed_dot, sp.yaw_rate, sp.yaw_acc]
    assert all(math.isfinite(float(x)) for x in vals if x is not None)
    V = math.hypot(*v)
    assert sp.singular == (V < 1e-3)
    if V >= 1e-3:
        assert abs(sp.speed * math.cos(sp.yaw) - v[0]) < 1e-12 * max(V, 1.0)
        assert abs(sp.speed * math.sin(sp.yaw) - v[1]) < 1e-12 * max(V, 1.0)
        # acceleration decomposed into tangential (V') and normal (V yaw_rate) parts
        ax = sp.speed_dot * math.cos(sp.yaw) - sp.speed * sp.yaw_rate * math.sin(sp.yaw)
        ay = sp.speed_dot * math.sin(sp.yaw) + sp.speed * sp.yaw_rate * math.cos(sp.yaw)
        A = max(1.0, math.hypot(*a))
        assert abs(ax - a[0]) < 1e-9 * A and abs(ay - a[1]) < 1e-9 * A
    out = symbolic().rover(vel_xy=v, acc_xy=a, jerk_xy=j)
    for key in ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc"):
        ref = float(out[key])
        assert abs(float(getattr(sp, key)) - ref) <= 1e-12 * max(1.0, abs(ref)), key
