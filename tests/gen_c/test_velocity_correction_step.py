"""The horizontal velocity correction's update step as generated C
(`ecca_velocity_correction_step`, double and float) against the Python step the companion runs
(companion.mavlink.velocity_correction on floats, the one `VelocityCorrection.update` calls):
random inputs (the update, both restarts, the clamp) and a recorded sequence of the companion's
filter on a velocity with a constant bias, fed back through the C step by step, whose correction
converges to minus the bias. Double to 1e-9, float to 1e-4 relative (scale max(|value|, 1))."""

from __future__ import annotations

import math

import numpy as np
import pytest

import companion.flatness._formulas as fm
from companion.mavlink.telemetry import VelocityCorrection
from companion.mavlink.velocity_correction import (
    DT_MAX_S,
    DT_MIN_S,
    POSITION_RESET_M,
    VCORR_INPUTS,
    VCORR_N_IN,
    VCORR_N_OUT,
    VELOCITY_CORRECTION_MAX_M_S,
    VELOCITY_CORRECTION_RAD_S,
    velocity_correction_step,
    velocity_correction_step_vector,
)
from gen_c import native
from tests.support.gen_c import assert_close

RTOL_DOUBLE = 1e-9
RTOL_FLOAT = 1e-4


def f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32).astype(np.float64)


def prediction(x: np.ndarray) -> tuple[float, float]:
    """The filter's predicted position (the step's, before the innovation)."""
    h = 0.5 * x[10]
    return (x[0] + (x[2] + x[8]) * h + x[4] * x[10], x[1] + (x[3] + x[9]) * h + x[5] * x[10])


def random_inputs(rng: np.random.Generator, n: int) -> np.ndarray:
    """Inputs of every branch (run or not, dt in and out of range, innovations below and
    beyond the reset distance, corrections driven into the clamp), away from the decisions'
    thresholds in dt (so float rounding cannot flip one; the reset's is checked per case)."""
    xs = np.empty((n, VCORR_N_IN))
    xs[:, 0:2] = rng.uniform(-20.0, 20.0, (n, 2))  # p_hat
    xs[:, 2:4] = rng.uniform(-8.0, 8.0, (n, 2))  # vel_prev
    xs[:, 8:10] = xs[:, 2:4] + rng.normal(0.0, 0.3, (n, 2))  # vel
    xs[:, 12] = rng.uniform(0.2, 2.0, n)  # max_corr
    xs[:, 4:6] = rng.uniform(-1.0, 1.0, (n, 2)) * xs[:, 12:13]  # corr, within its bound
    xs[:, 10] = np.where(rng.random(n) < 0.85, rng.uniform(2e-3, 0.2, n),
                         rng.choice([-0.01, 0.0, 5e-4, 0.6, 2.0], n))  # dt
    xs[:, 11] = rng.uniform(0.5, 12.0, n)  # omega (2 w dt beyond 1 too)
    xs[:, 13] = rng.uniform(0.5, 2.0, n)  # reset_m
    xs[:, 14] = (rng.random(n) < 0.8).astype(float)  # run
    # pos: the prediction plus an innovation, mostly inside the reset distance, some beyond
    for k in range(n):
        q = prediction(xs[k])
        scale = xs[k, 13] * (rng.uniform(0.0, 0.9) if rng.random() < 0.75
                             else rng.uniform(1.1, 4.0))
        ang = rng.uniform(0.0, 2.0 * math.pi)
        xs[k, 6:8] = (q[0] + scale * math.cos(ang), q[1] + scale * math.sin(ang))
    return xs


def python_step(x: np.ndarray) -> list[float]:
    return [float(v) for v in velocity_correction_step_vector(fm.FLOAT, x.tolist())]


def branch(x: np.ndarray) -> str:
    """Which branch the step takes on `x`: restart (run, dt), reset, clamp or update."""
    if not (x[14] > 0.5 and DT_MIN_S < x[10] < DT_MAX_S):
        return "restart"
    q = prediction(x)
    if math.hypot(x[6] - q[0], x[7] - q[1]) > x[13]:
        return "reset"
    b = x[11] * x[11] * x[10]
    free = (x[4] + b * (x[6] - q[0]), x[5] + b * (x[7] - q[1]))
    return "clamp" if max(abs(free[0]), abs(free[1])) > x[12] else "update"


