"""Reference shaping for the tilt limit: a reference that asks for more horizontal thrust than
the tilt limit allows is bent, ahead of time, into one the vehicle can fly.

Where the plan's reference needs a thrust vector tilted past the limit (a lighter vehicle than
told has more drag per mass; wind; a user's own fast reference), a controller that only reacts
falls behind while it is held at the limit and then has to catch up, again at the limit. The
error that leaves is several times what the limit costs: the least horizontal RMS any
controller can reach (perfect knowledge, no lag) is often a few centimetres where the reacting
law is off by 0.1-0.2 m (BENCHMARKS.md, "The tilt limit: what it costs").

`ShapedReference` adds a smooth correction delta(t) (horizontal, NED) to the reference. delta is
a uniform quintic B-spline on the reference's own clock (knots every `knot_s`): any coefficients
give a reference continuous through snap, so a correction never steps the feed-forward. Every
knot the coefficients of the next `horizon_s` are chosen by a small QP,

    minimise   sum_k |delta(t_k)|^2 + w2 |delta''(t_k)|^2 + w3 |delta'''(t_k)|^2
    subject to n_k . (a_k + delta''(t_k) + (D/m) (v_k + delta'(t_k)) - d) <= (g - a_z,k) tan(tilt)

over samples t_k of the horizon: a (acceleration), v (velocity) and a_z from the reference;
D/m the drag per mass and d the horizontal disturbance acceleration [m/s^2] the controller
estimates; n_k the direction of the reference's own demand (the cone, linearised where it
binds); tilt the limit less a margin for the feedback. The coefficients already in use stay as
they are, so the correction is continuous across solves. Where the whole horizon is within the
limit and no correction is under way the reference is passed through unchanged (the same
floating-point values), so a feasible flight is flown as before.

Frames: NED, SI units. Time: the reference's own clock [s].
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from companion.flatness.reference import Reference

FloatArray = npt.NDArray[np.float64]
SLACK_WEIGHT = 1e4  # [1/(m/s^2)^2 per m^2]: the constraint's slack against |delta|^2
SLACK_RAMP_S = 1.0  # [s] see `ShapedReference._slack_w`
DEGREE = 5  # quintic: delta is continuous through snap (4th derivative continuous)


@dataclass(frozen=True)
class ShapingConfig:
    """Shaping parameters.

    horizon_s: how far ahead each solve looks [s]; knot_s: B-spline knot spacing [s] (a solve
    every knot); sample_s: spacing of the constraint samples [s]; margin_rad: the tilt left to
    the feedback [rad] (figure-8 at 6 m/s, 0.8 kg against 45 deg, with the jerk term: mock
    attitude 0.077 m with 1 deg, 0.088 with 2, 0.108 with 3, rates 0.058 / 0.079 / 0.119;
    real PX4, medians of three, attitude 0.114 with 1 deg against 0.143 with 2, rates 0.124
    against 0.120; the bend itself is error from the plan, and a wider margin bends more;
    session 21's 3 deg also bent windy campaign plans the vehicle would have flown);
    smooth_weight: w2, the weight of |delta''|^2 [s^4]; jerk_weight: w3, the
    weight of |delta'''|^2 [s^6]: without it a bend doubled the reference's jerk (light
    figure-8, 15 -> 30 m/s^3), which rates mode flies as body rates: on real PX4 the roll rate
    saturated at 220 deg/s and one flight of six fell 1.5 m behind; with 1e-3 the jerk stays
    the plan's and the mock's light figure-8 improves (at a 2 deg margin: rates 0.119 ->
    0.079 m, attitude 0.091 -> 0.088; nominal 1 kg rates 0.035 -> 0.024);
    max_correction_m: a solution that moves the reference further than this [m] is not used
    (the plan is well beyond the limit: the time scaler's job, not a bend's); the correction
    under way then fades out.
    """

    horizon_s: float = 3.0
    knot_s: float = 0.2
    sample_s: float = 0.05
    margin_rad: float = math.radians(1.0)
    smooth_weight: float = 1e-3
    jerk_weight: float = 1e-3
    max_correction_m: float = 0.3


def _pieces() -> list[FloatArray]:
    """The cardinal quintic B-spline (knots 0, 1, ..., 6) on [r, r+1) as a polynomial in
    u = x - r (coefficients lowest power first), r = 0..DEGREE: the truncated-power form
    sum_i (-1)^i C(6, i) (x - i)_+^5 / 5!, expanded."""
    from numpy.polynomial import Polynomial

    out = []
    for r in range(DEGREE + 1):
        p = Polynomial([0.0])
        for i in range(r + 1):
            sign = (-1.0) ** i * math.comb(DEGREE + 1, i)
            p = p + sign * Polynomial([float(r - i), 1.0]) ** DEGREE
        c = np.zeros(DEGREE + 1)
        coef = np.asarray(p.coef, dtype=np.float64)
        c[: len(coef)] = coef / math.factorial(DEGREE)
        out.append(c)
    return out


_PIECES = _pieces()


def cardinal_bspline(x: npt.ArrayLike, n: int = 0) -> FloatArray:
    """Derivative `n` (0..DEGREE-1) of the cardinal quintic B-spline (knots 0, 1, ..., 6) at
    `x`, from its polynomial pieces (`_PIECES`); 0 outside [0, 6)."""
    from numpy.polynomial import polynomial as npoly

    xa: FloatArray = np.asarray(x, dtype=np.float64)
    r = np.floor(xa)
    out: FloatArray = np.zeros_like(xa)
    for k, piece in enumerate(_PIECES):
        sel = r == k
        if np.any(sel):
            out[sel] = npoly.polyval(xa[sel] - k, npoly.polyder(piece, n) if n else piece)
    return out


class ShapedReference:
    """`reference(t)` with the tilt-limit correction added (see the module docstring).

    Each control cycle: set `drag_per_kg` [1/s], `disturbance_ne` [m/s^2] and `max_tilt_rad`
    from the controller's estimates, then `advance(t)` with the reference time being flown (a
    solve when it first reaches a new knot interval). Calls evaluate only, at any time (the
    look-ahead, a second look at the same time); beyond the last solve's horizon the correction
    fades to zero. `solves` counts the QPs solved, `active` is True while a correction is
    non-zero, `fading` while the last solve found no bend within the limit and the cap (the
    correction under way fades out). `enabled` False: no new bend (one under way fades out).
    `g` [m/s^2].
    """

    @property
    def in_charge(self) -> bool:
        """The bend carries the plan's excess over the limit: enabled, its solver working, and
        its last solve not fading out."""
        return self.enabled and self.error is None and not self.fading

    def __init__(self, reference: Callable[[float], Reference],
                 config: ShapingConfig | None = None, *, max_tilt_rad: float = math.radians(45.0),
                 g: float = 9.80665) -> None:
        self.reference = reference
        self.config = cfg = config or ShapingConfig()
        self.max_tilt_rad = max_tilt_rad
        self.drag_per_kg = 0.0
        self.disturbance_ne = (0.0, 0.0)
        self.rate = 1.0  # reference seconds per flight second (a time scaler's slowing)
        self.enabled = True  # False: no new bend; one under way fades out
        self.error: str | None = None  # why the QP solver was given up (see `_qp`)
        self.g = g
        self._coef: dict[int, FloatArray] = {}  # knot index -> (2,) coefficient [m]
        self._interval: int | None = None  # the knot interval of the last solve
        self._samples: dict[int, Reference] = {}  # sample index -> the plan's reference
        # knot interval -> delta there as polynomials (see `_interval_poly`)
        self._polys: dict[int, list[tuple[list[float], list[float]]]] = {}
        self.solves = 0
        self.failures = 0
        self.active = False
        self.fading = False  # the last solve found no bend within the limit and the cap
        self._m = round(cfg.horizon_s / cfg.knot_s)  # free coefficients per solve
        self._k = round(cfg.horizon_s / cfg.sample_s)  # constraint samples per solve
        off = np.arange(self._k) * cfg.sample_s  # sample offsets from the window start [s]
        self._offsets = off
        # the slack's weight grows over SLACK_RAMP_S into the window: the near samples can only
        # be reached by a steep bend, which is worse than a brief excess
        ramp = np.minimum((off + cfg.sample_s) / SLACK_RAMP_S, 1.0)
        self._slack_w = SLACK_WEIGHT * ramp**2
        # basis matrices for a window starting at knot i+1: rows samples, columns knots
        # j = i+1-DEGREE .. i+1+m (committed first, then the m free ones)
        cols = np.arange(-DEGREE, self._m + 1)  # knot index relative to the window start
        x = off[:, None] / cfg.knot_s - cols[None, :]
        self._cols = cols
        self._b = [cardinal_bspline(x, n) / cfg.knot_s**n for n in range(4)]
        self._solver: Any = None  # built at the first solve (casadi is imported then)

    def _build_solver(self) -> Any:
        import casadi as ca  # only a flight that needs a bend pays for the import

        n = 2 * self._m + self._k  # the coefficients and a slack per sample (see `_solve`)
        # DAQP: a dense active-set QP solver, silent, ~0.6 ms for this size
        return ca.conic("shape", "daqp", {"h": ca.Sparsity.dense(n, n),
                                          "a": ca.Sparsity.dense(self._k, n)},
                        {"error_on_fail": False})

    def reset(self) -> None:
        """Forget the correction (a new flight)."""
        self._coef = {}
        self._samples = {}
        self._polys = {}
        self._interval = None
        self.active = False

    def advance(self, t_s: float) -> None:
        """Solve for the knot interval of reference time `t_s` [s] if it is a new one."""
        i = math.floor(t_s / self.config.knot_s)
        if self._interval is None or i > self._interval:
            self._solve(i)

    def __call__(self, t_s: float) -> Reference:
        ref = self.reference(t_s)
        if not self._coef:
            return ref
        h = self.config.knot_s
        x = t_s / h
        i = math.floor(x)
        poly = self._polys.get(i)
        if poly is None:
            poly = self._polys[i] = self._interval_poly(i)
            if len(self._polys) > 64:
                self._polys = {k: v for k, v in self._polys.items() if k >= i - 8}
        if not poly:
            return ref
        u = x - i
        add = []
        scale = 1.0
        for px, py in poly:  # value, then derivatives 1..4 (in u; d/dt = d/du / h)
            vx = vy = 0.0
            for a, b in zip(px, py, strict=True):  # Horner, highest power first
                vx = vx * u + a
                vy = vy * u + b
            add.append((vx * scale, vy * scale))
            scale /= h
        d = np.zeros((5, 3))
        d[:, :2] = add
        return Reference(ref.pos_ned + d[0], ref.vel_ned + d[1], ref.acc_ned + d[2],
                         ref.jerk_ned + d[3], ref.snap_ned + d[4], ref.yaw, ref.yaw_rate,
                         ref.yaw_acc)

    def correction_poly(self, i: int) -> tuple[list[float], list[float]] | None:
        """The correction on knot interval i (reference times [i h, (i+1) h], h = knot_s) as
        polynomials in u = t/h - i [m] (north, east; coefficients lowest power first), from the
        coefficients solved so far; None where it is zero."""
        poly = self._interval_poly(i)
        if not poly:
            return None
        px, py = poly[0]
        return px[::-1], py[::-1]

    def _interval_poly(self, i: int) -> list[tuple[list[float], list[float]]]:
        """delta on knot interval i as polynomials in u = t/h - i (x and y; the value and its
        u-derivatives 1..4, coefficients highest power first); [] where it is zero."""
        cx = np.zeros(DEGREE + 1)
        cy = np.zeros(DEGREE + 1)
        any_c = False
        for r in range(DEGREE + 1):  # knot j = i - r contributes its piece r
            c = self._coef.get(i - r)
            if c is not None:
                any_c = True
                cx += c[0] * _PIECES[r]
                cy += c[1] * _PIECES[r]
        if not any_c:
            return []
        px, py = cx.tolist(), cy.tolist()  # lowest power first
        out = []
        for _ in range(5):
            out.append((px[::-1], py[::-1]))
            px = [k * a for k, a in enumerate(px)][1:]
            py = [k * a for k, a in enumerate(py)][1:]
        return out

    def _qp(self, hmat: FloatArray, gvec: FloatArray, amat: FloatArray, uba: FloatArray,
            lbx: FloatArray) -> FloatArray | None:
        """The QP's coefficients (m, 2), or None if it has no finite solution. A solver that
        cannot be built or raises (a broken install) is given up for good: the reference is
        then flown as planned, the bend under way fading out, and `error` says why."""
        if self.error is not None:
            return None
        try:
            if self._solver is None:
                self._solver = self._build_solver()
            sol = self._solver(h=hmat, g=gvec, a=amat, lba=-np.inf, uba=uba, lbx=lbx)
            c: FloatArray = np.asarray(sol["x"])[: 2 * self._m].reshape(2, self._m).T
            ok = bool(self._solver.stats().get("success", False))
        except Exception as exc:  # never let the bend take a flight down
            self.error = f"reference shaping disabled: {type(exc).__name__}: {exc}"
            return None
        return c if ok and bool(np.all(np.isfinite(c))) else None

    def _sample(self, t_s: float) -> Reference:
        """The plan's reference at a sample time (kept: successive windows share samples)."""
        key = round(t_s / self.config.sample_s)
        r = self._samples.get(key)
        if r is None:
            r = self._samples[key] = self.reference(t_s)
        return r

    def _solve(self, i: int) -> None:
        """Choose the coefficients of knots i+2 .. i+1+m; those up to i+1 stay as they are."""
        cfg = self.config
        h = cfg.knot_s
        self._interval = i
        self._polys = {}
        # forget coefficients no longer in reach, and any beyond the committed ones
        self._coef = {j: v for j, v in self._coef.items() if i - 2 * DEGREE <= j <= i + 1}
        lo = round((i + 1) * h / cfg.sample_s)
        self._samples = {k: v for k, v in self._samples.items() if k >= lo}
        committed = [self._coef.get(i + 1 + int(c)) for c in self._cols[: DEGREE + 1]]
        self.fading = False
        if not self.enabled and all(v is None for v in committed):
            self.active = False
            return
        t0 = (i + 1) * h  # window start: the first interval with a free coefficient
        ts = t0 + self._offsets
        refs = [self._sample(float(t)) for t in ts]
        dm = self.drag_per_kg
        dx, dy = self.disturbance_ne
        s = min(max(self.rate, 0.0), 1.0)
        acc = np.array([r.acc_ned for r in refs]) * (s * s)
        need = acc[:, :2] + (s * dm) * np.array([r.vel_ned[:2] for r in refs]) - (dx, dy)
        tilt = max(self.max_tilt_rad - cfg.margin_rad, 0.0)
        vertical = np.maximum(self.g - acc[:, 2], 0.0)
        umax = vertical * math.tan(tilt)
        mag = np.linalg.norm(need, axis=1)
        # a bend starts only where the plan itself asks for more than the limit (a plan timed
        # within it is flown as planned); once started it keeps the margin
        if not any(v is not None for v in committed) and bool(
                np.all(mag <= vertical * math.tan(self.max_tilt_rad))):
            self.active = False
            return
        self.solves += 1
        nc = DEGREE + 1
        cfix = np.array([v if v is not None else np.zeros(2) for v in committed])  # (6, 2)
        # delta and its derivatives 0..3 at the samples: fixed part + free part
        fix = [b[:, :nc] @ cfix for b in self._b]  # (k, 2) each
        free = [b[:, nc:] for b in self._b]  # (k, m)
        m = self._m
        w2, w3 = cfg.smooth_weight, cfg.jerk_weight
        hq = 2.0 * (free[0].T @ free[0] + w2 * free[2].T @ free[2]
                    + w3 * free[3].T @ free[3]) + 1e-9 * np.eye(m)
        # a slack >= 0 on each sample's constraint, weighed heavily: samples the committed
        # coefficients already carry past the limit (the window's first knot interval is all
        # committed) keep their excess without relaxing the others
        k = self._k
        hmat = np.zeros((2 * m + k, 2 * m + k))
        hmat[2 * m:, 2 * m:] = 2.0 * np.diag(self._slack_w)
        gvec = np.zeros(2 * m + k)
        for ax in range(2):
            sl = slice(ax * m, (ax + 1) * m)
            hmat[sl, sl] = hq
            gvec[sl] = 2.0 * (free[0].T @ fix[0][:, ax] + w2 * free[2].T @ fix[2][:, ax]
                              + w3 * free[3].T @ fix[3][:, ax])
        nrm = need / np.maximum(mag, 1e-9)[:, None]
        # n . (need + s^2 fix'' + s dm fix' + (s^2 B2 + s dm B1) c) <= umax: flown at rate s,
        # d/dt of the flight is s d/dt of the reference
        fix[1] = s * fix[1]
        fix[2] = (s * s) * fix[2]
        lin = (s * s) * free[2] + (s * dm) * free[1]  # (k, m)
        amat = np.hstack([nrm[:, :1] * lin, nrm[:, 1:] * lin, -np.eye(k)])
        rhs = umax - np.sum(nrm * (need + fix[2] + dm * fix[1]), axis=1)
        lbx = np.full(2 * m + k, -np.inf)
        lbx[2 * m:] = 0.0
        c = self._qp(hmat, gvec, amat, rhs, lbx) if self.enabled else None
        if c is not None:
            delta = fix[0] + free[0] @ c
            if float(np.max(np.linalg.norm(delta, axis=1))) > cfg.max_correction_m:
                c = None
        if c is None:
            # no bend within max_correction_m (the plan is well past the limit: the time
            # scaler's job), no solution, or not enabled: the correction under way fades out
            self.failures += self.enabled
            self.fading = self.enabled
            c = self._qp(hmat, gvec, amat, np.full(k, np.inf), lbx)
            if c is None:
                c = np.zeros((m, 2))
        for q in range(m):  # only non-zero ones: a reference without a bend is passed through
            if np.any(c[q] != 0.0):
                self._coef[i + 2 + q] = c[q]
        self.active = bool(np.any(cfix != 0.0) or np.any(c != 0.0))
