"""Bezier segments and piecewise Bezier trajectories (pure numpy).

A degree-``n`` segment of duration ``h`` (seconds) is
``B(t) = sum_i P_i b_{i,n}(t / h)`` with Bernstein polynomials ``b_{i,n}`` and control points
``P`` of shape ``(n + 1, d)``. Time ``t`` is local to the segment, in seconds, ``0 <= t <= h``.
The control points are the stored and exchanged form (the curve lies in their convex hull, which
gives cheap bounds); hot loops evaluate per-segment monomial coefficients with Horner's rule.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Sequence
from math import comb, factorial
from typing import Any, overload

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]

__all__ = [
    "Bezier",
    "PiecewiseBezier",
    "ScalarEvaluator",
    "hermite",
    "hermite_batch",
    "horner_fn",
    "monomial_matrix",
]


def _as_points(control_points: ArrayLike) -> FloatArray:
    pts = np.array(control_points, dtype=np.float64)
    if pts.ndim == 1:
        pts = pts[:, None]
    if pts.ndim != 2 or pts.shape[0] < 1 or pts.shape[1] < 1:
        raise ValueError(
            f"Bezier control points must have shape (n+1, d) with n >= 0, d >= 1; got {pts.shape}"
        )
    if not np.all(np.isfinite(pts)):
        raise ValueError("Bezier control points must be finite (found NaN or inf)")
    pts.setflags(write=False)
    return pts


def _as_duration(duration: float) -> float:
    h = float(duration)
    if not np.isfinite(h) or h <= 0.0:
        raise ValueError(f"segment duration must be a finite positive number of seconds, got {h}")
    return h


def _diff_points(points: FloatArray, order: int, duration: float) -> FloatArray:
    """Control points of the ``order``-th time derivative (degree ``n - order``)."""
    n = points.shape[0] - 1
    if order > n:
        return np.zeros((1, points.shape[1]))
    pts = points
    for k in range(order):
        pts = (n - k) / duration * np.diff(pts, axis=0)
    return pts


def monomial_matrix(n: int) -> FloatArray:
    """Matrix ``A`` with ``a = A @ P``: monomial coefficients in ``s = t/h`` (ascending)."""
    A = np.zeros((n + 1, n + 1))
    for k in range(n + 1):
        for i in range(k + 1):
            A[k, i] = comb(n, k) * comb(k, i) * (-1.0) ** (k - i)
    return A


def _elevation_matrix(n: int) -> FloatArray:
    """Matrix ``E`` ((n+2) x (n+1)) with ``P' = E @ P`` for degree elevation n -> n+1."""
    E = np.zeros((n + 2, n + 1))
    for i in range(n + 2):
        a = i / (n + 1)
        if i <= n:
            E[i, i] += 1.0 - a
        if i >= 1:
            E[i, i - 1] += a
    return E


