"""The rates-mode SO(3) loop on floats (`so3_rate_command_f` and its parts) against the numpy
versions it stands in for, bit for bit.

numpy hands 3x3 products and dots of 3 to its BLAS; OpenBLAS's x86-64 kernels (Haswell and
later) round them as chains of fused multiply-adds, which the float code reproduces exactly
(`_fma`: Dekker's product and `math.fsum`). `_fma` is checked against exact rational arithmetic
everywhere; the comparisons with numpy are bit for bit where this numpy's BLAS rounds as that
chain (`NUMPY_ROUNDS_AS_FMA`, probed in tests/support/blas.py: OpenBLAS's SkylakeX kernels;
its Haswell kernels round a 1-D dot of 3 without FMA) and within 1e-13 elsewhere (the same
formulas, a different rounding of the sums).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.control import AttitudeGains
from companion.control.so3 import (
    TILT_GUARD_GAIN,
    TILT_GUARD_LEAD_S,
    _axis_angle_dcm,
    _axis_angle_dcm_f,
    _dot3,
    _fma,
    _mul,
    quat_to_dcm,
    quat_to_dcm_f,
    rotate_f,
    so3_rate_command_dcm,
    so3_rate_command_f,
    tilt_guard,
    tilt_guard_f,
    tilt_priority_error,
    tilt_priority_error_f,
)
from tests.support.blas import fma_exact as _fma_exact
from tests.support.blas import numpy_rounds_as_fma_chain

GAINS = [AttitudeGains(), AttitudeGains(tilt_priority=False),
         AttitudeGains(tilt_priority=False, large_angle=False), AttitudeGains(yaw_weight=1.0)]


NUMPY_ROUNDS_AS_FMA = numpy_rounds_as_fma_chain()


def _same(fast: object, general: np.ndarray) -> None:
    f = np.array(fast, dtype=np.float64)
    assert f.shape == general.shape
    if NUMPY_ROUNDS_AS_FMA:
        assert f.tobytes() == general.tobytes(), (f, general)
    else:
        np.testing.assert_allclose(f, general, rtol=0.0, atol=1e-13)


def _quat_to_dcm_array(q: np.ndarray) -> np.ndarray:
    """so3.quat_to_dcm before it wrapped the float version (b14b8dd): the oracle."""
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not (math.isfinite(n) and n > 0.0):
        return np.eye(3)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _tilt_guard_array(R: np.ndarray, omega: np.ndarray, lim: float,
                      now_frd: np.ndarray | None) -> np.ndarray:
    """so3.tilt_guard before it wrapped the float version (b14b8dd), default gain and lead:
    the oracle."""
    g0, g1 = float(R[2, 0]), float(R[2, 1])
    s = math.hypot(g0, g1)
    if s < 1e-9:
        return omega
    tilt = math.atan2(s, float(R[2, 2]))
    n0, n1 = g1 / s, -g0 / s
    if now_frd is not None:
        now = float(now_frd[0]) * n0 + float(now_frd[1]) * n1
        if math.isfinite(now):
            tilt += TILT_GUARD_LEAD_S * now
    rate = float(omega[0]) * n0 + float(omega[1]) * n1
    allowed = TILT_GUARD_GAIN * (lim - tilt)
    if rate <= allowed:
        return omega
    out = np.array(omega, dtype=np.float64)
    out[0] -= (rate - allowed) * n0
    out[1] -= (rate - allowed) * n1
    return out


def _rows(m: np.ndarray) -> tuple[tuple[float, float, float], ...]:
    return tuple((float(r[0]), float(r[1]), float(r[2])) for r in m)


def test_fma_is_one_rounding_of_the_exact_value() -> None:
    rng = np.random.default_rng(1)
    vals = np.concatenate([rng.normal(size=3000), rng.normal(size=500) * 1e-150,
                           rng.normal(size=500) * 1e140, [0.0, -0.0, 1.0, -1.0, 0.5]])
    for _ in range(20000):
        a, b, c = (float(x) for x in rng.choice(vals, 3))
        got, want = _fma(a, b, c), _fma_exact(a, b, c)
        assert (got, math.copysign(1.0, got)) == (want, math.copysign(1.0, want))
    # products that round: the exact value decides (a * b + c alone is off by one ulp)
    a, b = 1.0 + 2.0 ** -30, 1.0 + 2.0 ** -30
    assert _fma(a, b, -1.0) == 2.0 ** -29 + 2.0 ** -60 != a * b - 1.0


def test_dot3_is_the_fma_chain_from_plus_zero() -> None:
    rng = np.random.default_rng(2)
    for _ in range(5000):
        a, b = rng.normal(size=3).tolist(), rng.normal(size=3).tolist()
        chain = _fma_exact(a[2], b[2], _fma_exact(a[1], b[1], _fma_exact(a[0], b[0], 0.0)))
        assert _dot3(*a, *b) == chain
    assert math.copysign(1.0, _dot3(1.0, 1.0, 1.0, -0.0, -0.0, -0.0)) == 1.0  # as numpy: +0


def test_products_dots_and_norms_match_numpy() -> None:
    rng = np.random.default_rng(3)
    for _ in range(2000):
        A, B, v = rng.normal(size=(3, 3)), rng.normal(size=(3, 3)), rng.normal(size=3)
        _same(_mul(_rows(A), _rows(B.T)), A @ B)
        _same(_mul(_rows(A.T), _rows(B.T)), A.T @ B)
        _same(rotate_f(_rows(A), v.tolist()), A @ v)
        _same(_dot3(*A[:, 2].tolist(), *B[:, 2].tolist()), np.float64(A[:, 2] @ B[:, 2]))
        _same(math.sqrt(_dot3(*v.tolist(), *v.tolist())), np.float64(np.linalg.norm(v)))


def _pairs() -> list[tuple[np.ndarray, np.ndarray]]:
    """(q, q_des) (w, x, y, z): random, close (tilt ~0), yaw apart only, thrust axes ~opposite
    (tilt ~180 deg), equal."""
    rng = np.random.default_rng(4)
    rots = Rotation.random(1500, random_state=5)
    out = []
    for i in range(0, 1500, 2):
        out.append((rots[i], rots[i + 1]))
    for r in rots[:300]:
        gap = 10.0 ** rng.uniform(-13, -2)
        out.append((r, r * Rotation.from_rotvec(rng.normal(size=3) * gap)))
        out.append((r, r * Rotation.from_rotvec([0.0, 0.0, rng.uniform(-math.pi, math.pi)])))
        ax = rng.normal(size=2)
        flip = np.array([*ax / np.linalg.norm(ax), 0.0]) * (math.pi - gap)
        out.append((r, r * Rotation.from_rotvec(flip)))
        out.append((r, r * Rotation.from_rotvec([math.pi, 0.0, 0.0])))
        out.append((r, r))
    out.append((Rotation.identity(), Rotation.identity()))
    out.append((Rotation.identity(), Rotation.from_rotvec([math.pi, 0.0, 0.0])))
    out.append((Rotation.identity(), Rotation.from_rotvec([0.0, 0.0, math.pi])))

    def wxyz(r: Rotation) -> np.ndarray:
        x, y, z, w = r.as_quat()
        return np.array([w, x, y, z])

    return [(wxyz(a), wxyz(b)) for a, b in out]


PAIRS = _pairs()


@pytest.mark.parametrize("gains", GAINS, ids=["tilt_priority", "large_angle", "plain", "yaw_w1"])
def test_rate_command_matches_the_numpy_loop(gains: AttitudeGains) -> None:
    rng = np.random.default_rng(6)
    for q, qd in PAIRS:
        R, Rd = _quat_to_dcm_array(q), _quat_to_dcm_array(qd)
        Rf, Rdf = quat_to_dcm_f(q.tolist()), quat_to_dcm_f(qd.tolist())
        assert np.array(Rf).tobytes() == R.tobytes()
        ff = rng.normal(size=3) * 3.0
        omega, e_R = so3_rate_command_dcm(R, Rd, ff, gains)
        omega_f, e_R_f, X = so3_rate_command_f(Rf, Rdf, ff.tolist(), gains)
        _same(omega_f, omega)
        _same(e_R_f, e_R)
        _same(X, R.T @ Rd)
        _same(np.array(X).T, Rd.T @ R)  # the transpose's products are the same
        _same(X[2][2], np.float64(Rd[:, 2] @ R[:, 2]))  # the law's thrust projection
        _same(rotate_f(X, ff.tolist()), (R.T @ Rd) @ ff)  # the law's rate error


def test_tilt_priority_error_and_the_axis_angle_matrix_match_numpy() -> None:
    for q, qd in PAIRS:
        R, Rd = quat_to_dcm(q), quat_to_dcm(qd)
        for w in (0.4, 1.0, 0.05):
            _same(tilt_priority_error_f(_rows(R), _rows(Rd), w), tilt_priority_error(R, Rd, w))
        axis = np.cross(R[:, 2], Rd[:, 2])
        s, c = float(np.linalg.norm(axis)), float(R[:, 2] @ Rd[:, 2])
        _same(_axis_angle_dcm_f((axis[0], axis[1], axis[2]), s, c), _axis_angle_dcm(axis, s, c))


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_feed_forward_as_before(bad: float) -> None:
    q, qd = PAIRS[0]
    R, Rd = quat_to_dcm(q), quat_to_dcm(qd)
    ff = np.array([0.3, bad, -0.2])
    for gains in GAINS:
        omega, e_R = so3_rate_command_dcm(R, Rd, ff, gains)  # zeros in its place
        omega_f, e_R_f, X = so3_rate_command_f(_rows(R), _rows(Rd), ff.tolist(), gains)
        _same(omega_f, omega)
        _same(e_R_f, e_R)
    with np.errstate(invalid="ignore"):
        general = (R.T @ Rd) @ ff
    fast = np.array(rotate_f(X, ff.tolist()))
    assert fast.tobytes() == general.tobytes()  # through numpy itself


@pytest.mark.parametrize("q", [[0.0, 0.0, 0.0, 0.0], [math.nan, 0.0, 0.0, 1.0],
                               [math.inf, 1.0, 0.0, 0.0], [1e300, 1e300, 0.0, 0.0]])
def test_bad_quaternions_give_the_identity_as_before(q: list[float]) -> None:
    assert quat_to_dcm_f(q) == ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    assert quat_to_dcm(np.array(q)).tolist() == np.eye(3).tolist()
    assert _quat_to_dcm_array(np.array(q)).tolist() == np.eye(3).tolist()


def test_tilt_guard_on_floats_is_the_array_version() -> None:
    rng = np.random.default_rng(7)
    for q, _ in PAIRS[:600]:
        R = quat_to_dcm(q)
        omega = rng.normal(size=3) * 3.0
        now = rng.normal(size=3) * 2.0
        for omega_now in (None, now, np.array([math.nan, 0.0, 0.0])):
            lim = float(rng.uniform(0.2, 1.2))
            general = _tilt_guard_array(R, omega, lim, omega_now)
            assert np.array(tilt_guard(R, omega, lim, omega_now)).tobytes() == np.asarray(
                general, dtype=np.float64).tobytes()  # the array wrapper too
            w = (float(omega[0]), float(omega[1]), float(omega[2]))
            fast = tilt_guard_f(_rows(R), w, lim, None if omega_now is None else omega_now.tolist())
            assert np.array(fast).tobytes() == np.asarray(general, dtype=np.float64).tobytes()
            assert (fast is w) == (general is omega)  # unchanged rates: the very input
    level = np.eye(3)
    assert tilt_guard_f(_rows(level), (1.0, 2.0, 3.0), 0.5) == (1.0, 2.0, 3.0)
