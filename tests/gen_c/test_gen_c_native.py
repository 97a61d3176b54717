"""gen_c.native: the compiled library called through ctypes agrees with the Python path
(companion.flatness numeric, companion.trajectory.Bezier) on hypothesis-random inputs:
double to 1e-12 and float to 1e-4 relative (scale max(|field|, 1)); errors map to ValueError;
the loader falls back to None without a compiler."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.flatness import MultirotorParams, multirotor_setpoint, rover_setpoint
from companion.trajectory import Bezier
from gen_c import native
from tests.support.gen_c import RTOL_DOUBLE, RTOL_FLOAT, assert_close

SETTINGS = settings(max_examples=60, deadline=None)


@pytest.fixture(scope="module")
def cache(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tmp_path_factory.mktemp("gen_c_cache")


@pytest.fixture(scope="module")
def lib(cache: Path) -> native.NativeSetpoint:
    return native.NativeSetpoint(native.build_library(cache=cache))


def f32(x: object) -> np.ndarray:
    return np.asarray(x, dtype=np.float64).astype(np.float32).astype(np.float64)


def vec3(lo: float, hi: float) -> st.SearchStrategy[list[float]]:
    return st.lists(st.floats(lo, hi, allow_nan=False), min_size=3, max_size=3)


@st.composite
def params(draw: st.DrawFn, flight_envelope: bool = False) -> MultirotorParams:
    d = [draw(st.floats(0.005, 0.2)) for _ in range(3)]
    off = draw(st.floats(-0.3, 0.3)) * min(d)
    J = np.diag(d)
    J[0, 1] = J[1, 0] = off
    if flight_envelope:  # earth gravity, drag force well below the weight
        return MultirotorParams(mass=draw(st.floats(0.8, 5.0)), inertia=J, g=9.80665,
                                hover_thrust=draw(st.floats(0.2, 0.9)),
                                drag=draw(st.sampled_from([0.0, 0.1, 0.5])))
    return MultirotorParams(mass=draw(st.floats(0.3, 5.0)), inertia=J,
                            g=draw(st.sampled_from([9.80665, 9.81, 3.72])),
                            hover_thrust=draw(st.floats(0.2, 0.9)),
                            drag=draw(st.sampled_from([0.0, 0.1, 1.0])))


def compare_multirotor(got: native.NativeMultirotorSetpoint, exp: object, rtol: float) -> None:
    for name in ("thrust", "thrust_dot", "thrust_ddot", "thrust_norm", "q_wxyz", "C_eb",
                 "omega_frd", "omega_dot_frd", "moment_frd"):
        assert_close(getattr(got, name), getattr(exp, name), rtol, name)
    assert got.flags == exp.flags and got.singular == exp.singular  # type: ignore[attr-defined]


@SETTINGS
@given(vel=vec3(-15, 15), acc=vec3(-20, 20), jerk=vec3(-50, 50), snap=vec3(-200, 200),
       yaw=st.floats(-20, 20), yaw_rate=st.floats(-5, 5), yaw_acc=st.floats(-20, 20),
       p=params())
def test_multirotor_double_matches_python(lib: native.NativeSetpoint, vel: list[float],
                                          acc: list[float], jerk: list[float], snap: list[float],
                                          yaw: float, yaw_rate: float, yaw_acc: float,
                                          p: MultirotorParams) -> None:
    """Aggressive range (|a| up to 2 g, inverted and near-singular states included)."""
    exp = multirotor_setpoint(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, p)
    got = lib.multirotor(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, p)
    compare_multirotor(got, exp, RTOL_DOUBLE)


@SETTINGS
@given(vel=vec3(-3, 3), axy=st.lists(st.floats(-7, 7), min_size=2, max_size=2),
       az=st.floats(-6, 4), jerk=vec3(-20, 20), snap=vec3(-80, 80), yaw=st.floats(-7, 7),
       yaw_rate=st.floats(-3, 3), yaw_acc=st.floats(-10, 10), p=params(flight_envelope=True))
def test_multirotor_float_matches_python(lib: native.NativeSetpoint, vel: list[float],
                                         axy: list[float], az: float, jerk: list[float],
                                         snap: list[float], yaw: float, yaw_rate: float,
                                         yaw_acc: float, p: MultirotorParams) -> None:
    """Float variant on the flight envelope (tilt < ~70 deg, thrust well above 0), with inputs
    representable in float (the float library cannot see more digits)."""
    args = [f32(vel), f32([*axy, az]), f32(jerk), f32(snap), float(f32(yaw)),
            float(f32(yaw_rate)), float(f32(yaw_acc))]
    pf = MultirotorParams(mass=float(f32(p.mass)), inertia=f32(p.inertia), g=float(f32(p.g)),
                          hover_thrust=float(f32(p.hover_thrust)), drag=float(f32(p.drag)))
    exp = multirotor_setpoint(*args, pf)
    assert exp.flags == 0 and exp.thrust > 0.3 * pf.mass * pf.g  # inside the envelope
    got = lib.multirotor(*args, pf, precision="float")
    compare_multirotor(got, exp, RTOL_FLOAT)


@SETTINGS
@given(cp=st.lists(vec3(-50, 50), min_size=8, max_size=8),
       ycp=st.lists(st.floats(-7, 7), min_size=8, max_size=8), h=st.floats(0.05, 20),
       s=st.floats(-0.2, 1.2))
def test_bezier_matches_de_casteljau(lib: native.NativeSetpoint, cp: list[list[float]],
                                     ycp: list[float], h: float, s: float) -> None:
    """C Bernstein evaluation vs companion.trajectory.Bezier (de Casteljau), t clamped."""
    t = s * h
    tc = min(max(t, 0.0), h)
    seg, yseg = Bezier(cp, h), Bezier(np.asarray(ycp)[:, None], h)
    for prec, rtol in (("double", RTOL_DOUBLE), ("float", RTOL_FLOAT)):
        if prec == "float":
            cp, ycp, h = f32(cp), f32(ycp), float(f32(h))
            t, tc = float(f32(t)), min(max(float(f32(t)), 0.0), h)
            seg, yseg = Bezier(cp, h), Bezier(np.asarray(ycp)[:, None], h)
        got = lib.bezier(cp, ycp, h, t, precision=prec)  # type: ignore[arg-type]
        for k, name in enumerate(("pos", "vel", "acc", "jerk", "snap")):
            # scale of the k-th derivative: its control points (convex hull bound)
            exp = seg.evaluate(tc, k)
            hull = max(1.0, float(np.max(np.abs(seg.hull_bound(k)))))
            assert np.max(np.abs(getattr(got, name) - exp)) <= rtol * hull, (prec, name)
        for k, name in enumerate(("yaw", "yaw_rate", "yaw_acc")):
            hull = max(1.0, float(yseg.hull_bound(k)))
            assert abs(getattr(got, name) - yseg.evaluate(tc, k)[0]) <= rtol * hull, (prec, name)


@SETTINGS
@given(v=st.lists(st.floats(-10, 10), min_size=2, max_size=2),
       a=st.lists(st.floats(-5, 5), min_size=2, max_size=2),
       j=st.lists(st.floats(-5, 5), min_size=2, max_size=2))
def test_rover_matches_python(lib: native.NativeSetpoint, v: list[float], a: list[float],
                              j: list[float]) -> None:
    exp = rover_setpoint(v, a, j)
    got = lib.rover(v, a, j)
    for name in ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc"):
        assert_close(getattr(got, name), getattr(exp, name), RTOL_DOUBLE, name)
    assert got.singular == exp.singular
    assert lib.rover(v, a).yaw_acc is None


@settings(max_examples=25, deadline=None)
@given(cp=st.lists(vec3(-10, 10), min_size=8, max_size=8),
       ycp=st.lists(st.floats(-3, 3), min_size=8, max_size=8), h=st.floats(2.0, 10.0),
       s=st.floats(0, 1), p=params())
def test_full_setpoint_is_evaluate_then_flatness(lib: native.NativeSetpoint,
                                                 cp: list[list[float]], ycp: list[float],
                                                 h: float, s: float,
                                                 p: MultirotorParams) -> None:
    state, sp = lib.full(cp, ycp, h, s * h, p)
    seg, yseg = Bezier(cp, h), Bezier(np.asarray(ycp)[:, None], h)
    d = [seg.evaluate(s * h, k) for k in range(5)]
    y = [float(yseg.evaluate(s * h, k)[0]) for k in range(3)]
    for k, name in enumerate(("pos", "vel", "acc", "jerk", "snap")):
        hull = max(1.0, float(seg.hull_bound(k)))
        assert np.max(np.abs(getattr(state, name) - d[k])) <= RTOL_DOUBLE * hull
    # flatness of the C-evaluated state equals the Python path bit-for-bit-ish
    exp = multirotor_setpoint(state.vel, state.acc, state.jerk, state.snap, state.yaw,
                              state.yaw_rate, state.yaw_acc, p)
    compare_multirotor(sp, exp, RTOL_DOUBLE)
    assert abs(state.yaw - y[0]) <= RTOL_DOUBLE * max(1.0, float(yseg.hull_bound(0)))


def test_errors_become_value_errors(lib: native.NativeSetpoint) -> None:
    p = MultirotorParams(mass=1.0, inertia=[0.01, 0.01, 0.02])
    z = [0.0, 0.0, 0.0]
    with pytest.raises(ValueError, match="non-finite"):
        lib.multirotor([np.nan, 0, 0], z, z, z, 0.0, 0.0, 0.0, p)
    with pytest.raises(ValueError, match="non-finite or out-of-range"):
        lib.multirotor(z, z, z, [0.0, 2e12, 0.0], 0.0, 0.0, 0.0, p)  # Python path rejects too
    with pytest.raises(ValueError):
        multirotor_setpoint(z, z, z, [0.0, 2e12, 0.0], 0.0, 0.0, 0.0, p)
    with pytest.raises(ValueError, match="duration"):
        lib.bezier(np.zeros((8, 3)), None, 0.0, 0.0)
    with pytest.raises(ValueError, match="elevate"):
        lib.bezier(np.zeros((6, 3)), None, 1.0, 0.0)
    hover = lib.multirotor(z, z, z, z, 0.0, 0.0, 0.0, p, precision="float")
    assert hover.thrust == pytest.approx(9.80665, rel=1e-6) and hover.flags == 0


def test_loader_returns_working_library_or_none(monkeypatch: pytest.MonkeyPatch,
                                                tmp_path: Path, lib: native.NativeSetpoint,
                                                cache: Path) -> None:
    """The companion hot path: load_setpoint_library() gives the native path, agreeing with
    the Python path to 1e-12; without a compiler it returns None (Python fallback)."""
    monkeypatch.setenv("ECCA_GEN_C_CACHE", str(cache))
    monkeypatch.setattr(native, "_loaded", {})
    nat = native.load_setpoint_library()
    assert nat is not None and nat.casadi_version == "3.8.2"
    assert nat.path == lib.path  # reused from the cache, keyed by the source hash
    p = MultirotorParams(mass=1.5, inertia=[0.03, 0.03, 0.05], hover_thrust=0.6, drag=1.0)
    args = ([6.0, -1.0, 0.5], [1.0, 2.0, -1.0], [0.5, -0.5, 2.0], [3.0, 1.0, -2.0], 2.0, 0.7,
            -0.3)
    compare_multirotor(nat.multirotor(*args, p), multirotor_setpoint(*args, p), RTOL_DOUBLE)
    assert native.load_setpoint_library() is nat  # cached per process

    monkeypatch.setattr(native, "_loaded", {})
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    monkeypatch.setenv("ECCA_GEN_C_CACHE", str(tmp_path / "cache2"))
    assert native.load_setpoint_library() is None


def test_reentrant_from_concurrent_threads(lib: native.NativeSetpoint) -> None:
    """ctypes releases the GIL during the C call: four threads hammering the library give
    bit-identical results to a sequential run (no hidden shared state)."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(7)
    p = MultirotorParams(mass=1.2, inertia=[0.02, 0.025, 0.04], drag=0.4)
    cps = rng.uniform(-5, 5, size=(16, 8, 3))
    ycps = rng.uniform(-2, 2, size=(16, 8))

    def work(k: int) -> list[np.ndarray]:
        out = []
        for i in range(150):
            st, sp = lib.full(cps[(k + i) % 16], ycps[(k + i) % 16], 3.0, 0.02 * i, p)
            out.append(np.concatenate([st.snap, sp.q_wxyz, sp.omega_dot_frd, sp.moment_frd]))
        return out

    expected = [work(k) for k in range(4)]
    with ThreadPoolExecutor(max_workers=4) as pool:
        got = list(pool.map(work, range(4), timeout=120))
    for e, g in zip(expected, got, strict=True):
        assert all(np.array_equal(a, b) for a, b in zip(e, g, strict=True))


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), degree=st.sampled_from([5, 7]),
       s=st.floats(-0.05, 1.05), p=params(flight_envelope=True))