class Bezier:
    """One Bezier segment: ``control_points`` (n+1, d) and ``duration`` h > 0 in seconds.

    Immutable: the control points are stored as a read-only float64 array.
    """

    __slots__ = ("_duration", "_points")

    def __init__(self, control_points: ArrayLike, duration: float) -> None:
        self._points = _as_points(control_points)
        self._duration = _as_duration(duration)

    @property
    def control_points(self) -> FloatArray:
        """Control points, shape (n+1, d), read-only."""
        return self._points

    @property
    def duration(self) -> float:
        """Segment duration h in seconds."""
        return self._duration

    @property
    def degree(self) -> int:
        """Polynomial degree n."""
        return int(self._points.shape[0] - 1)

    @property
    def dim(self) -> int:
        """Dimension d of the curve."""
        return int(self._points.shape[1])

    def __repr__(self) -> str:
        return f"Bezier(degree={self.degree}, dim={self.dim}, duration={self._duration:g})"

    @overload
    def evaluate(self, t: float, order: int = 0) -> FloatArray: ...
    @overload
    def evaluate(self, t: ArrayLike, order: int = 0) -> FloatArray: ...

    def evaluate(self, t: ArrayLike, order: int = 0) -> FloatArray:
        """Value of the ``order``-th time derivative at local time ``t`` (s), by de Casteljau.

        Scalar ``t`` -> shape (d,); 1-D array ``t`` -> shape (len(t), d). Times outside
        [0, duration] extrapolate the polynomial.
        """
        if order < 0:
            raise ValueError(f"derivative order must be >= 0, got {order}")
        t_arr = np.asarray(t, dtype=np.float64)
        scalar = t_arr.ndim == 0
        tt = np.atleast_1d(t_arr).reshape(-1)
        pts = _diff_points(self._points, order, self._duration)
        s = (tt / self._duration)[:, None, None]
        work = np.broadcast_to(pts, (tt.shape[0], *pts.shape)).copy()
        for m in range(pts.shape[0] - 1, 0, -1):
            work = (1.0 - s[:, :, :]) * work[:, :m, :] + s * work[:, 1 : m + 1, :]
        out = work[:, 0, :]
        return out[0] if scalar else out

    def derivative(self) -> Bezier:
        """Time derivative: degree n-1, control points ``n/h (P_{i+1} - P_i)``.

        The derivative of a degree-0 segment is the zero segment of degree 0.
        """
        return Bezier(_diff_points(self._points, 1, self._duration), self._duration)

    def split(self, tau: float) -> tuple[Bezier, Bezier]:
        """Split at local time ``tau`` (seconds, 0 < tau < duration) into two segments.

        Returns ``(left, right)`` with durations ``tau`` and ``duration - tau``; together they
        trace exactly the same curve with the same time parametrisation.
        """
        tau_f = float(tau)
        if not (0.0 < tau_f < self._duration):
            raise ValueError(
                f"split time must be strictly inside (0, {self._duration:g}) s, got {tau_f}"
            )
        s = tau_f / self._duration
        n = self.degree
        work = self._points.copy()
        left = [work[0].copy()]
        right = [work[n].copy()]
        for m in range(n, 0, -1):
            work = (1.0 - s) * work[:m] + s * work[1 : m + 1]
            left.append(work[0].copy())
            right.append(work[m - 1].copy())
        return Bezier(np.array(left), tau_f), Bezier(np.array(right[::-1]), self._duration - tau_f)

    def elevate(self) -> Bezier:
        """Same curve expressed with degree n+1 (one more control point)."""
        return Bezier(_elevation_matrix(self.degree) @ self._points, self._duration)

    def to_monomial(self) -> FloatArray:
        """Monomial coefficients ``c`` (n+1, d), ascending: ``B(t) = sum_k c[k] t**k``.

        ``t`` is local time in seconds (0 at the segment start).
        """
        n = self.degree
        a = monomial_matrix(n) @ self._points
        scale = self._duration ** -np.arange(n + 1, dtype=np.float64)
        return np.asarray(a * scale[:, None], dtype=np.float64)

    def hull_bound(self, order: int = 0) -> float:
        """Upper bound of ``|d^order B / dt^order|`` (Euclidean norm) over the segment.

        From the convex-hull property: the maximum norm of the derivative's control points.
        """
        pts = _diff_points(self._points, order, self._duration)
        return float(np.max(np.linalg.norm(pts, axis=1)))

    @classmethod
    def hermite(cls, start_derivs: ArrayLike, end_derivs: ArrayLike, duration: float) -> Bezier:
        """See :func:`hermite`."""
        return hermite(start_derivs, end_derivs, duration)


