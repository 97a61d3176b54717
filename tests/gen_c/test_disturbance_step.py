"""The disturbance observer's update step as generated C (`ecca_disturbance_step`, double and
float) against the Python step the companion runs (companion.control.observer on floats, the
one `DisturbanceObserver.update` calls): random inputs (both branches, the magnitude bound), a
recorded sequence of an observer that converges on a constant force, fed back through the C
step by step, and the inputs the companion's observer had in a replayed flight in wind. Double
to 1e-9, float to 1e-4 relative (scale max(|value|, 1))."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import companion.flatness._formulas as fm
from companion.control.estimation import DisturbanceConfig, DisturbanceObserver
from companion.control.observer import (
    DIST_INPUTS,
    DIST_N_IN,
    DIST_N_OUT,
    DT_MAX_S,
    disturbance_step,
    disturbance_step_vector,
)
from gen_c import native
from tests.support.gen_c import assert_close

ROOT = Path(__file__).resolve().parents[2]
RTOL_DOUBLE = 1e-9
RTOL_FLOAT = 1e-4


def f32(x: np.ndarray) -> np.ndarray:
    return x.astype(np.float32).astype(np.float64)


def random_inputs(rng: np.random.Generator, n: int) -> np.ndarray:
    """Inputs of both branches (learn, dt in and out of range) and of the bound, away from
    the decisions' thresholds (so float rounding cannot flip one)."""
    xs = np.empty((n, DIST_N_IN))
    xs[:, 0:2] = rng.uniform(-8.0, 8.0, (n, 2))  # v_hat
    xs[:, 2:4] = rng.uniform(-4.0, 4.0, (n, 2))  # d_hat
    xs[:, 4:6] = xs[:, 0:2] + rng.normal(0.0, 0.5, (n, 2))  # vel
    xs[:, 6:8] = rng.uniform(-6.0, 6.0, (n, 2))  # a_model
    xs[:, 8] = np.where(rng.random(n) < 0.85, rng.uniform(1e-3, 0.1, n),
                        rng.choice([-0.01, 0.0, 0.6, 2.0], n))  # dt
    xs[:, 9] = rng.uniform(0.3, 6.0, n)  # bandwidth (2 w dt beyond 1 too)
    xs[:, 10] = rng.uniform(0.5, 8.0, n)  # max_acc
    xs[:, 11] = (rng.random(n) < 0.8).astype(float)  # learn
    return xs


def python_step(x: np.ndarray) -> list[float]:
    return [float(v) for v in disturbance_step_vector(fm.FLOAT, x.tolist())]


def bound_margin(x: np.ndarray) -> float:
    """|n - max_acc| / max_acc of the update's unbounded estimate (the bound's decision)."""
    _, d = disturbance_step(fm.FLOAT, x[0:2], x[2:4], x[4:6], x[6:8], x[8], x[9], 1e300,
                            True)
    return abs(math.hypot(*d) - x[10]) / x[10]


def test_the_layout_is_the_documented_one() -> None:
    assert [n for n, _ in DIST_INPUTS] == ["v_hat", "d_hat", "vel", "a_model", "dt",
                                           "bandwidth", "max_acc", "learn"]
    assert (DIST_N_IN, DIST_N_OUT) == (12, 4)


def test_c_matches_python_on_random_inputs(lib: native.NativeSetpoint) -> None:
    xs = random_inputs(np.random.default_rng(20261130), 400)
    bounded = 0
    for k, x in enumerate(xs):
        exp = python_step(x)
        assert_close(lib.disturbance_step(x), exp, RTOL_DOUBLE, f"double #{k}")
        xf = f32(x)
        if bound_margin(xf) > 1e-3:
            assert_close(lib.disturbance_step(xf, precision="float"), python_step(xf),
                         RTOL_FLOAT, f"float #{k}")
        bounded += math.hypot(exp[2], exp[3]) == pytest.approx(x[10]) and x[11] > 0.5
    assert bounded >= 20  # the magnitude bound acted on some