def test_trajectory_setpoint_matches_python_path(lib: native.NativeSetpoint, seed: int,
                                                 degree: int, s: float,
                                                 p: MultirotorParams) -> None:
    """The companion hot-path helper: PiecewiseBezier (any degree <= 7, with yaw) at global t,
    vs PiecewiseBezier.evaluate + multirotor_setpoint (t clamped, later segment at joints)."""
    from companion.trajectory import PiecewiseBezier

    rng = np.random.default_rng(seed)
    durs = rng.uniform(1.0, 4.0, size=3)
    pos = PiecewiseBezier([Bezier(rng.uniform(-3, 3, size=(degree + 1, 3)), h) for h in durs])
    yaw = PiecewiseBezier([Bezier(rng.uniform(-2, 2, size=(degree + 1, 1)), h) for h in durs])
    traj = pos.with_yaw(yaw)
    t = s * traj.duration if s < 1.0 else traj.duration + 1.0
    if 0.2 < s < 0.8:
        t = float(traj.breaks[1 + int(s > 0.5)])  # exactly at a joint
    state, sp = lib.trajectory_setpoint(traj, t, p)
    d = [traj.evaluate(t, k) for k in range(5)]
    y = [float(yaw.evaluate(t, k)[0]) for k in range(3)]
    for k, name in enumerate(("pos", "vel", "acc", "jerk", "snap")):
        scale = max(1.0, float(np.max(traj.hull_bounds(k))))
        assert np.max(np.abs(getattr(state, name) - d[k])) <= RTOL_DOUBLE * scale, name
    for k, name in enumerate(("yaw", "yaw_rate", "yaw_acc")):
        scale = max(1.0, float(np.max(yaw.hull_bounds(k))))
        assert abs(getattr(state, name) - y[k]) <= RTOL_DOUBLE * scale, name
    # flatness of the evaluated state: same inputs -> the 1e-12 agreement of the flatness map
    exp = multirotor_setpoint(state.vel, state.acc, state.jerk, state.snap, state.yaw,
                              state.yaw_rate, state.yaw_acc, p)
    compare_multirotor(sp, exp, RTOL_DOUBLE)