def hermite(start_derivs: ArrayLike, end_derivs: ArrayLike, duration: float) -> Bezier:
    """The unique Bezier of degree ``k0 + k1 - 1`` matching boundary derivatives.

    ``start_derivs`` (k0, d): rows are position, velocity, acceleration, ... at t = 0;
    ``end_derivs`` (k1, d): the same at t = duration (seconds). k0, k1 >= 1. The first k0
    control points follow from the start derivatives, the last k1 from the end ones
    (for a cubic: ``P1 = P0 + v0 h/3``, ``P2 = P3 - v1 h/3``).
    """
    h = _as_duration(duration)
    s0 = _as_points(start_derivs)
    s1 = _as_points(end_derivs)
    if s0.shape[1] != s1.shape[1]:
        raise ValueError(
            f"hermite: start and end derivatives have different dimensions "
            f"({s0.shape[1]} vs {s1.shape[1]})"
        )
    k0, k1 = s0.shape[0], s1.shape[0]
    n = k0 + k1 - 1
    pts = np.zeros((n + 1, s0.shape[1]))
    for j in range(k0):
        # B^(j)(0) = n!/(n-j)! h^-j sum_i (-1)^(j-i) C(j,i) P_i
        acc = s0[j] * h**j * factorial(n - j) / factorial(n)
        for i in range(j):
            acc = acc - (-1.0) ** (j - i) * comb(j, i) * pts[i]
        pts[j] = acc
    for j in range(k1):
        # B^(j)(h) = n!/(n-j)! h^-j sum_i (-1)^i C(j,i) P_{n-i}
        acc = s1[j] * h**j * factorial(n - j) / factorial(n)
        for i in range(j):
            acc = acc - (-1.0) ** i * comb(j, i) * pts[n - i]
        pts[n - j] = (-1.0) ** j * acc
    return Bezier(pts, h)


def hermite_batch(start_derivs: ArrayLike, end_derivs: ArrayLike,
                  durations: ArrayLike) -> PiecewiseBezier:
    """:func:`hermite` for M segments at once, joined as a :class:`PiecewiseBezier`:
    ``start_derivs`` (M, k0, d), ``end_derivs`` (M, k1, d), ``durations`` (M,) [s]. Each
    segment's control points are bit for bit those of ``hermite`` (the same floating-point
    operations in the same order, on whole arrays instead of one segment at a time)."""
    s0 = np.asarray(start_derivs, dtype=np.float64)
    s1 = np.asarray(end_derivs, dtype=np.float64)
    if s0.ndim != 3 or s1.ndim != 3 or s0.shape[0] != s1.shape[0] or s0.shape[2] != s1.shape[2]:
        raise ValueError(f"hermite_batch: derivative shapes {s0.shape} and {s1.shape} do not "
                         "match (M, k0, d) and (M, k1, d)")
    if not (np.all(np.isfinite(s0)) and np.all(np.isfinite(s1))):
        raise ValueError("hermite_batch: derivatives must be finite")
    hs = [_as_duration(float(x)) for x in np.asarray(durations, dtype=np.float64).reshape(-1)]
    if len(hs) != s0.shape[0]:
        raise ValueError(f"hermite_batch: {s0.shape[0]} segments but {len(hs)} durations")
    k0, k1 = s0.shape[1], s1.shape[1]
    n = k0 + k1 - 1
    pts = np.zeros((s0.shape[0], n + 1, s0.shape[2]))
    for j in range(k0):
        hj = np.array([h**j for h in hs])[:, None]  # Python's float power, as in `hermite`
        acc = s0[:, j] * hj * factorial(n - j) / factorial(n)
        for i in range(j):
            acc = acc - (-1.0) ** (j - i) * comb(j, i) * pts[:, i]
        pts[:, j] = acc
    for j in range(k1):
        hj = np.array([h**j for h in hs])[:, None]
        acc = s1[:, j] * hj * factorial(n - j) / factorial(n)
        for i in range(j):
            acc = acc - (-1.0) ** i * comb(j, i) * pts[:, n - i]
        pts[:, n - j] = (-1.0) ** j * acc
    return PiecewiseBezier.from_control_points(pts, np.array(hs))


