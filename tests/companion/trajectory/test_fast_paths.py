"""The planner's LAPACK routines loaded straight from SciPy's `_flapack` extension
(`companion.trajectory._lapack`, skipping the ~0.25 s import of scipy.linalg) are SciPy's own:
the same bits as `scipy.linalg.lapack.dpbtrf` / `dpbtrs` on banded systems, and planning does
not import scipy.linalg."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[3]


def _banded_spd(rng: np.random.Generator, n: int, u: int) -> np.ndarray:
    """Upper banded storage (u + 1, n) of a random symmetric positive definite matrix."""
    a = rng.standard_normal((n, n))
    full = a @ a.T + n * np.eye(n)
    band = np.zeros((u + 1, n))
    for k in range(u + 1):  # ab[u - k, j] = A[j - k, j]
        band[u - k, k:] = np.diagonal(full, offset=k)
    return band


@pytest.mark.parametrize("n,u", [(5, 1), (24, 7), (61, 5)])
def test_direct_lapack_equals_scipy_linalg_lapack(n: int, u: int) -> None:
    import scipy.linalg.lapack as public

    from companion.trajectory import _lapack

    direct = _lapack._direct()
    assert direct is not None, "scipy's _flapack extension was not found"
    pbtrf, pbtrs = direct
    rng = np.random.default_rng(n * 100 + u)
    ab = _banded_spd(rng, n, u)
    rhs = rng.standard_normal((n, 3))
    cb, info = pbtrf(ab.copy(), lower=0)
    cb_ref, info_ref = public.dpbtrf(ab.copy(), lower=0)
    assert info == info_ref == 0
    np.testing.assert_array_equal(cb, cb_ref)
    z, info = pbtrs(cb, rhs, lower=0)
    z_ref, _ = public.dpbtrs(cb_ref, rhs, lower=0)
    np.testing.assert_array_equal(z, z_ref)
    # and it solves the system
    full = np.zeros((n, n))
    for k in range(u + 1):
        full += np.diag(ab[u - k, k:], k) + (np.diag(ab[u - k, k:], -k) if k else 0.0)
    np.testing.assert_allclose(full @ z, rhs, rtol=1e-9, atol=1e-9)


def test_planning_does_not_import_scipy_linalg() -> None:
    code = (
        "import sys\n"
        "from companion.mission import load_mission, mission_to_flight_plan\n"
        "from companion.planning.schedule import VehicleLimits, build_schedule\n"
        "from companion.replay.runner import DEFAULT_QUAD\n"
        f"m = load_mission({str(ROOT / 'examples' / 'missions' / 'square.plan')!r})\n"
        "s = build_schedule(mission_to_flight_plan(m, vehicle='quad'), DEFAULT_QUAD, "
        "VehicleLimits())\n"
        "assert s.duration_s > 10.0\n"
        "print(sorted(k for k in sys.modules if k.startswith('scipy')))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                         text=True, timeout=120, check=True).stdout
    assert out.strip() == "[]"



# ---------------------------------------------------------------- time-optimal bound (oracle)
# `time_optimal_profile` as it was before its backward pass was rearranged (git 0b2475c):
# each point's vertices enumerated with numpy, the forward pass over the same rows.
_OCT = [(math.cos(k * math.pi / 4), math.sin(k * math.pi / 4)) for k in range(8)]


def _max_x(rows: np.ndarray) -> float:
    a, b, c = rows[:, 0], rows[:, 1], rows[:, 2]
    i, j = np.triu_indices(rows.shape[0], 1)
    det = a[i] * b[j] - a[j] * b[i]
    ok = np.abs(det) > 1e-12
    i, j, det = i[ok], j[ok], det[ok]
    u = (c[i] * b[j] - c[j] * b[i]) / det
    x = (a[i] * c[j] - a[j] * c[i]) / det
    slack = c[None, :] + 1e-9 * (1.0 + np.abs(c[None, :])) - (
        a[None, :] * u[:, None] + b[None, :] * x[:, None]
    )
    feas = np.all(slack >= 0.0, axis=1)
    return float(np.max(x[feas], initial=0.0))


def _reference_profile(traj: Any, limits: Any, speed_caps: Any = None,
                       samples_per_segment: int = 40) -> tuple[np.ndarray, ...]:
    n = samples_per_segment
    tau = np.linspace(0.0, 1.0, n, endpoint=False)
    t = np.concatenate(
        [(traj.breaks[:-1, None] + tau[None, :] * traj.durations[:, None]).reshape(-1),
         [traj.duration]]
    )
    seg = np.minimum(np.searchsorted(traj.breaks, t, side="right") - 1, traj.num_segments - 1)
    p = traj.evaluate(t, 0)
    v = traj.evaluate(t, 1)
    a = traj.evaluate(t, 2)
    speed = np.linalg.norm(v, axis=1)
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    keep = np.concatenate([[True], ds > 1e-6])
    p, v, a, speed, seg = p[keep], v[keep], a[keep], speed[keep], seg[keep]
    if p.shape[0] < 2:
        return np.zeros(1), p[:1], np.zeros(1)
    ds = np.linalg.norm(np.diff(p, axis=0), axis=1)
    moving = speed > 1e-6 * max(float(speed.max()), 1e-12)
    tan = np.zeros_like(v)
    tan[moving] = v[moving] / speed[moving, None]
    chord = np.diff(p, axis=0) / np.maximum(ds, 1e-12)[:, None]
    tan[~moving] = np.vstack([chord, chord[-1:]])[~moving]
    curv = np.zeros_like(a)
    along = np.einsum("ij,ij->i", a, tan)
    curv[moving] = (a[moving] - along[moving, None] * tan[moving]) / (speed[moving, None] ** 2)
    vcap_xy = np.full(p.shape[0], limits.max_speed_xy_m_s)
    big = 1e12
    n_pts = p.shape[0]
    x_cap = np.full(n_pts, big)
    if speed_caps is not None:
        x_cap = np.minimum(x_cap, np.asarray(speed_caps, dtype=np.float64)[seg] ** 2)
    t_xy2 = tan[:, 0] ** 2 + tan[:, 1] ** 2
    x_cap = np.where(t_xy2 > 1e-12, np.minimum(x_cap, vcap_xy**2 / np.maximum(t_xy2, 1e-12)),
                     x_cap)
    vz = np.where(tan[:, 2] > 0.0, limits.max_descent_m_s, limits.max_climb_m_s)
    x_cap = np.where(
        tan[:, 2] ** 2 > 1e-12, np.minimum(x_cap, vz**2 / np.maximum(tan[:, 2] ** 2, 1e-12)),
        x_cap
    )

    def rows_at(i: int) -> list[tuple[float, float, float]]:
        tx, ty, tz = tan[i]
        kx, ky, kz = curv[i]
        rows = [(ex * tx + ey * ty, ex * kx + ey * ky, limits.max_acc_xy_m_s2)
                for ex, ey in _OCT]
        rows.append((tz, kz, limits.max_acc_down_m_s2))
        rows.append((-tz, -kz, limits.max_acc_up_m_s2))
        rows.append((0.0, 1.0, float(x_cap[i])))
        rows.append((0.0, -1.0, 0.0))
        return rows

    x_hi = np.zeros(n_pts)
    for i in range(n_pts - 2, -1, -1):
        d2 = 2.0 * float(ds[i])
        rows = rows_at(i)
        rows.append((d2, 1.0, float(x_hi[i + 1])))
        rows.append((-d2, -1.0, 0.0))
        rows.append((1.0, 0.0, big))
        rows.append((-1.0, 0.0, big))
        x_hi[i] = _max_x(np.asarray(rows, dtype=np.float64))
    x = np.zeros(n_pts)
    times = np.zeros(n_pts)
    total = 0.0
    for i in range(n_pts - 1):
        d2 = 2.0 * float(ds[i])
        u_hi = big
        for ca, cb, cc in rows_at(i):
            if ca > 1e-12:
                u_hi = min(u_hi, (cc - cb * x[i]) / ca)
        nxt = min(x[i] + d2 * u_hi, float(x_hi[i + 1]))
        x[i + 1] = max(nxt, 0.0)
        vs = math.sqrt(x[i]) + math.sqrt(x[i + 1])
        total = math.inf if vs <= 0.0 else total + d2 / vs
        times[i + 1] = total
    return times, p, np.sqrt(np.maximum(x, 0.0))


@pytest.mark.parametrize("mission", ["square.plan", "ten_waypoints.plan", "hold_and_jump.plan",
                                     "survey.plan", "five_minute.plan"])
def test_time_optimal_profile_equals_the_vertex_enumeration(mission: str) -> None:
    """The time-optimal bound (its backward pass arranged so that only the next point's bound
    waits for the sequential pass) against the enumeration of every point's vertices it
    replaced: the same times, points and speeds, bit for bit, on every trajectory piece of a
    bundled mission, with PX4-like, tight and loose limits and random per-segment caps."""
    import dataclasses

    from companion.mission import load_mission, mission_to_flight_plan
    from companion.planning.schedule import VehicleLimits, build_schedule
    from companion.replay.runner import DEFAULT_QUAD
    from companion.trajectory.bound import KinematicLimits, time_optimal_profile

    lim = KinematicLimits(max_speed_xy_m_s=12.0, max_climb_m_s=3.0, max_descent_m_s=1.5,
                          max_acc_xy_m_s2=4.0, max_acc_up_m_s2=3.0, max_acc_down_m_s2=2.0)
    variants = (lim, dataclasses.replace(lim, max_acc_xy_m_s2=0.3, max_acc_down_m_s2=0.2),
                dataclasses.replace(lim, max_acc_xy_m_s2=40.0, max_speed_xy_m_s=3.0))
    m = load_mission(ROOT / "examples" / "missions" / mission)
    sched = build_schedule(mission_to_flight_plan(m, vehicle="quad"), DEFAULT_QUAD,
                           VehicleLimits())
    pieces = [p for p in sched.pieces if p.kind == "traj" and p.traj is not None]
    assert pieces
    rng = np.random.default_rng(len(mission))
    for piece in pieces:
        traj = piece.traj
        caps = [piece.speed_caps, rng.uniform(0.5, 15.0, traj.num_segments)]
        for variant in variants:
            for cap in caps:
                fast = time_optimal_profile(traj, variant, cap)
                slow = _reference_profile(traj, variant, cap)
                for f, s in zip(fast, slow, strict=True):
                    np.testing.assert_array_equal(f, s)
                assert fast[0][-1] > 0.0
