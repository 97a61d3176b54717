"""The tracking law's core (companion.control.core): the path the controller flies (pre, the
scalar flatness map, post) equals the whole core on floats bit for bit, the CasADi build of the
same source agrees with it, and the limits and the anti-windup do what they promise."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import companion.flatness._formulas as fm
from companion.control.core import (
    CORE_N_IN,
    CORE_N_OUT,
    CORE_OUTPUTS,
    limit_thrust,
    symbolic_core,
    tracking_core,
    tracking_post,
    tracking_pre,
)
from companion.flatness import MultirotorParams
from companion.flatness.numeric import multirotor_attitude_scalar
from tests.support.core_inputs import OFFSET, random_core_inputs

OUT = {name: sum(n for _, n in CORE_OUTPUTS[:i]) for i, (name, _) in enumerate(CORE_OUTPUTS)}


def _law_path(x: list[float]) -> list[float]:
    """What TrackingController._core does with the core: pre, the scalar flatness map with
    the vehicle's parameters, post."""
    pre = tracking_pre(fm.FLOAT, x)
    o = OFFSET
    params = MultirotorParams(mass=x[o["mass"]], inertia=np.eye(3), g=x[o["g"]],
                              hover_thrust=x[o["hover"]],
                              drag=x[o["drag_map"]])
    qw, qx, qy, qz, t_n, wx, wy, wz, sing = multirotor_attitude_scalar(
        pre["v_drag"], pre["acc"], pre["jerk"], pre["snap"], x[o["yaw"]], x[o["yaw"] + 1],
        pre["yaw_acc"], params)
    q, thrust, w = tracking_post(fm.FLOAT, (qw, qx, qy, qz), t_n, (wx, wy, wz), sing,
                                 x[o["hover"]], x[o["mass"]], x[o["g"]], x[o["thrust_min"]],
                                 x[o["thrust_max"]])
    return [*q, thrust, *w, 1.0 if pre["sat"] else 0.0, *pre["integ"], *pre["acc_d"],
            1.0 if sing else 0.0]


def test_the_controllers_path_is_the_whole_core_bit_for_bit() -> None:
    xs = random_core_inputs(np.random.default_rng(26), 400)
    n_sat = 0
    for row in xs:
        x = row.tolist()
        whole = tracking_core(fm.FLOAT, x)
        assert len(whole) == CORE_N_OUT
        assert _law_path(x) == [float(v) for v in whole]
        n_sat += whole[OUT["saturated"]] == 1.0
    assert 50 < n_sat < 350  # both sides of the limits were exercised


def test_the_casadi_build_of_the_core_agrees_with_floats() -> None:
    f = symbolic_core()
    assert (f.size1_in(0), f.size1_out(0)) == (CORE_N_IN, CORE_N_OUT)
    xs = random_core_inputs(np.random.default_rng(27), 300)
    for row in xs:
        ref = np.array(tracking_core(fm.FLOAT, row.tolist()), dtype=float)
        got = np.array(f(row)).ravel()
        np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(tx=st.floats(-60, 60), ty=st.floats(-60, 60), tz=st.floats(-30, 60),
       tilt_deg=st.floats(10, 70), t_min=st.floats(0.2, 3.0), t_max=st.floats(12, 40))
def test_the_limited_thrust_vector_is_within_every_limit(
        tx: float, ty: float, tz: float, tilt_deg: float, t_min: float, t_max: float) -> None:
    tilt = math.radians(tilt_deg)
    (ox, oy, oz), sat = limit_thrust(fm.FLOAT, (tx, ty, tz), t_min, t_max, math.cos(tilt),
                                     math.tan(tilt))
    eps = 1e-9 * t_max
    assert oz >= t_min * math.cos(tilt) - eps  # upward at least the minimum's share
    assert oz <= t_max + eps
    assert math.atan2(math.hypot(ox, oy), oz) <= tilt + 1e-9  # within the tilt cone
    assert math.hypot(ox, oy, oz) <= t_max * (1 + 1e-9)
    assert math.hypot(ox, oy, oz) >= t_min * (1 - 1e-9)
    if math.hypot(ox, oy) > 1e-9:  # the horizontal direction is kept
        assert abs(math.atan2(oy, ox) - math.atan2(ty, tx)) < 1e-9
    if (ox, oy, oz) != (tx, ty, tz):
        assert sat
    else:
        # untouched: it was inside every limit
        assert not sat
        assert t_min * math.cos(tilt) <= tz <= t_max
        assert math.hypot(tx, ty) <= min(tz * math.tan(tilt), math.sqrt(t_max**2 - tz**2))