# ------------------------------------------------------------------ rover: Ackermann
ROVER_FIELDS = ("yaw", "speed", "speed_dot", "yaw_rate", "yaw_acc")
ACK_FIELDS = ("curvature", "curvature_rate", "steer_angle", "steer_rate")


def _row(sp: object) -> dict[str, float]:
    """The fields of a batch-of-one RoverSetpoint (numpy backend) as floats."""
    return {n: float(np.asarray(getattr(sp, n))[0]) for n in (*ROVER_FIELDS, *ACK_FIELDS)}


def compare_ackermann(got: native.NativeRoverSetpoint, v: object, a: object, j: object,
                      wheel_base: float, rtol: float) -> None:
    """The C setpoint against both Python backends: float (one sample) and numpy (a batch)."""
    exp_float = rover_setpoint(v, a, j, wheel_base_m=wheel_base)  # type: ignore[arg-type]
    exp_numpy = rover_setpoint([v], [a], [j], wheel_base_m=wheel_base)  # type: ignore[list-item]
    row = _row(exp_numpy)
    for name in (*ROVER_FIELDS, *ACK_FIELDS):
        assert_close(getattr(got, name), getattr(exp_float, name), rtol, f"{name} (float)")
        assert_close(getattr(got, name), row[name], rtol, f"{name} (numpy)")
    assert got.singular == exp_float.singular == bool(np.asarray(exp_numpy.singular)[0])


