"""Reference shaping for the tilt limit (companion.control.shaping).

Oracles: SciPy's B-spline for the basis; finite differences for the derivatives the shaped
reference reports; the optimal bend of a circle flown too fast, which is a concentric circle
(by symmetry of the convex problem) of the radius whose demand is exactly the limit:
omega r sqrt(omega^2 + (D/m)^2) = g tan(limit)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.interpolate import BSpline

from companion.control import Reference, ShapedReference, ShapingConfig
from companion.control.shaping import cardinal_bspline

G = 9.80665


RAMP_S = 4.0  # the circles' angular rate rises from 0 over this long [s]


def _phase(t: float, omega: float) -> tuple[float, float, float, float, float]:
    """phi and its derivatives 1..4: phi' rises from 0 to `omega` by a septic smoothstep."""
    if t >= RAMP_S:
        return omega * (t - 0.5 * RAMP_S), omega, 0.0, 0.0, 0.0
    x, T = max(t, 0.0) / RAMP_S, RAMP_S
    s0 = 35 * x**4 - 84 * x**5 + 70 * x**6 - 20 * x**7
    s1 = 140 * x**3 - 420 * x**4 + 420 * x**5 - 140 * x**6
    s2 = 420 * x**2 - 1680 * x**3 + 2100 * x**4 - 840 * x**5
    s3 = 840 * x - 5040 * x**2 + 8400 * x**3 - 4200 * x**4
    integral = 7 * x**5 - 14 * x**6 + 10 * x**7 - 2.5 * x**8
    return omega * T * integral, omega * s0, omega * s1 / T, omega * s2 / T**2, omega * s3 / T**3


def circle(radius: float, omega: float):
    """A circle of `radius` [m] about the origin, 5 m up (NED), its angular rate rising to
    `omega` [rad/s] over RAMP_S. As a complex number f = r exp(i phi), with p1..p4 the
    derivatives of phi: f' = i p1 f, f'' = (i p2 - p1^2) f, f^(3) = (i p3 - 3 p1 p2 - i p1^3) f,
    f^(4) = (i p4 - 4 p1 p3 - 3 p2^2 - 6 i p1^2 p2 + p1^4) f."""

    def ref(t: float) -> Reference:
        phi, p1, p2, p3, p4 = _phase(t, omega)
        f = radius * complex(math.cos(phi), math.sin(phi))
        ds = [f, 1j * p1 * f, (1j * p2 - p1**2) * f, (1j * p3 - 3 * p1 * p2 - 1j * p1**3) * f,
              (1j * p4 - 4 * p1 * p3 - 3 * p2**2 - 6j * p1**2 * p2 + p1**4) * f]
        v = [np.array([d.real, d.imag, 0.0]) for d in ds]
        v[0][2] = -5.0
        return Reference(*v)

    return ref


def fly(shaper: ShapedReference, t_end: float, dt: float = 0.01) -> list[tuple[float, Reference]]:
    """Advance the shaper as a flight would and collect its reference every `dt`."""
    out = []
    for k in range(round(t_end / dt) + 1):
        t = k * dt
        shaper.advance(t)
        out.append((t, shaper(t)))
    return out


def demand_tilt(r: Reference, dm: float) -> float:
    """Tilt [rad] the thrust needs for reference `r` with drag per mass `dm`, altitude held."""
    h = math.hypot(r.acc_ned[0] + dm * r.vel_ned[0], r.acc_ned[1] + dm * r.vel_ned[1])
    return math.atan2(h, G - float(r.acc_ned[2]))


@pytest.mark.parametrize("n", range(5))
def test_the_basis_is_scipys_quintic_bspline(n: int) -> None:
    b = BSpline.basis_element(np.arange(7.0), extrapolate=False)
    x = np.linspace(-1.0, 7.0, 1601)
    want = np.nan_to_num((b.derivative(n) if n else b)(x))
    assert np.max(np.abs(cardinal_bspline(x, n) - want)) < 1e-12


def test_a_reference_within_the_limit_is_passed_through_unchanged() -> None:
    base = circle(10.0, 0.5)  # 2.5 m/s^2: 14 deg of tilt
    sh = ShapedReference(base, max_tilt_rad=math.radians(45.0))
    sh.drag_per_kg = 1.0
    for t, r in fly(sh, 20.0):
        b = base(t)
        for name in ("pos_ned", "vel_ned", "acc_ned", "jerk_ned", "snap_ned"):
            assert np.array_equal(getattr(r, name), getattr(b, name))
    assert sh.solves == 0 and not sh.active