def _one(**kw: float) -> list[float]:
    x = random_core_inputs(np.random.default_rng(5), 1)[0]
    for name, v in kw.items():
        x[OFFSET[name]] = v
    return x.tolist()


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_the_integrator_runs_in_the_air_and_only_unwinds_while_saturated(axis: int) -> None:
    o = OFFSET
    base = _one(dt=0.01, learn=1.0, fb_share=0.0)
    for i in range(3):
        base[o["ki"] + i], base[o["i_max"] + i], base[o["integ"] + i] = 0.5, 2.0, 0.2
    # near the reference: unsaturated, the integrator adds ki e dt
    near = list(base)
    for i in range(3):
        near[o["pos"] + i] = near[o["ref_pos"] + i] - 0.3
        near[o["vel"] + i] = near[o["ref_vel"] + i]
        near[o["acc_ff"] + i] = 0.0
        near[o["dist_ne"] + min(i, 1)] = 0.0
    near[o["drag"]] = near[o["drag_map"]] = 0.0
    y = tracking_core(fm.FLOAT, near)
    assert y[OUT["saturated"]] == 0.0
    assert y[OUT["integ"] + axis] == pytest.approx(0.2 + 0.5 * 0.3 * 0.01, abs=1e-15)
    # grounded or first update: frozen
    for frozen in ({"learn": 0.0}, {"dt": 0.0}):
        z = list(near)
        for k, v in frozen.items():
            z[o[k]] = v
        assert tracking_core(fm.FLOAT, z)[OUT["integ"] + axis] == 0.2
    # far behind (saturated): winding further is refused, unwinding allowed
    far = list(near)
    for i in range(3):
        far[o["pos"] + i] = far[o["ref_pos"] + i] - 40.0
    y = tracking_core(fm.FLOAT, far)
    assert y[OUT["saturated"]] == 1.0
    assert y[OUT["integ"] + axis] == 0.2
    for i in range(3):
        far[o["integ"] + i] = -0.2
    assert tracking_core(fm.FLOAT, far)[OUT["integ"] + axis] == pytest.approx(
        -0.2 + 0.5 * 40.0 * 0.01)
    # the bound holds
    for i in range(3):
        far[o["integ"] + i] = -0.2
        far[o["pos"] + i] = far[o["ref_pos"] + i] - 4000.0
    assert tracking_core(fm.FLOAT, far)[OUT["integ"] + axis] == 2.0


def test_the_commanded_attitude_is_within_the_tilt_limit_whatever_the_maps_drag() -> None:
    """The attitude the core commands (its quaternion's body z against down) tilts no further
    than the limit where the limit acts, also when the flatness map's drag (`drag_map`, the
    controller's rounding of the estimate) is not the drag of the limited thrust vector (before:
    the map's thrust vector was the limited one plus (D - D_map) v; real PX4, 45.001 deg)."""
    rng = np.random.default_rng(29)
    x = random_core_inputs(rng, 4000)
    d = x[:, OFFSET["drag"]]
    x[:, OFFSET["drag"]] = d + rng.choice([0.0, 4e-5, -4e-5, 0.3, -0.3], d.shape) * (d > 0.3)
    checked = 0
    for row in x:
        y = tracking_core(fm.FLOAT, row.tolist())
        if y[OUT["saturated"]] < 0.5 or y[OUT["singular"]] > 0.5:
            continue
        _qw, qx, qy, _qz = y[OUT["q_wxyz"]:OUT["q_wxyz"] + 4]
        cos_tilt = 1.0 - 2.0 * (qx * qx + qy * qy)  # body z . down of the commanded attitude
        limit = math.acos(row[OFFSET["cos_tilt"]])
        assert math.acos(max(-1.0, min(1.0, cos_tilt))) <= limit + 1e-9
        checked += 1
    assert checked > 500  # the limit acted in many of them