class PiecewiseBezier:
    """A trajectory made of Bezier segments joined end to end in time.

    ``segments``: a non-empty sequence of :class:`Bezier` of equal dimension d (segments of
    lower degree are degree-elevated to the highest degree, which leaves the curve unchanged).
    ``yaw``: optional 1-D channel (d = 1, yaw in rad, stored unwrapped) with the same segment
    durations. Time ``t`` is global, in seconds from the start, ``0 <= t <= duration``; times
    outside are clamped to the ends (the trajectory holds its end state).
    """

    __slots__ = ("_breaks", "_coeff_cache", "_cp", "_durations", "_scalar_evals", "_segments",
                 "_yaw")

    def __init__(self, segments: Sequence[Bezier], yaw: PiecewiseBezier | None = None) -> None:
        segs = list(segments)
        if not segs:
            raise ValueError("a PiecewiseBezier needs at least one segment")
        dim = segs[0].dim
        for k, seg in enumerate(segs):
            if not isinstance(seg, Bezier):
                raise TypeError(f"segment {k} is not a Bezier")
            if seg.dim != dim:
                raise ValueError(f"segment {k} has dimension {seg.dim}, segment 0 has {dim}")
        n = max(seg.degree for seg in segs)
        cps = []
        for seg in segs:
            while seg.degree < n:
                seg = seg.elevate()
            cps.append(seg.control_points)
        cp = np.stack(cps)
        durations = np.array([seg.duration for seg in segs], dtype=np.float64)
        self._init_arrays(cp, durations, yaw)

    @classmethod
    def from_control_points(
        cls, control_points: ArrayLike, durations: ArrayLike, yaw: PiecewiseBezier | None = None
    ) -> PiecewiseBezier:
        """Build from stacked control points (M, n+1, d) and durations (M,) in seconds."""
        cp = np.array(control_points, dtype=np.float64)
        if cp.ndim != 3 or cp.shape[0] < 1 or cp.shape[1] < 1 or cp.shape[2] < 1:
            raise ValueError(f"control points must have shape (M, n+1, d); got {cp.shape}")
        if not np.all(np.isfinite(cp)):
            raise ValueError("control points must be finite (found NaN or inf)")
        h = np.array(durations, dtype=np.float64).reshape(-1)
        if h.shape[0] != cp.shape[0]:
            raise ValueError(f"{cp.shape[0]} segments but {h.shape[0]} durations")
        obj = cls.__new__(cls)
        obj._init_arrays(cp, h, yaw)
        return obj

    def _init_arrays(
        self, cp: FloatArray, durations: FloatArray, yaw: PiecewiseBezier | None
    ) -> None:
        bad = ~np.isfinite(durations) | (durations <= 0.0)
        if np.any(bad):
            k = int(np.flatnonzero(bad)[0])
            raise ValueError(f"segment {k} has duration {durations[k]}; it must be positive")
        cp.setflags(write=False)
        durations.setflags(write=False)
        breaks = np.concatenate(([0.0], np.cumsum(durations)))
        breaks.setflags(write=False)
        self._cp = cp
        self._durations = durations
        self._breaks = breaks
        self._segments: tuple[Bezier, ...] | None = None
        self._coeff_cache: dict[int, FloatArray] = {}
        self._scalar_evals: dict[int, ScalarEvaluator] = {}
        if yaw is not None:
            if not isinstance(yaw, PiecewiseBezier):
                raise TypeError("yaw must be a PiecewiseBezier (1-D) or None")
            if yaw.dim != 1:
                raise ValueError(f"the yaw channel must be 1-D, got dimension {yaw.dim}")
            if yaw.yaw is not None:
                raise ValueError("the yaw channel cannot itself carry a yaw channel")
            if yaw.durations.shape != durations.shape or not np.allclose(
                yaw.durations, durations, rtol=1e-12, atol=0.0
            ):
                raise ValueError("the yaw channel must have the same segment durations")
        self._yaw = yaw

    # ----------------------------------------------------------------- properties
    @property
    def segments(self) -> tuple[Bezier, ...]:
        """The segments as :class:`Bezier` objects (all of the same degree)."""
        if self._segments is None:
            self._segments = tuple(
                Bezier(self._cp[k], float(self._durations[k])) for k in range(self._cp.shape[0])
            )
        return self._segments

    @property
    def control_points(self) -> FloatArray:
        """Stacked control points, shape (M, n+1, d), read-only."""
        return self._cp

    @property
    def durations(self) -> FloatArray:
        """Segment durations (M,) in seconds, read-only."""
        return self._durations

    @property
    def breaks(self) -> FloatArray:
        """Segment start times (M+1,) in seconds: 0, h0, h0+h1, ..., duration."""
        return self._breaks

    @property
    def duration(self) -> float:
        """Total duration in seconds."""
        return float(self._breaks[-1])

    @property
    def degree(self) -> int:
        """Common polynomial degree of the segments."""
        return int(self._cp.shape[1] - 1)

    @property
    def dim(self) -> int:
        """Dimension d (2 for a rover, 3 for a multirotor, 1 for a yaw channel)."""
        return int(self._cp.shape[2])

    @property
    def num_segments(self) -> int:
        """Number of segments M."""
        return int(self._cp.shape[0])

    @property
    def yaw(self) -> PiecewiseBezier | None:
        """The yaw channel (1-D, rad, unwrapped) or None."""
        return self._yaw

    def with_yaw(self, yaw: PiecewiseBezier | None) -> PiecewiseBezier:
        """A copy carrying another yaw channel."""
        return PiecewiseBezier.from_control_points(self._cp, self._durations, yaw)

    def __len__(self) -> int:
        return self.num_segments

    def __repr__(self) -> str:
        return (
            f"PiecewiseBezier(segments={self.num_segments}, degree={self.degree}, "
            f"dim={self.dim}, duration={self.duration:g}, yaw={self._yaw is not None})"
        )

    # ----------------------------------------------------------------- evaluation
    def _coeffs(self, order: int) -> FloatArray:
        """Horner coefficients (M, n+1-order, d) of the order-th derivative in s = t_local/h."""
        c = self._coeff_cache.get(order)
        if c is None:
            n = self.degree
            a = np.einsum("kj,mjd->mkd", monomial_matrix(n), self._cp)
            k = np.arange(order, n + 1)
            fall = np.array([factorial(int(i)) / factorial(int(i) - order) for i in k])
            scale = self._durations[:, None] ** (-float(order))
            c = a[:, order:, :] * fall[None, :, None] * scale[:, :, None]
            c.setflags(write=False)
            self._coeff_cache[order] = c
        return c

    def segment_index(self, t: ArrayLike) -> NDArray[np.intp]:
        """Index of the segment containing each (clamped) time ``t`` (s)."""
        tt = np.clip(np.asarray(t, dtype=np.float64), 0.0, self.duration)
        idx = np.searchsorted(self._breaks, tt, side="right") - 1
        return np.clip(idx, 0, self.num_segments - 1).astype(np.intp)

    @overload
    def evaluate(self, t: float, order: int = 0) -> FloatArray: ...
    @overload
    def evaluate(self, t: ArrayLike, order: int = 0) -> FloatArray: ...

    def evaluate(self, t: ArrayLike, order: int = 0) -> FloatArray:
        """``order``-th time derivative at global time(s) ``t`` (s).

        Scalar -> (d,); 1-D array -> (len(t), d). Times are clamped to [0, duration]; a
        NaN time raises ValueError. At a joint the later segment is used.
        """
        if order < 0:
            raise ValueError(f"derivative order must be >= 0, got {order}")
        t_arr = np.asarray(t, dtype=np.float64)
        scalar = t_arr.ndim == 0
        tt = np.atleast_1d(t_arr).reshape(-1)
        if np.any(np.isnan(tt)):
            raise ValueError("trajectory evaluated at a NaN time")
        if order > self.degree:
            out = np.zeros((tt.shape[0], self.dim))
            return out[0] if scalar else out
        idx, s = self._locate(tt)
        out = self._horner(order, idx, s)
        return out[0] if scalar else out

    def evaluate_orders(self, t: ArrayLike, orders: tuple[int, ...]) -> list[FloatArray]:
        """:meth:`evaluate` of a 1-D array of times for each of ``orders`` (the segment lookup
        shared; the same values), each (len(t), d)."""
        tt = np.asarray(t, dtype=np.float64).reshape(-1)
        if np.any(np.isnan(tt)):
            raise ValueError("trajectory evaluated at a NaN time")
        idx, s = self._locate(tt)
        return [
            np.zeros((tt.shape[0], self.dim)) if r > self.degree else self._horner(r, idx, s)
            for r in orders
        ]

    def _locate(self, tt: FloatArray) -> tuple[NDArray[np.intp], FloatArray]:
        """Segment index and normalised time (N, 1) of each (clamped) time."""
        tt = np.clip(tt, 0.0, self.duration)
        idx = np.searchsorted(self._breaks, tt, side="right") - 1
        np.clip(idx, 0, self.num_segments - 1, out=idx)
        s = ((tt - self._breaks[idx]) / self._durations[idx])[:, None]
        return idx, s

    def _horner(self, order: int, idx: NDArray[np.intp], s: FloatArray) -> FloatArray:
        """Horner with one (N, d) gather per coefficient (no (N, degree + 1, d) copy); rows
        gathered with np.take and s widened to (N, d) (both several times faster than fancy
        indexing and a broadcast column here; the same values)."""
        c = self._coeffs_by_power(order)
        out: FloatArray = np.take(c[-1], idx, axis=0)
        if c.shape[0] > 1:
            sw = np.repeat(s, out.shape[1], axis=1)
            for k in range(c.shape[0] - 2, -1, -1):
                out *= sw
                out += np.take(c[k], idx, axis=0)
        return out

    def _coeffs_by_power(self, order: int) -> FloatArray:
        """:meth:`_coeffs` laid out (power, segment, dim), contiguous (cached)."""
        key = -1 - order
        c = self._coeff_cache.get(key)
        if c is None:
            c = np.ascontiguousarray(self._coeffs(order).transpose(1, 0, 2))
            c.setflags(write=False)
            self._coeff_cache[key] = c
        return c

    def scalar_evaluator(self, max_order: int = 2) -> ScalarEvaluator:
        """Fast evaluator of this trajectory and its first ``max_order`` derivatives at one time
        (for per-cycle loops; same results as :meth:`evaluate`). Cached per ``max_order``."""
        ev = self._scalar_evals.get(max_order)
        if ev is None:
            ev = self._scalar_evals[max_order] = ScalarEvaluator(self, max_order)
        return ev

    def hull_bounds(self, order: int = 0) -> FloatArray:
        """Per-segment convex-hull upper bounds (M,) of ``|d^order p / dt^order|``."""
        pts = self._cp
        n = self.degree
        if order > n:
            return np.zeros(self.num_segments)
        for k in range(order):
            pts = (n - k) / self._durations[:, None, None] * np.diff(pts, axis=1)
        return np.asarray(np.max(np.linalg.norm(pts, axis=2), axis=1), dtype=np.float64)


