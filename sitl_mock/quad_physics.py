"""Quadrotor physics and sensors: rigid-body integration, gusts, measurement and estimator noise.

The state it integrates lives in `QuadState`'s slots (quad_state.py). World frame NED, body
FRD, SI units; see quad.py's docstring for the model.
"""

from __future__ import annotations

import math

from sitl_mock.estimate_error import advance_gauss_markov
from sitl_mock.flight_control import G
from sitl_mock.quad_state import QuadState

# Guards of the explicit integrator: parameter combinations at the ends of their ranges (a
# 0.05 kg vehicle with 100 N/(m/s) drag, 1e-4 kg m^2 inertia against 10 kg m^2) make it
# unstable; the state is held to these bounds (NaN -> 0) so the simulation goes on instead of
# overflowing. Never reached with physical parameters.
_W_LIMIT = 200.0  # body rate [rad/s]
_V_LIMIT = 1_000.0  # velocity [m/s]
_P_LIMIT = 1.0e7  # position [m]


def _bounded(xs: tuple[float, ...], limit: float) -> tuple[float, ...]:
    """Each value clamped to [-limit, limit]; NaN becomes 0."""
    return tuple(0.0 if x != x else max(-limit, min(limit, x)) for x in xs)


class QuadPhysics(QuadState):
    """The quadrotor's physics and sensor noise (their state is in `QuadState`'s slots)."""

    __slots__ = ()

    def _apply_gust(self) -> None:
        b, g = self._wind_base, self._gust
        self._wind = (b[0] + g[0], b[1] + g[1], b[2] + g[2])

    def _step_gust(self, dt: float) -> None:
        """Advance the gust process by `dt` [s] (exact Gauss-Markov discretisation)."""
        e = math.exp(-dt / max(self._gust_tau, 1e-3))
        s = self._gust_std * math.sqrt(1.0 - e * e)
        gauss = self._gust_rng.gauss
        gx, gy, gz = self._gust
        self._gust = (gx * e + s * gauss(), gy * e + s * gauss(), gz * e + 0.5 * s * gauss())
        self._apply_gust()

    def _advance_estimator_error(self, dt: float) -> None:
        """Horizontal estimator errors like EKF2's on SIH (measured on PX4 v1.16 SITL: position
        ~0.16 m, velocity ~0.2 m/s per axis, both slowly varying, ~1.7 s): per axis, white noise
        through two first-order lags of time constant SIM_EST_XY_TAU (a second-order
        Gauss-Markov process) scaled to the stationary std SIM_EST_XY_STD (position) and
        SIM_EST_VXY_STD (velocity), independent of each other as measured (estimate_error.py)."""
        std_p, std_v, tau = self._est_cfg
        advance_gauss_markov(self._est, (std_p, std_p, std_v, std_v), tau, dt, self._rng.gauss)

    def _refresh(self) -> None:
        if self._noise[0] > 0.0 or self._noise[1] > 0.0:
            gauss = self._rng.gauss
            sp, sv = self._noise[0], self._noise[1]
            self._npos = (gauss(0.0, sp), gauss(0.0, sp), gauss(0.0, sp)) if sp > 0 else (0, 0, 0)
            self._nvel = (gauss(0.0, sv), gauss(0.0, sv), gauss(0.0, sv)) if sv > 0 else (0, 0, 0)
        else:
            self._npos = (0.0, 0.0, 0.0)
            self._nvel = (0.0, 0.0, 0.0)
        if self._est_cfg[0] > 0.0 or self._est_cfg[1] > 0.0:
            e = self._est
            n, v = self._npos, self._nvel
            self._npos = (n[0] + e[1], n[1] + e[3], n[2])
            self._nvel = (v[0] + e[5], v[1] + e[7], v[2])

    def _integrate(self, dt: float) -> None:
        # motor lag
        if dt != self._alpha_dt:
            self._alpha_dt = dt
            self._alpha = 1.0 - math.exp(-dt / self._tau) if self._tau > 1e-6 else 1.0
            self._hdt = 0.5 * dt
            self._hdt2 = 0.5 * dt * dt
            self._invdt = 1.0 / dt
        a = self._alpha
        u0, u1, u2, u3 = self._u
        c0, c1, c2, c3 = self._motor_cmd
        u0 = u0 + (c0 - u0) * a
        u1 = u1 + (c1 - u1) * a
        u2 = u2 + (c2 - u2) * a
        u3 = u3 + (c3 - u3) * a
        self._u = (u0, u1, u2, u3)
        thrust = self._tmax * (u0 + u1 + u2 + u3)
        mx = self._lroll_t * (-u0 + u1 + u2 - u3)
        my = self._lpitch_t * (u0 - u1 + u2 - u3)
        mz = self._qmax * (u0 + u1 - u2 - u3)

        qw, qx, qy, qz = self._qw, self._qx, self._qy, self._qz
        # body z axis in world
        bzx = 2.0 * (qx * qz + qw * qy)
        bzy = 2.0 * (qy * qz - qw * qx)
        bzz = 1.0 - 2.0 * (qx * qx + qy * qy)
        m = self._mass
        kdv = self._kdv
        wnx, wny, wnz = self._wind
        vx, vy, vz = self._vx, self._vy, self._vz
        ax = (-thrust * bzx - kdv * (vx - wnx)) / m
        ay = (-thrust * bzy - kdv * (vy - wny)) / m
        az = (-thrust * bzz - kdv * (vz - wnz)) / m + G
        hdt2 = self._hdt2
        px = self._px + vx * dt + ax * hdt2
        py = self._py + vy * dt + ay * hdt2
        pz = self._pz + vz * dt + az * hdt2
        nvx, nvy, nvz = vx + ax * dt, vy + ay * dt, vz + az * dt

        # rotational dynamics (Euler's equations), midpoint rule
        ixx, iyy, izz, kdw = self._ixx, self._iyy, self._izz, self._kdw
        d_yz, d_zx, d_xy = self._izz_m_iyy, self._ixx_m_izz, self._iyy_m_ixx
        wx, wy, wz = self._wx, self._wy, self._wz
        hdt = self._hdt
        hx = wx + hdt * ((mx - kdw * wx - d_yz * wy * wz) / ixx)
        hy = wy + hdt * ((my - kdw * wy - d_zx * wz * wx) / iyy)
        hz = wz + hdt * ((mz - kdw * wz - d_xy * wx * wy) / izz)
        dwx = (mx - kdw * hx - d_yz * hy * hz) / ixx
        dwy = (my - kdw * hy - d_zx * hz * hx) / iyy
        dwz = (mz - kdw * hz - d_xy * hx * hy) / izz
        nwx, nwy, nwz = wx + dt * dwx, wy + dt * dwy, wz + dt * dwz
        if not (abs(nwx) < _W_LIMIT and abs(nwy) < _W_LIMIT and abs(nwz) < _W_LIMIT
                and abs(hx) < _W_LIMIT and abs(hy) < _W_LIMIT and abs(hz) < _W_LIMIT
                and abs(nvx) < _V_LIMIT and abs(nvy) < _V_LIMIT and abs(nvz) < _V_LIMIT):
            hx, hy, hz, nwx, nwy, nwz = _bounded((hx, hy, hz, nwx, nwy, nwz), _W_LIMIT)
            nvx, nvy, nvz = _bounded((nvx, nvy, nvz), _V_LIMIT)
            px, py, pz = _bounded((px, py, pz), _P_LIMIT)
        # attitude: q <- q * exp(omega_mid dt / 2)
        ang = math.sqrt(hx * hx + hy * hy + hz * hz) * dt
        if ang > 1e-12:
            s = math.sin(0.5 * ang) * dt / ang
            dw = math.cos(0.5 * ang)
            dx, dy, dz = hx * s, hy * s, hz * s
            rw = qw * dw - qx * dx - qy * dy - qz * dz
            rx = qw * dx + qx * dw + qy * dz - qz * dy
            ry = qw * dy - qx * dz + qy * dw + qz * dx
            rz = qw * dz + qx * dy - qy * dx + qz * dw
            n = 1.0 / math.sqrt(rw * rw + rx * rx + ry * ry + rz * rz)
            qw = rw * n
            qx = rx * n
            qy = ry * n
            qz = rz * n

        # ground contact
        if pz >= 0.0 and nvz >= 0.0:
            pz = 0.0
            nvx = nvy = nvz = 0.0
            nwx = nwy = nwz = 0.0
            yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
            qw, qx, qy, qz = math.cos(0.5 * yaw), 0.0, 0.0, math.sin(0.5 * yaw)
            px, py = self._px, self._py
            self._on_ground = True
            self._touched = True
        else:
            self._on_ground = False
        inv = self._invdt
        self._ax, self._ay, self._az = (nvx - vx) * inv, (nvy - vy) * inv, (nvz - vz) * inv
        self._px, self._py, self._pz = px, py, pz
        self._vx, self._vy, self._vz = nvx, nvy, nvz
        self._wx, self._wy, self._wz = nwx, nwy, nwz
        self._qw, self._qx, self._qy, self._qz = qw, qx, qy, qz
