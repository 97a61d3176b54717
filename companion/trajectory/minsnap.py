"""Minimum-snap (or minimum-jerk) core for fixed durations: one banded solve.

Formulation. Each segment is a polynomial of degree ``2s - 1`` (s = 4 for snap, 3 for jerk)
written in Hermite form by its derivatives of orders ``0..s-1`` at both ends,
so derivatives up to ``s - 1`` are continuous by construction. The cost
``J = sum_k int ||p^(s)(t)||^2 dt`` is then a quadratic form in the joint derivatives whose
Hessian is block-tridiagonal (joints couple only through the segment between them). Minimising
over the free joint derivatives is one symmetric positive definite banded solve (Cholesky:
LAPACK's ``dpbtrf``/``dpbtrs`` from SciPy, as ``scipy.linalg.solveh_banded`` uses them,
bandwidth ``2s - 1``): linear in the number of segments and exact to round-off. At free
joints the optimum is additionally continuous in derivatives ``s .. 2s - 2`` (the
minimum-snap optimality conditions), exactly as MINCO's.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

from companion.trajectory._lapack import banded_cholesky
from companion.trajectory.bezier import FloatArray, hermite, monomial_matrix

__all__ = ["BandedSystem"]


@lru_cache(maxsize=8)
def _basis(s: int) -> tuple[FloatArray, FloatArray]:
    """(H, Qt) for half-order s: P = H @ x_scaled, J = x_scaled^T Qt x_scaled on [0, 1].

    ``x_scaled`` = [D_0 .. D_{s-1} at start, D_0 .. D_{s-1} at end] in normalised time.
    """
    n = 2 * s - 1
    eye = np.eye(2 * s)
    H = hermite(eye[:s], eye[s:], 1.0).control_points.copy()  # (2s, 2s): column = input
    a = monomial_matrix(n) @ H  # monomial coefficients in tau of each input
    k = np.arange(s, n + 1)
    fall = np.array([math.factorial(int(i)) / math.factorial(int(i) - s) for i in k])
    B = a[s:, :] * fall[:, None]  # coefficients of q^(s), powers 0..s-1
    p = np.arange(s)
    hilb = 1.0 / (p[:, None] + p[None, :] + 1.0)
    Qt = B.T @ hilb @ B
    Qt = 0.5 * (Qt + Qt.T)
    H.setflags(write=False)
    Qt.setflags(write=False)
    return H, Qt


def _pair_sources(
    target: NDArray[np.intp], source: NDArray[np.intp], n_targets: int, pad: int
) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """For ``np.bincount(target, weights=v[source])`` with at most two terms per target: the
    first and second source of each target in input order (``pad``, the index of an appended
    zero, where there is none), see :func:`_pair_sum`."""
    first = np.full(n_targets, pad, dtype=np.intp)
    second = np.full(n_targets, pad, dtype=np.intp)
    order = np.argsort(target, kind="stable")
    t_sorted = target[order]
    src_sorted = source[order]
    new = np.ones(t_sorted.shape[0], dtype=bool)
    new[1:] = t_sorted[1:] != t_sorted[:-1]
    first[t_sorted[new]] = src_sorted[new]
    rest = ~new
    if rest.any():
        again = np.zeros(t_sorted.shape[0], dtype=bool)
        again[1:] = rest[1:] & rest[:-1]
        if again.any():
            raise AssertionError("a band entry with more than two terms")  # pragma: no cover
        second[t_sorted[rest]] = src_sorted[rest]
    return first, second


def _pair_sum(v: FloatArray, src: tuple[NDArray[np.intp], NDArray[np.intp]]) -> FloatArray:
    """``v.reshape(-1)[first] + v.reshape(-1)[second]`` with a zero appended to v (equal to
    the ``np.bincount`` sum of at most two terms)."""
    flat = np.concatenate([v.reshape(-1), _ZERO])
    out: FloatArray = flat[src[0]]
    out += flat[src[1]]
    return out


_ZERO = np.zeros(1)


class BandedSystem:
    """Banded minimum-derivative system for a fixed structure (which joint derivatives are
    fixed); ``solve(h)`` can be called repeatedly with new durations."""

    def __init__(self, fixed_mask: NDArray[np.bool_], fixed_vals: FloatArray, s: int) -> None:
        self.s = s
        self.n_joints = fixed_mask.shape[0]
        self.m = self.n_joints - 1
        self.d = fixed_vals.shape[2]
        self.H, self.Qt = _basis(s)
        o = np.tile(np.arange(s), 2).astype(np.float64)
        self.o = o
        self.expo = 1.0 - 2.0 * s + o[:, None] + o[None, :]
        free = ~fixed_mask.reshape(-1)
        self.free = free
        self.nf = int(free.sum())
        fmap = np.full(free.shape[0], -1, dtype=np.int64)
        fmap[free] = np.arange(self.nf)
        self.x0 = np.where(free[:, None], 0.0, fixed_vals.reshape(-1, self.d))
        self.gidx = np.arange(self.m)[:, None] * s + np.arange(2 * s)[None, :]  # (M, 2s)
        fa = fmap[self.gidx]
        ai = fa[:, :, None]
        bj = fa[:, None, :]
        # bandwidth: the widest index span of the free derivatives one segment couples (2s - 1
        # at most; 2s - 3 with every waypoint position fixed, which makes the factorisation
        # about twice as cheap)
        hi_f = np.max(fa, axis=1)
        lo_f = np.min(np.where(fa >= 0, fa, np.iinfo(np.int64).max), axis=1)
        spans = np.where(hi_f >= 0, hi_f - lo_f, 0)
        self.u = max(int(spans.max()) if spans.shape[0] else 0, 1)
        mask = (ai >= 0) & (bj >= 0) & (ai <= bj)
        self.band_mask = mask
        # band storage (LAPACK upper, u + 1 rows) in Fortran order: entry (u + a - b, b) at
        # flat index b * (u + 1) + u + a - b, so that dpbtrf factorises it in place
        self.band_flat = (bj * (self.u + 1) + self.u + ai - bj)[mask]
        self.fa = fa
        self.free_rows = fa >= 0  # (M, 2s)
        rows = fa[self.free_rows]
        self.rhs_index = (rows[:, None] * self.d + np.arange(self.d)[None, :]).reshape(-1)
        self.free_idx = np.flatnonzero(free)
        # flat indices of the free rows' entries (a 1-D scatter is several times faster)
        self._free_flat = (self.free_idx[:, None] * self.d + np.arange(self.d)[None, :]).reshape(-1)
        self.free_rows_idx = np.flatnonzero(self.free_rows.reshape(-1))
        self.band_take = np.flatnonzero(mask.reshape(-1))
        # the same sums as np.bincount over (band_flat, band_take) and (rhs_index, free rows)
        # as two gathers and one addition: every entry has at most two terms (a joint is shared
        # by two segments), and (0 + a) + b == a + b exactly
        self._band_src = _pair_sources(
            self.band_flat, self.band_take, (self.u + 1) * self.nf, self.m * 4 * s * s
        )
        rhs_src = (self.free_rows_idx[:, None] * self.d + np.arange(self.d)[None, :]).reshape(-1)
        self._rhs_src = _pair_sources(
            self.rhs_index, rhs_src, self.nf * self.d, self.m * 2 * s * self.d
        )
        # exponent index of each Q entry: h^(1-2s+o_a+o_b), exponents 1-2s .. -1
        self.expo_idx = (self.expo - (1.0 - 2.0 * s)).astype(np.intp)
        # band storage entry (r, j) holds A[j - (u - r), j]: row index per entry for scaling
        band_i = np.arange(self.nf)[None, :] - (self.u - np.arange(self.u + 1))[:, None]
        self.band_i = np.clip(band_i, 0, max(self.nf - 1, 0))
        # the fixed part x0 per segment window, restricted to the window columns it is not
        # zero in (positions, fixed boundary derivatives)
        x0_windows = np.concatenate(
            [self.x0[:-s].reshape(self.m, s, self.d), self.x0[s:].reshape(self.m, s, self.d)],
            axis=1,
        )
        self._x0_cols = np.flatnonzero(np.any(x0_windows != 0.0, axis=(0, 2)))
        self._x0_windows = np.ascontiguousarray(x0_windows[:, self._x0_cols, :])
        self._factor: tuple[FloatArray, FloatArray] | None = None
        self._last: tuple[FloatArray, FloatArray, FloatArray] | None = None  # h, hp, Q
        self._windows: tuple[FloatArray, FloatArray] | None = None  # x, windows(x)
        #: the last solve without a data term: (h, x, cost or NaN)
        self._solved: tuple[FloatArray, FloatArray, float] | None = None

    def _prepare(self, h: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(hp, Q) for durations h: hp = h^o (M, 2s), Q_k = h^(1-2s) S Qt S, S = diag(hp)."""
        last = self._last
        if last is not None and last[0] is h:
            return last[1], last[2]
        s = self.s
        m = h.shape[0]
        hp = np.empty((m, 2 * s))
        hp[:, 0] = 1.0
        for i in range(1, s):
            hp[:, i] = hp[:, i - 1] * h
        hp[:, s:] = hp[:, :s]
        # h^e for e = 1-2s .. -1, then gather per Q entry
        pw = np.empty((m, 2 * s - 1))
        pw[:, -1] = 1.0 / h
        for i in range(2 * s - 3, -1, -1):
            pw[:, i] = pw[:, i + 1] * pw[:, -1]
        Q = pw[:, self.expo_idx]
        Q *= self.Qt
        self._last = (h, hp, Q)
        return hp, Q

    def windows(self, x: FloatArray) -> FloatArray:
        """Per-segment joint derivatives (M, 2s, d) of x (n_joints * s, d) (cached for the
        last solution returned by :meth:`solve`; treat as read-only)."""
        cached = self._windows
        if cached is not None and cached[0] is x:
            return cached[1]
        s, m = self.s, self.m
        d = x.shape[1]
        return np.concatenate([x[:-s].reshape(m, s, d), x[s:].reshape(m, s, d)], axis=1)

    def powers(self, h: FloatArray, r: int) -> FloatArray:
        """h^(o_a - r) for the 2s Hermite inputs, shape (M, 2s)."""
        hp, _ = self._prepare(h)
        return hp if r == 0 else hp / h[:, None] ** r

    def solve(
        self,
        h: FloatArray,
        fit: tuple[FloatArray, FloatArray] | None = None,
        with_cost: bool = True,
    ) -> tuple[FloatArray, float]:
        """Joint derivatives x (n_joints * s, d, read-only) and cost J for durations h (M,)
        (NaN without ``with_cost``).

        ``fit = (R, g)`` adds a per-segment quadratic data term ``x_k^T R_k x_k - 2 g_k . x_k``
        (R (M, 2s, 2s), g (M, 2s, d)) to the objective (same band structure); the returned
        cost is the derivative cost J alone."""
        last = self._solved
        if fit is None and last is not None and last[0].shape == h.shape and (
            np.array_equal(last[0], h)
        ):
            # the same durations as the last solve (e.g. the refinement's result, checked
            # again): the same solution; its factorisation is still the current one
            x, cost = last[1], last[2]
            if with_cost and math.isnan(cost):
                cost = self.cost(x, h)
                self._solved = (last[0], x, cost)
            return x, cost if with_cost else math.nan
        d = self.d
        _, Q = self._prepare(h)
        A = Q if fit is None else Q + fit[0]
        x = self.x0.copy()
        if self.nf:
            # A x0 per segment from the window columns where x0 is not zero (the zero terms
            # add nothing: the same sums)
            cols = self._x0_cols
            yk = np.matmul(A[:, :, cols], self._x0_windows)
            if fit is not None:
                yk -= fit[1]
            rhs = -_pair_sum(yk, self._rhs_src).reshape(self.nf, d)
            ab = _pair_sum(A, self._band_src).reshape(self.nf, self.u + 1).T
            # Jacobi scaling for conditioning across very different durations
            diag = ab[self.u]
            if np.any(diag <= 0.0):
                raise ValueError(
                    "the trajectory is under-determined: some free derivative does not affect "
                    "the cost (fix more boundary derivatives)"
                )
            sc = 1.0 / np.sqrt(diag)
            ab *= sc[self.band_i]
            ab *= sc[None, :]
            pbtrf, pbtrs = banded_cholesky()  # LAPACK (SciPy's wrapper)
            cb, info = pbtrf(ab, lower=0, overwrite_ab=1)
            if info != 0:
                raise ValueError(
                    "the trajectory problem is singular (under-determined free derivatives)"
                )
            self._factor = (cb, sc)
            z, info = pbtrs(cb, rhs * sc[:, None], lower=0)
            x.reshape(-1)[self._free_flat] = (z * sc[:, None]).reshape(-1)
        xk = self.windows(x)
        cost = float(np.einsum("mad,mad->", xk, Q @ xk)) if with_cost else math.nan
        x.setflags(write=False)  # its windows are cached
        self._windows = (x, xk)
        self._solved = None if fit is not None else (h.copy(), x, cost)
        return x, cost

    def cost(self, x: FloatArray, h: FloatArray) -> float:
        """Cost J of the joint derivatives x (as :meth:`solve` returns) for durations h."""
        _, Q = self._prepare(h)
        xk = self.windows(x)
        return float(np.einsum("mad,mad->", xk, Q @ xk))

    def adjoint(self, g_full: FloatArray) -> FloatArray:
        """lambda = A^-1 g_F for the last factorised system, scattered to all joint
        derivatives (zeros at fixed ones); g_full has shape (n_joints * s, d)."""
        lam = np.zeros_like(g_full)
        if self.nf and self._factor is not None:
            cb, sc = self._factor
            pbtrs = banded_cholesky()[1]
            z, _ = pbtrs(cb, np.take(g_full, self.free_idx, axis=0) * sc[:, None], lower=0)
            lam.reshape(-1)[self._free_flat] = (z * sc[:, None]).reshape(-1)
        return lam

    def dq(self, h: FloatArray) -> FloatArray:
        """dQ_k / dh_k (M, 2s, 2s)."""
        _, Q = self._prepare(h)
        return np.asarray(Q * self.expo[None] / h[:, None, None], dtype=np.float64)

    def dq_x(self, x: FloatArray, h: FloatArray) -> FloatArray:
        """(dQ_k / dh_k) x_k per segment, (M, 2s, d)."""
        return np.asarray(self.dq(h) @ self.windows(x), dtype=np.float64)

    def cost_grad(self, x: FloatArray, h: FloatArray, dqx: FloatArray | None = None) -> FloatArray:
        """dJ*/dh (M,) at the optimum x (envelope theorem: fixed joint derivatives);
        ``dqx``: ``dq_x(x, h)`` if already computed."""
        if dqx is None:
            dqx = self.dq_x(x, h)
        return np.asarray(np.einsum("mad,mad->m", self.windows(x), dqx), dtype=np.float64)

    def control_points(self, x: FloatArray, h: FloatArray) -> FloatArray:
        """Bezier control points (M, 2s, d) of the segments."""
        xk = self.windows(x) * self.powers(h, 0)[:, :, None]
        return np.asarray(self.H @ xk, dtype=np.float64)