@pytest.mark.parametrize("dm", [0.0, 1.25])
def test_a_circle_too_fast_is_bent_to_the_concentric_circle_at_the_limit(dm: float) -> None:
    radius, limit, margin = 3.0, math.radians(45.0), math.radians(2.0)
    tilt = limit - margin
    # the rate at which the circle 0.25 m inside is exactly at the limit less the margin:
    # omega^2 (omega^2 + dm^2) = (g tan(tilt) / r)^2; the circle itself then asks for 45.5 deg
    k = G * math.tan(tilt) / (radius - 0.25)
    omega = math.sqrt((-dm**2 + math.sqrt(dm**4 + 4 * k**2)) / 2)
    r_star = G * math.tan(tilt) / (omega * math.hypot(omega, dm))
    assert r_star == pytest.approx(radius - 0.25)
    assert demand_tilt(circle(radius, omega)(20.0), dm) > limit  # a bend starts only past it
    cfg = ShapingConfig(margin_rad=margin, max_correction_m=1.0)  # the spin-up bends more
    sh = ShapedReference(circle(radius, omega), cfg, max_tilt_rad=limit)
    sh.drag_per_kg = dm
    steady = [r for t, r in fly(sh, 30.0) if t > 16.0]
    radii = np.array([math.hypot(r.pos_ned[0], r.pos_ned[1]) for r in steady])
    tilts = np.array([demand_tilt(r, dm) for r in steady])
    assert sh.solves > 0 and sh.failures == 0
    assert np.max(np.abs(radii - r_star)) < 0.01  # [m], of a 0.25 m bend
    assert np.max(tilts) < tilt + math.radians(0.5)


def test_the_derivatives_it_reports_are_those_of_its_position() -> None:
    sh = ShapedReference(circle(5.0, 1.5), max_tilt_rad=math.radians(45.0))
    sh.drag_per_kg = 1.0
    dt = 1e-3
    refs = fly(sh, 12.0, dt)
    names = ("pos_ned", "vel_ned", "acc_ned", "jerk_ned", "snap_ned")
    for lo, hi in itertools.pairwise(names):
        x = np.array([getattr(r, lo) for _, r in refs])
        d = np.array([getattr(r, hi) for _, r in refs])
        fd = (x[2:] - x[:-2]) / (2 * dt)
        scale = np.max(np.abs(d)) + 1e-9
        assert np.max(np.abs(fd - d[1:-1])) < 2e-3 * scale, lo  # continuous across solves too


def test_a_time_scaler_slowing_the_reference_takes_the_bend_away() -> None:
    # at half rate the circle needs a quarter of the acceleration (and half the drag)
    sh = ShapedReference(circle(5.0, 1.5), max_tilt_rad=math.radians(45.0))
    sh.drag_per_kg = 1.0
    sh.rate = 0.5
    fly(sh, 10.0)
    assert sh.solves == 0 and not sh.active


def test_a_plan_far_past_the_limit_gets_no_bend_larger_than_the_cap() -> None:
    # 9 m/s^2 of centripetal demand plus 6 m/s^2 of wind: the time scaler's case
    cap = 0.3
    base = circle(4.0, 1.5)
    sh = ShapedReference(base, ShapingConfig(max_correction_m=cap),
                         max_tilt_rad=math.radians(45.0))
    sh.disturbance_ne = (-6.0, 0.0)
    refs = fly(sh, 20.0)
    bend = max(float(np.linalg.norm(r.pos_ned - base(t).pos_ned)) for t, r in refs)
    assert sh.failures > 0
    assert bend <= cap * 1.2


def test_a_solver_that_fails_to_load_leaves_the_plan_flown_as_planned() -> None:
    class Broken(ShapedReference):
        def _build_solver(self) -> object:
            raise RuntimeError("Plugin 'daqp' is not found")

    base = circle(3.0, 2.0)  # far past the limit: a bend would be wanted at once
    sh = Broken(base, max_tilt_rad=math.radians(45.0))
    refs = fly(sh, 10.0)
    assert sh.error is not None and "daqp" in sh.error
    for t, r in refs:
        assert np.array_equal(r.pos_ned, base(t).pos_ned)


def _max_jerk(refs: list[tuple[float, Reference]], t_from: float) -> float:
    return max(float(np.hypot(*r.jerk_ned[:2])) for t, r in refs if t >= t_from)


def test_a_bend_adds_no_jerk_the_plan_does_not_have() -> None:
    """Rates mode flies the reference's jerk as body rates: a bend that doubles it saturates
    PX4's rate limit (real PX4, light figure-8: 220 deg/s). The circle flown too fast, as the
    concentric test: the bend starts during the spin-up and settles at 0.25 m. With the jerk
    term the bent reference's jerk stays within 10 % of the plan's own largest (14.0 m/s^3: 13.8);
    without it the bend's onset adds 29 % (18.1 m/s^3; on the light figure-8, 100 %), so the
    check can fail."""
    radius, limit, margin, dm = 3.0, math.radians(45.0), math.radians(2.0), 1.25
    k = G * math.tan(limit - margin) / (radius - 0.25)
    omega = math.sqrt((-dm**2 + math.sqrt(dm**4 + 4 * k**2)) / 2)
    base = circle(radius, omega)
    plan = _max_jerk([(t, base(t)) for t in np.arange(0.0, 20.0, 0.01)], 0.0)
    got = {}
    for w3 in (ShapingConfig().jerk_weight, 0.0):
        cfg = ShapingConfig(margin_rad=margin, max_correction_m=1.0, jerk_weight=w3)
        sh = ShapedReference(base, cfg, max_tilt_rad=limit)
        sh.drag_per_kg = dm
        got[w3] = _max_jerk(fly(sh, 20.0), 0.0)
        assert sh.solves > 0
    assert ShapingConfig().jerk_weight > 0.0
    assert got[ShapingConfig().jerk_weight] < 1.1 * plan
    assert got[0.0] > 1.2 * plan