@SETTINGS
@given(v=st.lists(st.floats(-10, 10), min_size=2, max_size=2),
       a=st.lists(st.floats(-5, 5), min_size=2, max_size=2),
       j=st.lists(st.floats(-5, 5), min_size=2, max_size=2), wheel_base=st.floats(0.05, 5.0))
def test_ackermann_double_matches_python(lib: native.NativeSetpoint, v: list[float],
                                         a: list[float], j: list[float],
                                         wheel_base: float) -> None:
    compare_ackermann(lib.rover(v, a, j, wheel_base), v, a, j, wheel_base, RTOL_DOUBLE)


@SETTINGS
@given(speed=st.floats(0.5, 10.0), heading=st.floats(-np.pi, np.pi),
       a=st.lists(st.floats(-5, 5), min_size=2, max_size=2),
       j=st.lists(st.floats(-5, 5), min_size=2, max_size=2), wheel_base=st.floats(0.1, 3.0))
def test_ackermann_float_matches_python(lib: native.NativeSetpoint, speed: float,
                                        heading: float, a: list[float], j: list[float],
                                        wheel_base: float) -> None:
    """Float variant on a moving rover (0.5..10 m/s), float-representable inputs."""
    v = f32([speed * np.cos(heading), speed * np.sin(heading)])
    af, jf, L = f32(a), f32(j), float(f32(wheel_base))
    compare_ackermann(lib.rover(v, af, jf, L, precision="float"), v, af, jf, L, RTOL_FLOAT)


