"""The time allocation's sampled limit penalty and its exact duration gradient (adjoint of the
banded minimum-snap system), plus the allocation's safety margin on every limit.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from companion.trajectory.bezier import FloatArray, monomial_matrix
from companion.trajectory.limits import Limits, RoverLimits, thin_matmul
from companion.trajectory.minsnap import BandedSystem

__all__ = ["ALLOCATION_MARGIN", "LimitPenalty", "component_sum"]

#: Safety margin on limits used by the time allocation (sampling cannot see every peak exactly).
ALLOCATION_MARGIN = 0.995

#: Jerk penalised in the allocation per rad/s of the body-rate limit, in units of g.
BODY_RATE_JERK_PROXY = 0.8


def component_sum(terms: list[FloatArray]) -> FloatArray:
    """Sum of the per-component arrays ``terms`` in the order ``np.einsum`` sums a contiguous
    axis of that length (3: ``(t0 + t2) + t1``), so that a component-major layout gives the
    same values as the former component-minor ``einsum``."""
    if len(terms) == 3:
        return terms[0] + terms[2] + terms[1]
    out = terms[0]
    for t in terms[1:]:
        out = out + t
    return out


class LimitPenalty:
    """Sampled smooth penalty ``P = sum_k h_k / n sum_j max(0, g)^3`` of the limit violations
    ``g`` (dimensionless, > 0 when violated) of speed, acceleration, jerk, tilt and thrust, with
    its exact gradient w.r.t. the durations through the optimal joint derivatives (adjoint of
    the banded system). Used only to steer the time allocation; limits are enforced after."""

    def __init__(
        self,
        system: BandedSystem,
        limits: Limits | RoverLimits,
        params: Any,
        n_samples: int = 8,
        speed_scale: FloatArray | None = None,
    ) -> None:
        self.system = system
        self.n = n_samples
        s = system.s
        deg = 2 * s - 1
        mono = monomial_matrix(deg) @ system.H  # (deg+1, 2s): coefficient of tau^p
        tau = (np.arange(n_samples) + 0.5) / n_samples
        self.W: dict[int, FloatArray] = {}
        for r in (1, 2, 3):
            p = np.arange(r, deg + 1)
            fall = np.array([math.factorial(int(i)) / math.factorial(int(i) - r) for i in p])
            V = tau[:, None] ** (p - r)[None, :].astype(np.float64) * fall[None, :]
            self.W[r] = V @ mono[r:, :]
        m = ALLOCATION_MARGIN
        self.terms: list[tuple[str, float]] = [("speed", (limits.max_speed_m_s * m) ** 2)]
        self.params = params
        self.limits = limits
        if isinstance(limits, Limits):
            self.terms.append(("acc", (limits.max_acc_m_s2 * m) ** 2))
            if limits.max_jerk_m_s3 is not None:
                self.terms.append(("jerk", (limits.max_jerk_m_s3 * m) ** 2))
            elif limits.max_body_rate_rad_s is not None and params is not None:
                # the body rate is not in the penalty (it needs the flatness map): its jerk
                # proxy |omega| ~ |j_perp| / (T / m) at hover thrust steers the allocation
                # away from corners that only a uniform slow-down could make feasible
                proxy = BODY_RATE_JERK_PROXY * limits.max_body_rate_rad_s * float(params.g)
                self.terms.append(("jerk", (proxy * m) ** 2))
            if limits.max_tilt_rad is not None:
                self.terms.append(("tilt", math.tan(limits.max_tilt_rad * m) ** 2))
            if limits.max_thrust_n is not None:
                self.terms.append(("max_thrust", (limits.max_thrust_n * m) ** 2))
            if limits.min_thrust_n is not None and limits.min_thrust_n > 0.0:
                self.terms.append(("min_thrust", (limits.min_thrust_n / m) ** 2))
        self.orders = sorted(
            {3 if n == "jerk" else 2 if n != "speed" else 1 for n, _ in self.terms} | {1}
        )
        if any(n in ("tilt", "max_thrust", "min_thrust") for n, _ in self.terms):
            self.orders = sorted(set(self.orders) | {1, 2})
        self.W_all = np.vstack([self.W[r] for r in self.orders])
        self.W_all_r = np.vstack([r * self.W[r] for r in self.orders])
        self.order_pow = np.array(self.orders, dtype=np.float64)[:, None]
        kin_order = {"speed": 1, "acc": 2, "jerk": 3}
        # (R, 1, M): 1 / limit^2 per derivative order and segment (per-segment speed caps)
        self.kin_inv_lim2 = np.zeros((len(self.orders), 1, system.m))
        for name, lim2 in self.terms:
            if name in kin_order:
                row = np.full(system.m, 1.0 / lim2)
                if name == "speed" and speed_scale is not None:
                    row = row / (speed_scale * speed_scale)
                self.kin_inv_lim2[self.orders.index(kin_order[name]), 0, :] = row
        self.dyn_terms = [(nm, lim2) for nm, lim2 in self.terms if nm not in kin_order]
        # per-axis speed and acceleration (horizontal, up, down), squared with the margin
        self.axis_terms: list[tuple[int, tuple[float, float, float]]] = []
        if isinstance(limits, Limits):
            for order, axes in ((1, limits.max_vel_axes_m_s), (2, limits.max_acc_axes_m_s2)):
                if axes is not None:
                    h2, up2, dn2 = ((v * m) ** 2 for v in axes)
                    self.axis_terms.append((self.orders.index(order), (h2, up2, dn2)))
        self.W_all_T = np.ascontiguousarray(self.W_all.T)
        self.W_all_rT = np.ascontiguousarray(self.W_all_r.T)

    def _violations(
        self, d_all: FloatArray, grad: bool = True
    ) -> tuple[FloatArray, FloatArray | None]:
        """Per-sample penalty phi (n, M) from the sampled derivatives d_all (R, n, d, M: the
        components of all segments contiguous) and, if ``grad``, dphi/d(d_all) (shape of d_all;
        None when nothing is violated). Sums over the d components are formed as
        ``(x0 + x2) + x1``, the order np.einsum uses on a contiguous (..., 3) axis."""
        n, m = d_all.shape[1], d_all.shape[3]
        dim = d_all.shape[2]
        sq = d_all * d_all
        g_kin = component_sum([sq[:, :, k] for k in range(dim)])
        g_kin *= self.kin_inv_lim2
        g_kin -= 1.0
        active = bool(g_kin.max() > 0.0)
        g_all = None
        if active:
            pos = np.maximum(g_kin, 0.0)
            w = pos * pos
            wp = w * pos
            phi = wp[0]
            for r in range(1, wp.shape[0]):
                phi = phi + wp[r]
            if grad:
                w *= 6.0 * self.kin_inv_lim2
                g_all = d_all * w[:, :, None, :]
        else:
            phi = np.zeros((n, m))
        for row, (h2, up2, dn2) in self.axis_terms if dim == 3 else ():
            vec, vsq = d_all[row], sq[row]  # components and their squares, (n, 3, M)
            inv_z = np.where(vec[:, 2] < 0.0, 1.0 / up2, 1.0 / dn2)
            g_h = (vsq[:, 0] + vsq[:, 1]) / h2 - 1.0
            g_z = vsq[:, 2] * inv_z - 1.0
            for g, axes, inv in ((g_h, (0, 1), 1.0 / h2), (g_z, (2,), inv_z)):
                if not g.max() > 0.0:
                    continue
                pos = np.maximum(g, 0.0)
                w = pos * pos
                phi = phi + w * pos
                if not grad:
                    continue
                if g_all is None:
                    g_all = np.zeros_like(d_all)
                w6 = 6.0 * w * inv
                for ax in axes:
                    g_all[row, :, ax] += w6 * vec[:, ax]
        if not self.dyn_terms:
            return phi, g_all
        i1, i2 = self.orders.index(1), self.orders.index(2)
        mass = float(self.params.mass)
        drag = float(getattr(self.params, "drag", 0.0))
        mg = mass * float(self.params.g)
        tv = -mass * d_all[i2]
        if drag:
            tv -= drag * d_all[i1]
        tv[:, 2] += mg
        dsum = None
        t2 = None
        tsq = None  # squared thrust components
        for name, lim2 in self.dyn_terms:
            if tsq is None:
                tsq = tv * tv
            if name == "tilt":
                tz = np.maximum(tv[:, 2], 1e-3 * mg)
                hor = tsq[:, 0] + tsq[:, 1]
                inv = 1.0 / (lim2 * tz * tz)
                g = hor * inv - 1.0
                if not g.max() > 0.0:
                    continue
                pos = np.maximum(g, 0.0)
                w = pos * pos
                phi += w * pos
                if not grad:
                    continue
                w *= 6.0 * inv
                if dsum is None:
                    dsum = np.zeros_like(tv)
                dsum[:, 0] += w * tv[:, 0]
                dsum[:, 1] += w * tv[:, 1]
                dsum[:, 2] -= w * hor / tz
            else:
                if t2 is None:
                    t2 = component_sum([tsq[:, k] for k in range(tv.shape[1])])
                sign = 1.0 if name == "max_thrust" else -1.0
                g = sign * (t2 / lim2 - 1.0)
                if not g.max() > 0.0:
                    continue
                pos = np.maximum(g, 0.0)
                w = pos * pos
                phi += w * pos
                if not grad:
                    continue
                w *= sign * 6.0 / lim2
                if dsum is None:
                    dsum = np.zeros_like(tv)
                dsum += w[:, None, :] * tv
        if dsum is not None:
            if g_all is None:
                g_all = np.zeros_like(d_all)
            g_all[i2] -= mass * dsum
            if drag:
                g_all[i1] -= drag * dsum
        return phi, g_all

    def sampled(self, x: FloatArray, h: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(d_all (R, n, d, M) sampled derivatives, zs (2s, d, M) scaled joint derivatives,
        ihp) at the optimum x(h). The samples are component-major (each component of all
        segments contiguous) for the element-wise penalty terms."""
        sysm = self.system
        s = sysm.s
        xk = sysm.windows(x)
        m, d = xk.shape[0], xk.shape[2]
        hp = sysm.powers(h, 0)
        zs = np.ascontiguousarray((xk * hp[:, :, None]).transpose(1, 2, 0))  # (2s, d, M)
        ihp = (1.0 / h)[None, :] ** self.order_pow  # (R, M)
        d_all = thin_matmul(self.W_all, zs.reshape(2 * s, d * m)).reshape(
            len(self.orders), self.n, d, m
        )
        d_all *= ihp[:, None, None, :]
        return d_all, zs, ihp

    def value(self, x: FloatArray, h: FloatArray) -> tuple[float, Any]:
        """Penalty P at the optimum x(h), and the state :meth:`gradient` needs."""
        d_all, zt, ihp = self.sampled(x, h)
        phi, g_all = self._violations(d_all)
        if g_all is None:
            return 0.0, None
        phis = np.sum(phi, axis=0)
        return float(phis @ h) / self.n, (phis, g_all, zt, ihp)

    def gradient(
        self, state: Any, x: FloatArray, h: FloatArray, dqx: FloatArray | None = None
    ) -> FloatArray:
        """dP/dh (M,) from :meth:`value`'s state (explicit dependence through the sample
        times plus the adjoint of the banded system for the dependence through x(h)).
        ``dqx``: ``system.dq_x(x, h)`` if already computed (shared with ``cost_grad``)."""
        if state is None:
            return np.zeros(h.shape[0])
        phis, g_all, zs, ihp = state
        sysm = self.system
        s = sysm.s
        n = self.n
        d, m = g_all.shape[2], g_all.shape[3]
        hp = sysm.powers(h, 0)
        inv_h = 1.0 / h
        dh = phis / n
        # back-projection: U = sum_r W_r^T G_r h^-r, V = sum_r r W_r^T G_r h^-r
        g_all *= (ihp * (h / n)[None, :])[:, None, None, :]
        gt = g_all.reshape(len(self.orders) * n, d * m)
        U = thin_matmul(self.W_all_T, gt).reshape(2 * s, d, m)
        V = thin_matmul(self.W_all_rT, gt).reshape(2 * s, d, m)
        # sum over the inputs a and components of zs * (o U - V), in the order of the former
        # np.einsum("amd,amd->m") (components as in component_sum, then a in turn)
        prod = zs * (sysm.o[:, None, None] * U - V)  # (2s, d, M)
        per_a = component_sum([prod[:, k] for k in range(d)])
        acc = per_a[0]
        for a in range(1, per_a.shape[0]):
            acc = acc + per_a[a]
        dh += acc * inv_h
        U *= hp.T[:, None, :]  # dP/dx per segment window, (2s, d, M)
        g_full = np.zeros_like(x)
        g_full[: m * s] += U[:s].transpose(2, 0, 1).reshape(-1, d)
        g_full[s:] += U[s:].transpose(2, 0, 1).reshape(-1, d)
        lam = sysm.adjoint(g_full)
        if dqx is None:
            dqx = sysm.dq_x(x, h)
        dh -= np.einsum("mad,mad->m", sysm.windows(lam), dqx)
        return np.asarray(dh, dtype=np.float64)

    def value_grad(
        self, x: FloatArray, h: FloatArray, dqx: FloatArray | None = None
    ) -> tuple[float, FloatArray]:
        """Penalty P and its total derivative dP/dh (M,) at the optimum x(h).

        Arrays are kept in (order, sample, segment, axis) layout: one matrix product maps the
        joint derivatives of all segments to the samples and one maps the sensitivities back.
        """
        p, state = self.value(x, h)
        return p, self.gradient(state, x, h, dqx)

