"""Wind gusts of the mock quadrotor (SIM_WIND_GUST, SIM_WIND_GUST_T): a stationary first-order
Gauss-Markov process (oracle: its standard deviation and its autocorrelation exp(-lag / T)),
seeded, on its own random stream, and felt by the airframe through the drag."""

from __future__ import annotations

import math

import numpy as np

from sitl_mock.params import ParamStore
from sitl_mock.quad import Quadrotor
from sitl_mock.setpoints import IdleTarget

DT = 0.004


def _winds(params: dict[str, float], seconds: float, seed: int = 0,
           steady: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> np.ndarray:
    q = Quadrotor(ParamStore(params), seed=seed)
    q.set_wind(steady)
    out = []
    for k in range(int(seconds / DT)):
        q.step(DT, IdleTarget(), False)
        if k % 5 == 0:  # every 0.02 s
            out.append(q.wind)
    return np.asarray(out)


def test_gust_std_and_correlation_time_match_the_parameters() -> None:
    std, tau = 1.5, 0.4
    w = _winds({"SIM_WIND_GUST": std, "SIM_WIND_GUST_T": tau}, 300.0, seed=3)[250:]
    lag = round(tau / 0.02)
    for axis, expected in ((0, std), (1, std), (2, 0.5 * std)):
        x = w[:, axis] - w[:, axis].mean()
        assert abs(x.std() / expected - 1.0) < 0.15, (axis, x.std())
        rho = float(np.dot(x[:-lag], x[lag:]) / np.dot(x, x))
        assert abs(rho - math.exp(-1.0)) < 0.12, (axis, rho)


def test_gusts_add_to_the_steady_wind_and_are_seeded() -> None:
    p = {"SIM_WIND_GUST": 1.0}
    a = _winds(p, 20.0, seed=1, steady=(3.0, -2.0, 0.0))
    assert np.array_equal(a, _winds(p, 20.0, seed=1, steady=(3.0, -2.0, 0.0)))
    assert not np.array_equal(a, _winds(p, 20.0, seed=2, steady=(3.0, -2.0, 0.0)))
    assert abs(a[:, 0].mean() - 3.0) < 1.0 and abs(a[:, 1].mean() + 2.0) < 1.0
    assert a[:, 0].std() > 0.2


def test_without_gusts_the_wind_is_exactly_the_steady_wind() -> None:
    w = _winds({}, 5.0, steady=(2.0, 1.0, 0.0))
    assert np.all(w == np.array([2.0, 1.0, 0.0]))


def test_gusts_push_an_unpowered_airframe() -> None:
    """The drag sees the gust: a vehicle dropped in still air falls straight down, with gusts
    it drifts sideways."""
    def drift(params: dict[str, float]) -> float:
        q = Quadrotor(ParamStore(params), seed=5)
        q.set_state(pos_ned=(0.0, 0.0, -500.0))
        for _ in range(int(3.0 / DT)):
            q.step(DT, IdleTarget(), True)
        n, e, _ = q.state.pos_ned
        return math.hypot(n, e)

    assert drift({}) == 0.0
    assert drift({"SIM_WIND_GUST": 2.0, "SIM_WIND_GUST_T": 0.5}) > 0.05
