"""Exact per-segment maxima of the rover quantities (speed, yaw rate, lateral acceleration) from
the critical points of each segment's polynomials, no sampling (:func:`rover_extrema`).

Used by :func:`companion.trajectory.limits.check` and by the rover time allocation: the yaw rate
``|v x a| / V^2`` and lateral acceleration ``|v x a| / V`` peak far more narrowly than any
sampling grid where a path turns while its speed dips.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from companion.trajectory.bezier import FloatArray, PiecewiseBezier, monomial_matrix

__all__ = ["ROVER_MIN_SPEED_M_S", "polyval01", "rover_extrema"]

#: Below this speed (m/s) the rover yaw rate / lateral acceleration are not evaluated (singular).
ROVER_MIN_SPEED_M_S = 1e-3

#: Evenly spaced normalised times added to the critical points (robustness against root error).
_ROVER_GRID = np.linspace(0.0, 1.0, 17)


#: Powers 0, 1, 2, ... as floats (derivatives and power matrices of the polynomials below).
_POWERS = np.arange(64, dtype=np.float64)


# Lean equivalents of numpy.polynomial's polyder / polymul / polysub / polyadd / polyroots
# for 1-D float64 coefficient arrays (ascending): the same floating-point operations in the
# same order, so the same bits, without the wrappers' argument handling (which dominated
# the rover allocation's time: thousands of tiny polynomials per plan).
def _trim(c: FloatArray) -> FloatArray:
    """Trailing exact zeros dropped, at least one coefficient kept (``polyutils.trimseq``)."""
    if c.shape[0] == 0 or c[-1] != 0:
        return c
    nz = np.flatnonzero(c)
    return c[: int(nz[-1]) + 1] if nz.shape[0] else c[:1]


def _pder(c: FloatArray) -> FloatArray:
    """First derivative (``polyder``: coefficient j times j)."""
    n = c.shape[0]
    if n <= 1:
        return np.asarray(c[:1] * 0, dtype=np.float64)
    return np.asarray(c[1:] * _POWERS[1:n], dtype=np.float64)


def _pmul(a: FloatArray, b: FloatArray) -> FloatArray:
    """Product (``polymul``)."""
    return _trim(np.asarray(np.convolve(_trim(a), _trim(b)), dtype=np.float64))


def _padd(a: FloatArray, b: FloatArray) -> FloatArray:
    """Sum (``polyadd``)."""
    a, b = _trim(a), _trim(b)
    if a.shape[0] > b.shape[0]:
        r = a.copy()
        r[: b.shape[0]] += b
    else:
        r = b.copy()
        r[: a.shape[0]] += a
    return _trim(r)


def _psub(a: FloatArray, b: FloatArray) -> FloatArray:
    """Difference a - b (``polysub``: a + (-b) rounds exactly as a - b)."""
    return _padd(a, -b)


def _proots(c: FloatArray) -> NDArray[np.complex128] | FloatArray:
    """Roots, sorted, of the polynomial ``c`` whose last coefficient is non-zero and which
    has at least two (``polyroots``: eigenvalues of the companion matrix)."""
    n = c.shape[0] - 1
    if n == 1:
        return np.array([-c[0] / c[1]])
    mat = np.zeros((n, n), dtype=np.float64)
    mat.reshape(-1)[n :: n + 1] = 1
    mat[:, -1] -= c[:-1] / c[-1]
    r = np.linalg.eigvals(mat)
    r.sort()
    return r


def _root_candidates(coef: FloatArray) -> FloatArray:
    """Real parts, clipped to [0, 1], of all roots of the polynomial with ascending
    coefficients ``coef``. Complex roots are kept: a pair close to the real axis marks a
    near-double root (a narrow peak) whose computed roots are not real to round-off, and
    extra candidates can only raise the maximum found, never lower it."""
    scale = float(np.max(np.abs(coef))) if coef.shape[0] else 0.0
    if scale == 0.0:
        return np.zeros(0)
    keep = np.flatnonzero(np.abs(coef) > 1e-13 * scale)
    c = coef[: int(keep[-1]) + 1] / scale
    if c.shape[0] < 2:
        return np.zeros(0)
    r = np.clip(_proots(c).real, 0.0, 1.0)
    # Newton polish (near-double roots come out of the eigenvalue solver with ~sqrt(eps)
    # error); raw and polished both kept
    dc = _pder(c)
    x = r.copy()
    # 3 steps: the zoom around the best candidate in `rover_extrema` covers what is left
    for _ in range(3):
        d = polyval01(x, dc)
        step = np.where(d != 0.0, polyval01(x, c) / np.where(d != 0.0, d, 1.0), 0.0)
        x = np.clip(x - step, 0.0, 1.0)
    return np.asarray(np.concatenate([r, x]), dtype=np.float64)


def polyval01(x: FloatArray, coef: FloatArray) -> FloatArray:
    """The polynomial with ascending coefficients ``coef`` at ``x`` in [0, 1], as one
    power-matrix product (numpy's ``polyval`` loops over the coefficients in Python, and this
    runs thousands of times per rover plan; on [0, 1] the powers lose nothing)."""
    return np.asarray(np.power.outer(x, _POWERS[: coef.shape[0]]) @ coef, dtype=np.float64)


#: Offsets (normalised time) around the best candidate evaluated as well, against root error.
_ZOOM = np.concatenate([-np.logspace(-10.0, -2.0, 17), np.logspace(-10.0, -2.0, 17)])


def rover_extrema(
    traj: PiecewiseBezier, min_speed_m_s: float = ROVER_MIN_SPEED_M_S
) -> dict[str, tuple[FloatArray, FloatArray]]:
    """Per-segment maxima of the rover quantities, from their critical points (no sampling).

    For each segment (normalised time tau in [0, 1], velocity v, acceleration a, cross
    ``c = x' y'' - y' x''``) the speed ``V``, yaw rate ``|c| / V^2`` and lateral acceleration
    ``|c| / V`` are evaluated where V >= ``min_speed_m_s`` at the roots in [0, 1] of
    ``(V^2)'``, ``c' V^2 - c (V^2)'``, ``2 c' V^2 - c (V^2)'`` (the derivatives of V^2,
    c / V^2 and c^2 / V^2), of ``V^2 - min_speed^2`` (the edge of the evaluated set), at both
    ends and on a 17-point grid. Critical points do not move when the durations are scaled
    uniformly, so these are the maxima of the (guarded) quantities in ``check`` up to root
    accuracy, however narrow a peak is. Returns ``{name: (worst (M,), tau_worst (M,))}``.
    """
    if traj.dim != 2:
        raise ValueError(f"rover quantities need a 2-D trajectory, this one is {traj.dim}-D")
    cp = traj.control_points
    n = cp.shape[1] - 1
    mono = np.einsum("kj,mjd->mkd", monomial_matrix(n), cp)  # ascending in tau
    names = ("speed", "yaw_rate", "lat_acc")
    out = {nm: (np.zeros(cp.shape[0]), np.zeros(cp.shape[0])) for nm in names}
    for k in range(cp.shape[0]):
        h = float(traj.durations[k])
        vx, vy = _pder(mono[k, :, 0]), _pder(mono[k, :, 1])
        ax, ay = _pder(vx), _pder(vy)
        c = _psub(_pmul(vx, ay), _pmul(vy, ax))
        v2 = _padd(_pmul(vx, vx), _pmul(vy, vy))
        dv2, dc = _pder(v2), _pder(c)
        dc_v2, c_dv2 = _pmul(dc, v2), _pmul(c, dv2)
        cands = [_ROVER_GRID, _root_candidates(dv2)]
        cands.append(_root_candidates(_psub(dc_v2, c_dv2)))
        cands.append(_root_candidates(_psub(2.0 * dc_v2, c_dv2)))
        edge = v2.copy()
        edge[0] -= (min_speed_m_s * h) ** 2
        cands.append(_root_candidates(edge))
        tau0 = np.concatenate(cands)
        vals0 = _rover_values(tau0, v2, c, h, min_speed_m_s)
        for nm in names:
            i = int(np.argmax(vals0[nm]))
            best_v, best_t = float(vals0[nm][i]), float(tau0[i])
            for _ in range(2):  # zoom around the best candidate (root error on narrow peaks)
                tz = np.clip(best_t + _ZOOM, 0.0, 1.0)
                vz = _rover_values(tz, v2, c, h, min_speed_m_s)[nm]
                j = int(np.argmax(vz))
                if vz[j] > best_v:
                    best_v, best_t = float(vz[j]), float(tz[j])
            out[nm][0][k] = best_v
            out[nm][1][k] = best_t
    return out


def _rover_values(
    tau: FloatArray, v2: FloatArray, c: FloatArray, h: float, min_speed_m_s: float
) -> dict[str, FloatArray]:
    """Speed, yaw rate and lateral acceleration at normalised times tau of a segment of
    duration h with ``V^2`` and ``v x a`` given as polynomials in tau (ascending)."""
    speed = np.sqrt(np.maximum(polyval01(tau, v2), 0.0)) / h  # m/s
    ct = np.abs(polyval01(tau, c)) / h**3  # |v x a|, m^2/s^3
    # the edge roots sit on V = min speed up to round-off: keep them (conservative)
    ok = speed >= min_speed_m_s * (1.0 - 1e-9)
    sv = np.where(ok, speed, 1.0)
    return {
        "speed": np.asarray(speed, dtype=np.float64),
        "yaw_rate": np.asarray(np.where(ok, ct / (sv * sv), 0.0), dtype=np.float64),
        "lat_acc": np.asarray(np.where(ok, ct / sv, 0.0), dtype=np.float64),
    }