_HornerFn = Callable[[float, tuple[float, ...]], list[float]]
_HORNER_FNS: dict[tuple[int, ...], _HornerFn] = {}


def horner_fn(lengths: tuple[int, ...]) -> _HornerFn:
    """``f(s, c)`` -> Horner value of each row at ``s``, rows of ``lengths`` descending
    coefficients concatenated in ``c``. Straight-line code (generated once per layout; its source
    holds only indices, no data) runs ~2x faster than a Python loop; a loop for huge layouts."""
    fn = _HORNER_FNS.get(lengths)
    if fn is not None:
        return fn
    if max(lengths) > 32 or len(lengths) > 256:

        def loop(s: float, c: tuple[float, ...]) -> list[float]:
            out, off = [], 0
            for n in lengths:
                acc = 0.0
                for k in range(off, off + n):
                    acc = acc * s + c[k]
                out.append(acc)
                off += n
            return out

        fn = loop
    else:
        exprs, off = [], 0
        for n in lengths:
            e = f"c[{off}]"
            for k in range(off + 1, off + n):
                e = f"({e}) * s + c[{k}]"
            exprs.append(e)
            off += n
        namespace: dict[str, Any] = {}
        exec("def horner(s, c):\n    return [" + ", ".join(exprs) + "]\n", namespace)
        fn = namespace["horner"]
    _HORNER_FNS[lengths] = fn
    return fn