def reset_margin(x: np.ndarray) -> float:
    """| |r| - reset_m | / reset_m: how far the reset's decision is from flipping."""
    q = prediction(x)
    return abs(math.hypot(x[6] - q[0], x[7] - q[1]) - x[13]) / x[13]


def test_the_layout_is_the_documented_one() -> None:
    assert [n for n, _ in VCORR_INPUTS] == ["p_hat", "vel_prev", "corr", "pos", "vel", "dt",
                                            "omega", "max_corr", "reset_m", "run"]
    assert (VCORR_N_IN, VCORR_N_OUT) == (15, 4)


def test_c_matches_python_on_random_inputs(lib: native.NativeSetpoint) -> None:
    xs = random_inputs(np.random.default_rng(20261201), 600)
    seen: dict[str, int] = {}
    for k, x in enumerate(xs):
        exp = python_step(x)
        assert_close(lib.velocity_correction_step(x), exp, RTOL_DOUBLE, f"double #{k}")
        xf = f32(x)
        if reset_margin(xf) > 1e-3:
            assert_close(lib.velocity_correction_step(xf, precision="float"), python_step(xf),
                         RTOL_FLOAT, f"float #{k}")
        b = branch(x)
        seen[b] = seen.get(b, 0) + 1
        if b in ("restart", "reset"):  # the sample's position, the correction held
            assert exp == [x[6], x[7], x[4], x[5]]
        if b == "clamp":
            assert max(abs(exp[2]), abs(exp[3])) == pytest.approx(x[12])
    assert all(seen.get(b, 0) >= 20 for b in ("restart", "reset", "clamp", "update")), seen


def _biased_flight(seconds: float, bias: tuple[float, float], rate_hz: float = 50.0
                   ) -> list[tuple[float, tuple[float, float], tuple[float, float],
                                   tuple[float, float]]]:
    """Samples (t, position, reported velocity, true velocity) of a vehicle on a 6 m/s
    figure-8 whose reported velocity is the true one plus `bias` [m/s] while its position
    moves with the true velocity."""
    w = 6.0 / 20.0
    out = []
    for k in range(int(seconds * rate_hz)):
        t = 3.0 + k / rate_hz
        p = (20.0 * math.sin(w * t), 10.0 * math.sin(2.0 * w * t))
        v = (20.0 * w * math.cos(w * t), 20.0 * w * math.cos(2.0 * w * t))
        out.append((t, p, (v[0] + bias[0], v[1] + bias[1]), v))
    return out


