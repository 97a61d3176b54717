"""Fast paths of the time allocation's limit checks, against independent evaluations: the
fixed-grid segment sampler against each segment's own de Casteljau evaluation, the cheap
body-rate bound against the flatness module's |omega_frd| (and scipy's rotation algebra), the
screened per-segment worst values against the unscreened ones, and the chunked matrix product
against a plain one."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.trajectory import Limits, PiecewiseBezier, plan
from companion.trajectory.limits import (
    Samples,
    TimeScaledRatio,
    body_rate_bound,
    segment_samples,
    segment_worst,
    thin_matmul,
)

G = 9.80665
PARAMS = MultirotorParams(mass=1.5, inertia=np.diag([0.03, 0.03, 0.05]), drag=0.4)
MG = PARAMS.mass * G
LIMITS = Limits(
    max_speed_m_s=5.0,
    max_acc_m_s2=4.0,
    max_jerk_m_s3=30.0,
    max_tilt_rad=0.4,
    max_thrust_n=1.5 * MG,
    min_thrust_n=0.6 * MG,
    max_body_rate_rad_s=3.0,
)


def _trajectory(seed: int) -> PiecewiseBezier:
    rng = np.random.default_rng(seed)
    wp = np.cumsum(rng.normal(size=(7, 3)) * [4.0, 4.0, 1.0], axis=0)
    yaw = np.cumsum(rng.uniform(-2.0, 2.0, 7))
    return plan(wp, durations=rng.uniform(0.6, 3.0, 6), yaw=yaw)


@pytest.mark.parametrize("seed", range(3))
def test_grid_samples_match_each_segments_own_evaluation(seed: int) -> None:
    tr = _trajectory(seed)
    per = 11
    smp = segment_samples(tr, LIMITS, per)
    tau = np.linspace(0.0, 1.0, per)
    assert tr.yaw is not None
    for k, (seg, yseg) in enumerate(zip(tr.segments, tr.yaw.segments, strict=True)):
        t = tau * seg.duration
        rows = slice(k * per, (k + 1) * per)
        for order, got in ((1, smp.vel), (2, smp.acc), (3, smp.jerk), (4, smp.snap)):
            assert got is not None
            want = seg.evaluate(t, order)
            np.testing.assert_allclose(got[rows], want, rtol=1e-9, atol=1e-9 * np.max(abs(want)))
        for order, got_y in ((0, smp.yaw), (1, smp.yaw_rate), (2, smp.yaw_acc)):
            want_y = yseg.evaluate(t, order)[:, 0]
            np.testing.assert_allclose(got_y[rows], want_y, rtol=1e-9, atol=1e-9)


def _random_samples(rng: np.random.Generator, n: int) -> Samples:
    """Flat-output samples with large horizontal accelerations (tilts up to ~80 deg), climbs
    and dives, jerks and yaw motion, to exercise the bound well away from hover."""
    acc = rng.normal(size=(n, 3)) * [12.0, 12.0, 4.0]
    return Samples(
        vel=rng.normal(size=(n, 3)) * 5.0,
        acc=acc,
        jerk=rng.normal(size=(n, 3)) * 20.0,
        snap=rng.normal(size=(n, 3)) * 50.0,
        yaw=rng.uniform(-np.pi, np.pi, n),
        yaw_rate=rng.normal(size=n) * 1.5,
        yaw_acc=rng.normal(size=n),
    )


def test_body_rate_bound_is_an_upper_bound_of_the_flatness_body_rate() -> None:
    rng = np.random.default_rng(7)
    smp = _random_samples(rng, 20000)
    sp = multirotor_setpoint(
        smp.vel, smp.acc, smp.jerk, smp.snap, smp.yaw, smp.yaw_rate, smp.yaw_acc, PARAMS
    )
    exact = np.linalg.norm(sp.omega_frd, axis=1)
    bound = body_rate_bound(smp, PARAMS)
    assert np.all(bound >= exact * (1.0 - 1e-12))
    finite = np.isfinite(bound)
    assert finite.mean() > 0.99
    # not vacuous: with no yaw rate and a level-ish thrust the bound is nearly tight
    assert np.median((bound / np.maximum(exact, 1e-9))[finite & (exact > 0.1)]) < 3.0


def test_body_rate_bound_against_rotation_derivatives() -> None:
    """Independent oracle: the body rate from finite differences of the attitude (scipy
    Rotation) of the flatness setpoints along a smooth trajectory stays below the bound."""
    tr = _trajectory(11)
    t = np.linspace(0.0, tr.duration, 4001)
    assert tr.yaw is not None
    smp = Samples(
        tr.evaluate(t, 1),
        tr.evaluate(t, 2),
        tr.evaluate(t, 3),
        tr.evaluate(t, 4),
        tr.yaw.evaluate(t, 0)[:, 0],
        tr.yaw.evaluate(t, 1)[:, 0],
        tr.yaw.evaluate(t, 2)[:, 0],
    )
    sp = multirotor_setpoint(
        smp.vel, smp.acc, smp.jerk, smp.snap, smp.yaw, smp.yaw_rate, smp.yaw_acc, PARAMS
    )
    rot = Rotation.from_quat(np.asarray(sp.q_wxyz)[:, [1, 2, 3, 0]])
    dt = t[1] - t[0]
    rate = np.linalg.norm((rot[:-1].inv() * rot[1:]).as_rotvec(), axis=1) / dt
    bound = body_rate_bound(smp, PARAMS)
    mid_bound = np.maximum(bound[:-1], bound[1:])
    # finite-difference rate over one step is the mean rate: below the larger end bound + O(dt)
    assert np.all(rate <= mid_bound * (1.0 + 1e-3) + 1e-3)


def test_screened_worst_values_agree_with_the_unscreened_ones() -> None:
    tr = _trajectory(5)
    smp = segment_samples(tr, LIMITS, 16)
    lim = Limits(max_speed_m_s=5.0, max_acc_m_s2=4.0, max_body_rate_rad_s=1.0)
    full = segment_worst(smp, tr.num_segments, lim, PARAMS)["body_rate"]
    # a limit between the segments' worst values, so that some segments are screened out
    screen = 0.995
    limit = float(np.median(full)) / screen
    lim = Limits(max_speed_m_s=5.0, max_acc_m_s2=4.0, max_body_rate_rad_s=limit)
    scr = segment_worst(smp, tr.num_segments, lim, PARAMS, screen=screen)["body_rate"]
    thr = screen * limit
    assert np.any(full > thr) and np.any(full <= thr)  # both cases are exercised
    above = full > thr
    np.testing.assert_allclose(scr[above], full[above], rtol=1e-12)
    assert np.all(scr[~above] <= thr)
    assert np.all(scr[~above] >= full[~above] * (1.0 - 1e-12))


def test_thin_matmul_equals_the_plain_product() -> None:
    rng = np.random.default_rng(3)
    a = rng.normal(size=(192, 8))
    b = rng.normal(size=(8, 5001))  # several chunks and a ragged last one
    np.testing.assert_allclose(thin_matmul(a, b), a @ b, rtol=1e-13, atol=1e-12)
    small = rng.normal(size=(8, 10))
    np.testing.assert_allclose(thin_matmul(a, small), a @ small, rtol=1e-13, atol=1e-12)


@pytest.mark.parametrize("rate_limit", [0.5, 3.0, 50.0])
def test_time_scaled_ratio_matches_resampling_the_slowed_trajectory(rate_limit: float) -> None:
    """The common-scale search's ratio(alpha) against the slowed-down trajectory itself
    (durations alpha h, re-planned, sampled and checked through the flatness module)."""
    rng = np.random.default_rng(2)
    wp = np.cumsum(rng.normal(size=(6, 3)) * [4.0, 4.0, 1.0], axis=0)
    h = rng.uniform(0.8, 2.5, 5)
    yaw = np.cumsum(rng.uniform(-1.0, 1.0, 6))
    lim = Limits(
        max_speed_m_s=5.0,
        max_acc_m_s2=4.0,
        max_jerk_m_s3=30.0,
        max_tilt_rad=0.4,
        max_thrust_n=1.5 * MG,
        min_thrust_n=0.6 * MG,
        max_body_rate_rad_s=rate_limit,
    )
    margin = 0.995
    per = 16
    ratio = TimeScaledRatio(
        segment_samples(plan(wp, durations=h, yaw=yaw), lim, per), lim, PARAMS, margin
    )
    for alpha in (0.7, 1.0, 1.6, 3.0):
        slow = plan(wp, durations=alpha * h, yaw=yaw)
        smp = segment_samples(slow, lim, per)
        sp = multirotor_setpoint(
            smp.vel, smp.acc, smp.jerk, smp.snap, smp.yaw, smp.yaw_rate, smp.yaw_acc, PARAMS
        )
        tv = -PARAMS.mass * smp.acc - PARAMS.drag * smp.vel
        tv[:, 2] += MG
        thrust = np.linalg.norm(tv, axis=1)
        want = (
            max(
                np.max(np.linalg.norm(smp.vel, axis=1)) / 5.0,
                np.max(np.linalg.norm(smp.acc, axis=1)) / 4.0,
                np.max(np.linalg.norm(smp.jerk, axis=1)) / 30.0,
                np.max(np.arccos(tv[:, 2] / thrust)) / 0.4,
                np.max(thrust) / (1.5 * MG),
                0.6 * MG / np.min(thrust),
                np.max(np.linalg.norm(sp.omega_frd, axis=1)) / rate_limit,
            )
            / margin
        )
        got = ratio(alpha)
        if got > 1.0 or want > 1.0:
            # above the limit the value is exact (the body-rate bound is only used below it)
            assert got == pytest.approx(want, rel=1e-7)
        else:
            assert want <= got <= 1.0 + 1e-12