class ScalarEvaluator:
    """Value and derivatives 0..``max_order`` of a :class:`PiecewiseBezier` at one time.

    Same results as ``traj.evaluate(t, k)`` for k = 0..max_order (clamping to [0, duration],
    later segment at a joint, zeros above the degree, ValueError on a NaN time), at a fraction
    of its cost for a single time: per segment the Horner coefficients of every derivative (in
    the normalised segment time s = t_local / h, as ``evaluate`` uses them) are kept as Python
    floats, and one call is a segment lookup plus unrolled Horner in plain float arithmetic (no
    numpy dispatch; as fast as a precomputed per-segment matrix product even when an array is
    wanted, and twice as fast for floats). Get one with :meth:`PiecewiseBezier.scalar_evaluator`
    (cached per trajectory).
    """

    __slots__ = ("_breaks", "_coef", "_duration", "_h", "_horner", "_last", "_shape", "dim",
                 "max_order")

    def __init__(self, traj: PiecewiseBezier, max_order: int) -> None:
        if max_order < 0:
            raise ValueError(f"derivative order must be >= 0, got {max_order}")
        self.max_order = max_order
        self.dim = traj.dim
        self._shape = (max_order + 1, self.dim)
        self._breaks = [float(b) for b in traj.breaks]
        self._duration = self._breaks[-1]
        self._h = [float(h) for h in traj.durations]
        self._last = traj.num_segments - 1
        zero = (0.0,)
        per_order = [
            traj._coeffs(k).tolist() if k <= traj.degree else None for k in range(max_order + 1)
        ]
        # per segment: the descending Horner coefficients of order k = 0..max_order, dim
        # j = 0..d-1, concatenated (row lengths: n+1-k, or 1 for a zero row above the degree)
        lengths: list[int] = []
        self._coef: list[tuple[float, ...]] = []
        for i in range(self._last + 1):
            flat: list[float] = []
            for c in per_order:
                for j in range(self.dim):
                    row = zero if c is None else [c[i][k][j] for k in range(len(c[i]) - 1, -1, -1)]
                    flat += row
                    if i == 0:
                        lengths.append(len(row))
            self._coef.append(tuple(flat))
        self._horner = horner_fn(tuple(lengths))

    def values(self, t: float) -> list[float]:
        """Flat list of (max_order+1) * dim floats at global time ``t`` [s]: order-major, i.e.
        ``[p_0 .. p_{d-1}, v_0 .. v_{d-1}, a_0, ...]`` (SI units of the trajectory)."""
        b = self._breaks
        if t != t:
            raise ValueError("trajectory evaluated at a NaN time")
        if t <= 0.0:
            t = 0.0
        elif t >= self._duration:
            t = self._duration
        i = bisect_right(b, t) - 1
        if i > self._last:
            i = self._last
        return self._horner((t - b[i]) / self._h[i], self._coef[i])

    def __call__(self, t: float) -> FloatArray:
        """(max_order+1, dim) array: row k is ``evaluate(t, k)``."""
        return np.array(self.values(t)).reshape(self._shape)