def test_c_follows_the_companion_s_filter_and_removes_a_velocity_bias(
        lib: native.NativeSetpoint) -> None:
    """The companion's VelocityCorrection on a velocity with a constant 0.4 m/s bias, and the C
    (double and float) carrying its own state from the same samples: the same corrections,
    which converge to minus the bias within 2 s at 4 rad/s (both poles at -4: the error decays
    as (1 + w t) e^-wt, 0.3 % at 2 s), so the corrected velocity is the position's rate."""
    bias = (0.4, -0.25)
    vc = VelocityCorrection()
    state_d: np.ndarray | None = None
    state_f: np.ndarray | None = None
    prev: tuple[float, tuple[float, float], tuple[float, float]] | None = None
    worst_after_2s = 0.0
    rate_err = 0.0
    samples = _biased_flight(10.0, bias)
    for t, p, v, _ in samples:
        c = vc.update(t, (p[0], p[1], -5.0), (v[0], v[1], 0.0))
        run = prev is not None
        dt = t - prev[0] if prev is not None else 0.0
        v0 = prev[2] if prev is not None else (0.0, 0.0)
        tail = [*p, *v, dt, VELOCITY_CORRECTION_RAD_S, VELOCITY_CORRECTION_MAX_M_S,
                POSITION_RESET_M, 1.0 if run else 0.0]
        xd = np.array([*(state_d[0:2] if state_d is not None else (0.0, 0.0)), *v0,
                       *(state_d[2:4] if state_d is not None else (0.0, 0.0)), *tail])
        xf = np.array([*(state_f[0:2] if state_f is not None else (0.0, 0.0)), *v0,
                       *(state_f[2:4] if state_f is not None else (0.0, 0.0)), *tail])
        state_d = lib.velocity_correction_step(xd)
        state_f = lib.velocity_correction_step(f32(xf), precision="float")
        assert_close(state_d[2:4], c[0:2], RTOL_DOUBLE, f"double at t={t:.2f}")
        assert_close(state_f[2:4], c[0:2], 1e-3, f"float at t={t:.2f}")
        if t >= samples[0][0] + 2.0:
            worst_after_2s = max(worst_after_2s, math.hypot(c[0] + bias[0], c[1] + bias[1]))
            # the corrected velocity against the position's rate over the last interval
            # (the chord's velocity: the mean of the two true velocities, to O(dt^2))
            assert prev is not None
            rate = ((p[0] - prev[1][0]) / dt, (p[1] - prev[1][1]) / dt)
            rate_err = max(rate_err, math.hypot(v[0] + c[0] - rate[0], v[1] + c[1] - rate[1]))
        prev = (t, p, v)
    assert worst_after_2s < 0.01
    assert rate_err < 0.05  # the rate's own difference from the velocity: a dt / 2 < 0.04


def test_the_branches_without_update(lib: native.NativeSetpoint) -> None:
    x = np.array([1.0, 2.0, 0.5, -0.5, 0.3, -0.4, 1.01, 1.99, 0.5, -0.5, 0.02, 4.0, 1.0, 1.0,
                  0.0])
    assert lib.velocity_correction_step(x).tolist() == [1.01, 1.99, 0.3, -0.4]  # not running
    for dt in (0.0, -0.1, DT_MIN_S, DT_MAX_S, 3.0):  # a gap or a clock jump: restart, hold
        x2 = x.copy()
        x2[10], x2[14] = dt, 1.0
        assert lib.velocity_correction_step(x2).tolist() == [1.01, 1.99, 0.3, -0.4]
    x3 = x.copy()  # an estimator reset: a position 1.5 m from the prediction
    x3[6], x3[14] = 1.0 + 0.02 * (0.5 + 0.3) + 1.5, 1.0
    assert lib.velocity_correction_step(x3).tolist() == [x3[6], 1.99, 0.3, -0.4]
    x3[6] -= 1.0  # 0.5 m: an update
    out = lib.velocity_correction_step(x3).tolist()
    assert out[2] > 0.3 and out[3] != -0.4
    assert out == pytest.approx(python_step(x3), rel=1e-12)
    assert velocity_correction_step(fm.FLOAT, x3[0:2], x3[2:4], x3[4:6], x3[6:8], x3[8:10],
                                    0.02, 4.0, 1.0, 1.0, False) == ((x3[6], x3[7]), (0.3, -0.4))


@pytest.mark.parametrize("index", [0, 4, 6, 10, 14])
@pytest.mark.parametrize("bad", [math.nan, math.inf, 1e13])
def test_refuses_invalid_inputs(lib: native.NativeSetpoint, index: int, bad: float) -> None:
    x = np.array([1.0, 2.0, 0.5, -0.5, 0.3, -0.4, 1.01, 1.99, 0.5, -0.5, 0.02, 4.0, 1.0, 1.0,
                  1.0])
    x[index] = bad
    with pytest.raises(ValueError):
        lib.velocity_correction_step(x)


@pytest.mark.parametrize("index", [11, 12, 13])
def test_refuses_a_non_positive_frequency_bound_or_reset_distance(lib: native.NativeSetpoint,
                                                                  index: int) -> None:
    x = np.array([1.0, 2.0, 0.5, -0.5, 0.3, -0.4, 1.01, 1.99, 0.5, -0.5, 0.02, 4.0, 1.0, 1.0,
                  1.0])
    x[index] = 0.0
    with pytest.raises(ValueError):
        lib.velocity_correction_step(x)