def test_c_follows_a_recorded_observer_sequence(lib: native.NativeSetpoint) -> None:
    """The Python observer on a point mass in a constant wind force (its velocity from the
    model plus d, with noise), recorded, and the C fed its own outputs back: the same
    estimates, converged on d."""
    d_true = (0.9, -0.6)
    cfg = DisturbanceConfig()
    obs = DisturbanceObserver(cfg)
    rng = np.random.default_rng(7)
    dt, v, t = 0.02, np.array([1.0, 0.5]), 0.0
    xs: list[np.ndarray] = []
    state_d: np.ndarray | None = None
    state_f: np.ndarray | None = None
    for _ in range(600):
        a_model = np.array([-0.3 * v[0] + 0.2 * math.sin(t), -0.3 * v[1] - 0.1])
        v = v + (a_model + d_true) * dt
        t += dt
        vel = v + rng.normal(0.0, 0.01, 2)
        v_before, d_before = obs._v, obs.acc_ne
        obs.update(t, (float(vel[0]), float(vel[1])), (float(a_model[0]), float(a_model[1])),
                   0.5, True)
        if v_before is None:
            continue
        x = np.array([*v_before, *d_before, *vel, *a_model, dt, cfg.bandwidth_rad_s,
                      cfg.max_acc, 1.0])
        xs.append(x)
        # the C carries its own state from the first recorded input on
        xd = x.copy() if state_d is None else np.concatenate([state_d, x[4:]])
        xf = f32(x) if state_f is None else f32(np.concatenate([state_f, x[4:]]))
        state_d = lib.disturbance_step(xd)
        state_f = lib.disturbance_step(xf, precision="float")
        assert_close(state_d, [*obs._v, *obs.acc_ne], RTOL_DOUBLE, f"double at t={t:.2f}")
        assert_close(state_f, [*obs._v, *obs.acc_ne], 1e-3, f"float at t={t:.2f}")
    assert len(xs) >= 500
    assert obs.acc_ne == pytest.approx(d_true, abs=0.05)


def test_the_branches_without_update(lib: native.NativeSetpoint) -> None:
    x = np.array([1.0, 2.0, 0.3, -0.4, 1.5, 2.5, 0.1, 0.2, 0.02, 1.5, 8.0, 0.0])
    assert lib.disturbance_step(x).tolist() == [1.5, 2.5, 0.3, -0.4]  # not learning
    for dt in (0.0, -0.1, DT_MAX_S, 3.0):  # a gap or a clock jump: follow, hold
        x2 = x.copy()
        x2[8], x2[11] = dt, 1.0
        assert lib.disturbance_step(x2).tolist() == [1.5, 2.5, 0.3, -0.4]


@pytest.mark.parametrize("index", [0, 4, 8, 11])
@pytest.mark.parametrize("bad", [math.nan, math.inf, 1e13])
def test_refuses_invalid_inputs(lib: native.NativeSetpoint, index: int, bad: float) -> None:
    x = np.array([1.0, 2.0, 0.3, -0.4, 1.5, 2.5, 0.1, 0.2, 0.02, 1.5, 8.0, 1.0])
    x[index] = bad
    with pytest.raises(ValueError):
        lib.disturbance_step(x)


@pytest.mark.parametrize("index", [9, 10])
def test_refuses_a_non_positive_bandwidth_or_bound(lib: native.NativeSetpoint,
                                                   index: int) -> None:
    x = np.array([1.0, 2.0, 0.3, -0.4, 1.5, 2.5, 0.1, 0.2, 0.02, 1.5, 8.0, 1.0])
    x[index] = 0.0
    with pytest.raises(ValueError):
        lib.disturbance_step(x)


def test_c_matches_the_companion_s_observer_in_a_replayed_flight_in_wind(
        lib: native.NativeSetpoint, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The inputs the companion's `DisturbanceObserver` gave the step in a streamed replay of
    px4_short in a 3 m/s wind with gusts, recorded, through the C: the same outputs."""
    import companion.control.estimation as estimation
    from companion.replay.config import ReplayConfig
    from companion.replay.runner import replay_file

    calls: list[tuple[np.ndarray, list[float]]] = []

    def record(ops: Any, v_hat: Any, d_hat: Any, vel: Any, a_model: Any, dt: float, w: float,
               max_acc: float, learn: bool) -> Any:
        out = disturbance_step(ops, v_hat, d_hat, vel, a_model, dt, w, max_acc, learn)
        x = np.array([*v_hat, *d_hat, *vel, *a_model, dt, w, max_acc, float(learn)])
        calls.append((x, [*out[0], *out[1]]))
        return out

    monkeypatch.setattr(estimation, "disturbance_step", record)
    res = replay_file(ROOT / "tests" / "data" / "missions" / "px4_short.plan", tmp_path,
                      ReplayConfig(wind_m_s=3.0, seed=2,
                                   mock_params=(("SIM_WIND_GUST", 1.0),)))
    assert res.ok
    learning = [c for c in calls if c[0][11] > 0.5]
    assert len(learning) >= 300
    assert max(math.hypot(y[2], y[3]) for _, y in learning) > 1.0  # it learnt the wind
    for k, (x, y) in enumerate(calls):
        assert_close(lib.disturbance_step(x), y, RTOL_DOUBLE, f"double #{k}")
        xf = f32(x)
        if x[11] > 0.5 and bound_margin(xf) > 1e-3:
            assert_close(lib.disturbance_step(xf, precision="float"), python_step(xf),
                         RTOL_FLOAT, f"float #{k}")
