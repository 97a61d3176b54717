"""gen_c input/output validation: every input element, set to NaN, +-inf or an out-of-range
value, is rejected with the documented code and leaves the outputs untouched, in double and
float, for ecca_bezier_eval, ecca_multirotor_setpoint and ecca_full_setpoint.

The library checks fewer values on its fast path (a finite sum of outputs proves the control
points and inertia finite, see ecca_setpoint_impl.inc) and falls back to element-by-element
checks; the expected codes here come from the documented rule, written independently in Python
(`_segment_ok`, `_params_ok`, `_state_ok`), not from the C code. Also: the fast path's
false alarms (a sum that overflows although every term is finite) still give ECCA_OK, and the
fused full setpoint equals evaluate-then-flatness bit for bit.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from gen_c import native

OK, ERR_INPUT = 0, -2
LIMIT = 1e12
PRECS = ("double", "float")
NONFINITE = (math.nan, math.inf, -math.inf)


def _struct(lib: native.NativeSetpoint, prec: str, kind: str) -> Any:
    return lib._s[prec][kind]()


def _leaves(obj: Any) -> Iterator[tuple[str, Callable[[float], None], Callable[[], float]]]:
    """(name, setter, getter) of every real element of a ctypes struct (nested arrays too)."""
    for fname, ftype in obj._fields_:
        if ftype in (ctypes.c_uint, ctypes.c_int):
            continue
        val = getattr(obj, fname)
        if isinstance(val, float):
            def set_s(x: float, o: Any = obj, f: str = fname) -> None:
                setattr(o, f, x)

            def get_s(o: Any = obj, f: str = fname) -> float:
                return float(getattr(o, f))

            yield fname, set_s, get_s
            continue
        stack: list[tuple[str, Any]] = [(fname, val)]
        while stack:
            name, arr = stack.pop()
            for i in range(len(arr)):
                if isinstance(arr[i], float):
                    def set_a(x: float, a: Any = arr, k: int = i) -> None:
                        a[k] = x

                    def get_a(a: Any = arr, k: int = i) -> float:
                        return float(a[k])

                    yield f"{name}[{i}]", set_a, get_a
                else:
                    stack.append((f"{name}[{i}]", arr[i]))


def _segment(lib: native.NativeSetpoint, prec: str, scale: float = 1.0) -> Any:
    seg = _struct(lib, prec, "segment")
    pts = [(0, 0, -2), (1, 0.5, -2.2), (2.5, 1.5, -2.5), (4, 1, -3), (5, -0.5, -3.2),
           (6.5, -1, -3), (8, 0, -2.8), (9, 0.5, -2.5)]
    for i, p in enumerate(pts):
        for k in range(3):
            seg.ctrl_pts_ned_m[i][k] = scale * p[k]
        seg.yaw_ctrl_pts_rad[i] = 0.125 * i
    seg.duration_s = 4.0
    return seg


def _params(lib: native.NativeSetpoint, prec: str) -> Any:
    p = _struct(lib, prec, "params")
    p.mass_kg, p.gravity_m_s2, p.hover_thrust, p.drag_n_s_m = 1.5, 9.80665, 0.5, 0.75
    J = ((0.03, 0.001, 0.0), (0.001, 0.03, 0.0), (0.0, 0.0, 0.05))
    for i in range(3):
        for k in range(3):
            p.inertia_frd_kg_m2[i][k] = J[i][k]
    return p


def _state(lib: native.NativeSetpoint, prec: str, omega_zero: bool) -> Any:
    """A flat state; omega_zero gives a hover (omega = omega_dot = 0: the inertia then only
    enters as J * 0, the case where a non-finite J must still be caught)."""
    s = _struct(lib, prec, "state")
    if not omega_zero:
        for name, vals in (("vel_ned_m_s", (1.0, -0.5, 0.25)), ("acc_ned_m_s2", (0.5, 1.0, -0.5)),
                           ("jerk_ned_m_s3", (0.25, -0.5, 1.0)), ("snap_ned_m_s4", (1, 2, -1))):
            arr = getattr(s, name)
            for k in range(3):
                arr[k] = vals[k]
        s.yaw_rad, s.yaw_rate_rad_s, s.yaw_acc_rad_s2 = 0.5, 0.25, -0.125
    return s


# The documented acceptance rule (README "Errors"), written independently of the C code.
def _finite(x: float) -> bool:
    return math.isfinite(x)


def _segment_ok(seg: Any, t: float) -> bool:
    vals = [v for row in seg.ctrl_pts_ned_m for v in row] + list(seg.yaw_ctrl_pts_rad)
    return (all(map(_finite, vals)) and _finite(seg.duration_s) and seg.duration_s > 0
            and _finite(t))


def _params_ok(p: Any) -> bool:
    J = [v for row in p.inertia_frd_kg_m2 for v in row]
    return (all(map(_finite, J)) and _finite(p.mass_kg) and p.mass_kg > 0
            and _finite(p.gravity_m_s2) and p.gravity_m_s2 > 0 and 0 < p.hover_thrust <= 1
            and _finite(p.drag_n_s_m) and p.drag_n_s_m >= 0)


def _state_ok(s: Any, lim: float) -> bool:
    vals = [*s.vel_ned_m_s, *s.acc_ned_m_s2, *s.jerk_ned_m_s3, *s.snap_ned_m_s4, s.yaw_rad,
            s.yaw_rate_rad_s, s.yaw_acc_rad_s2]
    return all(abs(v) <= lim for v in vals)  # False for NaN


def _limit(prec: str) -> float:
    return float(ctypes.c_float(LIMIT).value) if prec == "float" else LIMIT


def _bad_values(name: str) -> tuple[float, ...]:
    extra: dict[str, tuple[float, ...]] = {
        "duration_s": (0.0, -1.0, -0.0), "mass_kg": (0.0, -1.0), "gravity_m_s2": (0.0, -9.8),
        "hover_thrust": (0.0, -0.5, 1.0000001, 1.5), "drag_n_s_m": (-0.5,),
    }
    bounded = name.split("[")[0] in ("vel_ned_m_s", "acc_ned_m_s2", "jerk_ned_m_s3",
                                     "snap_ned_m_s4", "yaw_rad", "yaw_rate_rad_s",
                                     "yaw_acc_rad_s2")
    return NONFINITE + extra.get(name, ()) + ((2e12, -2e12) if bounded else ())


def _sentinel(obj: Any) -> bytes:
    ctypes.memset(ctypes.addressof(obj), 0x5A, ctypes.sizeof(obj))
    return bytes(obj)


@pytest.mark.parametrize("prec", PRECS)
def test_bezier_eval_rejects_every_bad_element(lib: native.NativeSetpoint, prec: str) -> None:
    fn = lib._fn[(prec, "bezier")]
    seg = _segment(lib, prec)
    out = _struct(lib, prec, "state")
    checked = 0
    for t in (0.0, 1.3, 4.0):  # tau = 0 (all but one Bernstein weight zero), inside, 1
        for name, setter, getter in [*_leaves(seg), ("t_s", lambda _x: None, lambda: 0.0)]:
            good = getter()
            for bad in _bad_values(name):
                tt = bad if name == "t_s" else t
                if name != "t_s":
                    setter(bad)
                expect = OK if _segment_ok(seg, tt) else ERR_INPUT
                before = _sentinel(out)
                rc = fn(ctypes.byref(seg), tt, ctypes.byref(out))
                assert rc == expect, (prec, name, bad, t, rc)
                if rc != OK:
                    assert bytes(out) == before, (prec, name, bad, "output modified")
                checked += 1
                if name != "t_s":
                    setter(good)
    assert checked > 3 * (24 + 8) * 3
    assert fn(ctypes.byref(seg), 1.0, ctypes.byref(out)) == OK


@pytest.mark.parametrize("prec", PRECS)
@pytest.mark.parametrize("omega_zero", [False, True])
def test_multirotor_rejects_every_bad_element(lib: native.NativeSetpoint, prec: str,
                                              omega_zero: bool) -> None:
    fn = lib._fn[(prec, "multirotor")]
    st, pr = _state(lib, prec, omega_zero), _params(lib, prec)
    out = _struct(lib, prec, "attitude")
    lim = _limit(prec)
    assert fn(ctypes.byref(st), ctypes.byref(pr), ctypes.byref(out)) == OK
    if omega_zero:
        assert list(out.omega_dot_frd_rad_s2) == [0.0, 0.0, 0.0]
    for name, setter, getter in [*_leaves(st), *_leaves(pr)]:
        good = getter()
        for bad in _bad_values(name):
            setter(bad)
            # pos is not a flatness input: any value (even NaN) is ignored.
            expect = OK if _state_ok(st, lim) and _params_ok(pr) else ERR_INPUT
            before = _sentinel(out)
            rc = fn(ctypes.byref(st), ctypes.byref(pr), ctypes.byref(out))
            assert rc == expect, (prec, omega_zero, name, bad, rc)
            if rc != OK:
                assert bytes(out) == before, (prec, name, bad, "output modified")
            else:
                assert all(map(_finite, [out.thrust_n, *out.q_wxyz, *out.moment_frd_n_m]))
            setter(good)


@pytest.mark.parametrize("prec", PRECS)
def test_full_setpoint_rejects_every_bad_element(lib: native.NativeSetpoint, prec: str) -> None:
    fn = lib._fn[(prec, "full")]
    seg, pr = _segment(lib, prec), _params(lib, prec)
    st, out = _struct(lib, prec, "state"), _struct(lib, prec, "attitude")
    for t in (0.0, 2.1):
        for name, setter, getter in [*_leaves(seg), *_leaves(pr),
                                     ("t_s", lambda _x: None, lambda: 0.0)]:
            good = getter()
            for bad in _bad_values(name):
                tt = bad if name == "t_s" else t
                if name != "t_s":
                    setter(bad)
                expect = OK if _segment_ok(seg, tt) and _params_ok(pr) else ERR_INPUT
                before_a, before_s = _sentinel(out), _sentinel(st)
                rc = fn(ctypes.byref(seg), tt, ctypes.byref(pr), ctypes.byref(st),
                        ctypes.byref(out))
                assert rc == expect, (prec, name, bad, t, rc)
                if rc != OK:
                    assert bytes(out) == before_a and bytes(st) == before_s, (prec, name, bad)
                if name != "t_s":
                    setter(good)


@pytest.mark.parametrize("prec", PRECS)
def test_derivatives_beyond_the_limit_are_refused(lib: native.NativeSetpoint, prec: str) -> None:
    """A valid segment whose evaluated snap exceeds 1e12 (tiny duration): evaluation is fine,
    the full setpoint refuses it (ECCA_ERR_INPUT) and leaves both outputs untouched."""
    seg, pr = _segment(lib, prec), _params(lib, prec)
    seg.duration_s = 1e-4
    st, out = _struct(lib, prec, "state"), _struct(lib, prec, "attitude")
    assert lib._fn[(prec, "bezier")](ctypes.byref(seg), 0.0, ctypes.byref(st)) == OK
    assert _finite(st.snap_ned_m_s4[0]) and not _state_ok(st, _limit(prec))
    before_a, before_s = _sentinel(out), _sentinel(st)
    rc = lib._fn[(prec, "full")](ctypes.byref(seg), 0.0, ctypes.byref(pr), ctypes.byref(st),
                                 ctypes.byref(out))
    assert rc == ERR_INPUT and bytes(out) == before_a and bytes(st) == before_s


@pytest.mark.parametrize("prec", PRECS)
def test_fast_path_false_alarms_still_succeed(lib: native.NativeSetpoint, prec: str) -> None:
    """Every value finite and in range, but their sums overflow or exceed the limit: the
    library must fall back to the element checks and succeed."""
    big = 1.5e308 if prec == "double" else 3.0e38
    seg = _segment(lib, prec, scale=0.0)
    for i in range(8):
        for k in range(3):
            seg.ctrl_pts_ned_m[i][k] = big  # constant segment: pos = big (x3 overflows a sum)
    st = _struct(lib, prec, "state")
    assert lib._fn[(prec, "bezier")](ctypes.byref(seg), 0.5, ctypes.byref(st)) == OK
    assert st.pos_ned_m[0] == pytest.approx(big, rel=1e-6) and st.vel_ned_m_s[0] == 0.0
    pr, out = _params(lib, prec), _struct(lib, prec, "attitude")
    rc = lib._fn[(prec, "full")](ctypes.byref(seg), 0.5, ctypes.byref(pr), ctypes.byref(st),
                                 ctypes.byref(out))
    assert rc == OK and out.thrust_n == pytest.approx(1.5 * 9.80665, rel=1e-5)
    # 15 flatness inputs each <= 1e12 whose absolute sum is > 1e12.
    s2 = _state(lib, prec, omega_zero=True)
    s2.vel_ned_m_s[0] = s2.vel_ned_m_s[1] = 0.75 * LIMIT
    assert _state_ok(s2, _limit(prec))
    rc = lib._fn[(prec, "multirotor")](ctypes.byref(s2), ctypes.byref(pr), ctypes.byref(out))
    assert rc == OK and _finite(out.thrust_n) and out.thrust_n > 1e11


@pytest.mark.parametrize("prec", PRECS)
def test_fused_full_setpoint_equals_evaluate_then_flatness(lib: native.NativeSetpoint,
                                                           prec: str) -> None:
    """ecca_full_setpoint (one fused kernel) == ecca_bezier_eval then ecca_multirotor_setpoint,
    bit for bit, over the segment including both ends."""
    seg, pr = _segment(lib, prec), _params(lib, prec)
    st1, st2 = _struct(lib, prec, "state"), _struct(lib, prec, "state")
    a1, a2 = _struct(lib, prec, "attitude"), _struct(lib, prec, "attitude")
    for i in range(41):
        t = 4.0 * i / 40
        assert lib._fn[(prec, "full")](ctypes.byref(seg), t, ctypes.byref(pr),
                                       ctypes.byref(st1), ctypes.byref(a1)) == OK
        assert lib._fn[(prec, "bezier")](ctypes.byref(seg), t, ctypes.byref(st2)) == OK
        assert lib._fn[(prec, "multirotor")](ctypes.byref(st2), ctypes.byref(pr),
                                             ctypes.byref(a2)) == OK
        assert bytes(st1) == bytes(st2) and bytes(a1) == bytes(a2), (prec, t)


# Ackermann rover: the documented rule (README "Errors"): the x, y components of vel, acc and
# jerk are the inputs (finite, |value| <= 1e12; z, snap, yaw and pos are ignored) and the wheel
# base must be in (0, 1e12] m.
_ROVER_INPUTS = ("vel_ned_m_s[0]", "vel_ned_m_s[1]", "acc_ned_m_s2[0]", "acc_ned_m_s2[1]",
                 "jerk_ned_m_s3[0]", "jerk_ned_m_s3[1]")
_BAD_WHEEL_BASES = (*NONFINITE, 0.0, -0.0, -0.5, 2e12)


def _wheel_base_ok(wheel_base: float, lim: float) -> bool:
    return 0.0 < wheel_base <= lim  # False for NaN


@pytest.mark.parametrize("prec", PRECS)
def test_ackermann_rejects_every_bad_element(lib: native.NativeSetpoint, prec: str) -> None:
    fn = lib._fn[(prec, "ackermann")]
    st = _state(lib, prec, omega_zero=False)
    out = _struct(lib, prec, "steering")
    lim = _limit(prec)
    assert fn(ctypes.byref(st), 0.5, ctypes.byref(out)) == OK
    checked = 0
    for name, setter, getter in _leaves(st):
        good = getter()
        for bad in _bad_values(name):
            setter(bad)
            expect = OK
            if name in _ROVER_INPUTS and not abs(bad) <= lim:
                expect = ERR_INPUT
            before = _sentinel(out)
            rc = fn(ctypes.byref(st), 0.5, ctypes.byref(out))
            assert rc == expect, (prec, name, bad, rc)
            if rc != OK:
                assert bytes(out) == before, (prec, name, bad, "output modified")
            else:
                assert all(map(_finite, [out.heading.yaw_rad, out.curvature_1_m,
                                         out.steer_rate_rad_s]))
            checked += 1
            setter(good)
    for bad in _BAD_WHEEL_BASES:
        before = _sentinel(out)
        expect = OK if _wheel_base_ok(bad, lim) else ERR_INPUT
        assert fn(ctypes.byref(st), bad, ctypes.byref(out)) == expect == ERR_INPUT, (prec, bad)
        assert bytes(out) == before, (prec, bad, "output modified")
    assert fn(ctypes.byref(st), lim, ctypes.byref(out)) == OK  # the limit itself is accepted
    assert checked > 6 * 5


@pytest.mark.parametrize("prec", PRECS)
def test_full_ackermann_rejects_every_bad_element(lib: native.NativeSetpoint, prec: str) -> None:
    fn = lib._fn[(prec, "full_ackermann")]
    seg = _segment(lib, prec)
    st, out = _struct(lib, prec, "state"), _struct(lib, prec, "steering")
    lim = _limit(prec)
    for t in (0.0, 2.1):
        for wheel_base in (0.5, *_BAD_WHEEL_BASES):
            for name, setter, getter in [*_leaves(seg), ("t_s", lambda _x: None, lambda: 0.0),
                                         ("none", lambda _x: None, lambda: 0.0)]:
                good = getter()
                bads = _bad_values(name) if name != "none" else (0.0,)
                for bad in bads:
                    tt = bad if name == "t_s" else t
                    if name not in ("t_s", "none"):
                        setter(bad)
                    ok = _segment_ok(seg, tt) and _wheel_base_ok(wheel_base, lim)
                    expect = OK if ok else ERR_INPUT
                    before_o, before_s = _sentinel(out), _sentinel(st)
                    rc = fn(ctypes.byref(seg), tt, wheel_base, ctypes.byref(st),
                            ctypes.byref(out))
                    assert rc == expect, (prec, name, bad, t, wheel_base, rc)
                    if rc != OK:
                        assert bytes(out) == before_o and bytes(st) == before_s, (prec, name)
                    if name not in ("t_s", "none"):
                        setter(good)