@pytest.mark.parametrize("v, a, j", [
    ([0.0, 0.0], [0.0, 0.0], [0.0, 0.0]),  # standing still
    ([0.0, 0.0], [-0.5, 0.75], [0.25, 0.0]),  # starting from rest
    ([0.0005, -0.0002], [1.0, 2.0], [-1.0, 0.5]),  # below the stop threshold
    ([0.00125, -0.0005], [0.5, 1.0], [-1.0, 0.5]),  # just above: kappa ~ 6e5 1/m
])
@pytest.mark.parametrize("prec", ["double", "float"])
def test_ackermann_stopped_and_near_stop_match_python(lib: native.NativeSetpoint,
                                                      v: list[float], a: list[float],
                                                      j: list[float], prec: str) -> None:
    v32, a32, j32 = f32(v), f32(a), f32(j)
    got = lib.rover(v32, a32, j32, 0.5, precision=prec)  # type: ignore[arg-type]
    compare_ackermann(got, v32, a32, j32, 0.5, RTOL_DOUBLE if prec == "double" else RTOL_FLOAT)
    if got.singular:
        assert [getattr(got, n) for n in ACK_FIELDS] == [0.0, 0.0, 0.0, 0.0]


def test_rover_without_wheel_base_or_jerk_has_no_ackermann_fields(
        lib: native.NativeSetpoint) -> None:
    plain = lib.rover([1.0, 0.5], [0.25, -0.5], [0.1, 0.2])
    assert [getattr(plain, n) for n in ACK_FIELDS] == [None] * 4
    no_jerk = lib.rover([1.0, 0.5], [0.25, -0.5], wheel_base_m=0.5)
    assert no_jerk.curvature is not None and no_jerk.steer_angle is not None
    assert no_jerk.yaw_acc is None and no_jerk.curvature_rate is None
    assert no_jerk.steer_rate is None
    ack = lib.rover([1.0, 0.5], [0.25, -0.5], [0.1, 0.2], 0.5)
    for name in (*ROVER_FIELDS, "singular"):  # the unicycle part is ecca_rover_setpoint's
        assert getattr(ack, name) == getattr(plain, name), name
    for bad in (0.0, -1.0, np.nan, np.inf, 2e12):
        with pytest.raises(ValueError, match="wheel base"):
            lib.rover([1.0, 0.5], [0.25, -0.5], [0.1, 0.2], bad)
        with pytest.raises(ValueError, match="wheel_base_m"):
            rover_setpoint([1.0, 0.5], [0.25, -0.5], [0.1, 0.2], wheel_base_m=bad)


@settings(max_examples=25, deadline=None)
@given(cp=st.lists(vec3(-10, 10), min_size=8, max_size=8), h=st.floats(2.0, 10.0),
       s=st.floats(0, 1), wheel_base=st.one_of(st.none(), st.floats(0.1, 3.0)))
def test_full_rover_is_evaluate_then_flatness(lib: native.NativeSetpoint,
                                              cp: list[list[float]], h: float, s: float,
                                              wheel_base: float | None) -> None:
    """ecca_full_rover_setpoint / ecca_full_ackermann_setpoint: the Bezier state (de Casteljau)
    and the Python rover map of that state."""
    state, sp = lib.full_rover(cp, h, s * h, wheel_base)
    seg = Bezier(cp, h)
    for k, name in enumerate(("pos", "vel", "acc", "jerk", "snap")):
        hull = max(1.0, float(seg.hull_bound(k)))
        assert np.max(np.abs(getattr(state, name) - seg.evaluate(s * h, k))) <= RTOL_DOUBLE * hull
    exp = rover_setpoint(state.vel[:2], state.acc[:2], state.jerk[:2], wheel_base_m=wheel_base)
    for name in (*ROVER_FIELDS, *ACK_FIELDS):
        if wheel_base is None and name in ACK_FIELDS:
            assert getattr(sp, name) is None and getattr(exp, name) is None
            continue
        assert_close(getattr(sp, name), getattr(exp, name), RTOL_DOUBLE, name)
    assert sp.singular == exp.singular
