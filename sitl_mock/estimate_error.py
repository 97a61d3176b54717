"""Estimator error like EKF2's on SIH: slowly varying Gauss-Markov errors, shared by the vehicles.

PX4 steers by EKF2's estimate, which on SIH's simulated GPS wanders off the truth by decimetres
(position), decimetres per second (velocity) and degrees (the rover's heading), each varying over
seconds. The mock models each error channel as white noise through two first-order lags of one
time constant (a second-order Gauss-Markov process), scaled to a stationary standard deviation;
channels are independent of each other (as measured on PX4 SITL). The quadrotor
(quad_physics.py) and the rover (rover.py) advance their channels with `advance_gauss_markov`
from their own random stream, and add the errors to what their controllers and the telemetry
see; their truth stays available (`true_state`, HIL_STATE_QUATERNION on request).

Besides the random part EKF2's position estimate on SIH leads the truth along the motion by
~0.1 s of travel (measured on PX4 main's rover: 0.10-0.13 s in every speed band from 0.5 to
3.5 m/s; most likely EKF2 taking SIH's GPS, which has no delay, for EKF2_GPS_DELAY old). The rover
models it as the true velocity times SIM_EST_LEAD_S added to the position estimate. Its heading
estimate also carries an offset for a whole PX4 start (-4.9 to +3.1 deg over six flights, RMS
3.0 deg): one draw per vehicle, std SIM_EST_YAW_BIAS [deg].

Parameters (mock-only names, sitl_mock/params.py): SIM_EST_XY_STD [m], SIM_EST_VXY_STD [m/s],
SIM_EST_XY_TAU [s] (horizontal position / velocity, per axis); SIM_EST_YAW_STD [deg],
SIM_EST_YAW_TAU [s], SIM_EST_YAW_BIAS [deg], SIM_EST_LEAD_S [s] (the rover only). All 0 by
default: the estimate is the truth.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence


def advance_gauss_markov(state: list[float], stds: Sequence[float], tau_s: float, dt_s: float,
                         gauss: Callable[[float, float], float]) -> None:
    """Advance second-order Gauss-Markov channels by `dt_s` [s] in place (exact discretisation).

    `state` holds one (driving state, error) pair per channel: [d0, e0, d1, e1, ...]; channel j
    has the stationary error std `stds[j]` (the driving state's is sqrt(2) times larger: a
    first-order lag halves the variance of what it filters) and both lags the time constant
    `tau_s` [s]. `gauss(mu, sigma)` draws one normal sample per channel, in channel order."""
    a = math.exp(-dt_s / tau_s)
    k = math.sqrt(2.0) * math.sqrt(1.0 - a * a)  # var(lagged) = var(driving) / 2
    for j, std in enumerate(stds):
        i = 2 * j
        s = a * state[i] + k * std * gauss(0.0, 1.0)
        state[i] = s
        state[i + 1] = a * state[i + 1] + (1.0 - a) * s


def horizontal_config(p: Mapping[str, float]) -> tuple[float, float, float]:
    """(position std [m], velocity std [m/s], time constant [s]) of the horizontal errors, as
    SIM_EST_XY_STD, SIM_EST_VXY_STD, SIM_EST_XY_TAU give them (stds >= 0, tau >= 0.05 s)."""
    return (max(p["SIM_EST_XY_STD"], 0.0), max(p["SIM_EST_VXY_STD"], 0.0),
            max(p["SIM_EST_XY_TAU"], 0.05))


def lead_config(p: Mapping[str, float]) -> float:
    """How far the position estimate leads the truth [s of travel], SIM_EST_LEAD_S (>= 0)."""
    return max(p["SIM_EST_LEAD_S"], 0.0)


def yaw_bias_config(p: Mapping[str, float]) -> float:
    """Std [rad] of the per-start heading bias, from SIM_EST_YAW_BIAS [deg] (>= 0)."""
    return math.radians(max(p["SIM_EST_YAW_BIAS"], 0.0))


def yaw_config(p: Mapping[str, float]) -> tuple[float, float]:
    """(heading std [rad], time constant [s]) from SIM_EST_YAW_STD [deg], SIM_EST_YAW_TAU [s]."""
    return math.radians(max(p["SIM_EST_YAW_STD"], 0.0)), max(p["SIM_EST_YAW_TAU"], 0.05)
