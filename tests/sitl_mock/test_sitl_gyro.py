"""The mock's gyro pipeline and offboard control-mode switch, modelled on PX4 v1.16 + SIH.

- SIH adds white gyro noise per sample while the rotors push; PX4's vehicle_angular_velocity
  low-passes it (IMU_GYRO_CUTOFF, second-order Butterworth) for the rate loop and ATTITUDE, and
  low-passes its derivative (IMU_DGYRO_CUTOFF) for the D term. Oracle: scipy.signal's
  Butterworth design and lfilter.
- A change of the offboard attitude-target kind (attitude <-> body rates) reaches the controllers
  at the next tick of PX4's 2 Hz control-mode republish, not at once: the rates stay held after
  switching back to attitude.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from sitl_mock.flight_control import AngularVelocityFilter
from sitl_mock.params import ParamStore
from sitl_mock.quad import SIH_GYRO_NOISE, SIH_IMU_PERIOD_S, Quadrotor
from sitl_mock.setpoints import AttitudeTarget, IdleTarget

LEVEL = (1.0, 0.0, 0.0, 0.0)


@pytest.mark.parametrize(("fs", "fc", "fdc"), [(250.0, 40.0, 30.0), (500.0, 80.0, 20.0)])
def test_angular_velocity_filter_is_a_butterworth_low_pass_of_rate_and_derivative(
    fs: float, fc: float, fdc: float
) -> None:
    rng = np.random.default_rng(3)
    x = np.cumsum(rng.normal(0.0, 0.05, (400, 3)), axis=0) + rng.normal(0.0, 0.1, (400, 3))
    f = AngularVelocityFilter()
    f.reset(tuple(x[0]))  # type: ignore[arg-type]
    out = [f.update(tuple(row), 1.0 / fs, fc, fdc) for row in x]  # type: ignore[arg-type]
    rates = np.array([o[0] for o in out])
    accel = np.array([o[1] for o in out])
    b, a = signal.butter(2, fc, fs=fs)
    bd, ad = signal.butter(2, fdc, fs=fs)
    deriv = np.vstack([np.zeros(3), np.diff(x, axis=0) * fs])
    for i in range(3):
        want = signal.lfilter(b, a, x[:, i], zi=signal.lfilter_zi(b, a) * x[0, i])[0]
        np.testing.assert_allclose(rates[:, i], want, atol=1e-9)
        np.testing.assert_allclose(accel[:, i], signal.lfilter(bd, ad, deriv[:, i]), atol=1e-7)


def test_cutoff_zero_or_above_nyquist_passes_the_gyro_through() -> None:
    f = AngularVelocityFilter()
    f.reset((0.0, 0.0, 0.0))
    for cut in (0.0, 125.0, 400.0):
        r, _a = f.update((0.3, -0.2, 0.1), 0.004, cut, cut)
        assert r == (0.3, -0.2, 0.1)
        f.reset((0.0, 0.0, 0.0))


def _hover_attitude(p: ParamStore, seconds: float, dt: float = 0.004) -> tuple[
        np.ndarray, np.ndarray]:
    """Hover on a level attitude target; (measured, true) roll rates every step after 1 s."""
    v = Quadrotor(p, seed=2)
    v.set_state(pos_ned=(0.0, 0.0, -50.0), motors=0.49)
    v.mark_airborne(0.49)
    tgt = AttitudeTarget(q_wxyz=LEVEL, thrust_norm=0.49)
    meas, true = [], []
    for k in range(round(seconds / dt)):
        v.step(dt, tgt, True)
        if k * dt >= 1.0:
            meas.append(v.attitude[1][0])
            true.append(v.state.omega_frd[0])
    return np.array(meas), np.array(true)


@pytest.mark.parametrize("dt", [0.004, 0.001])
def test_sih_gyro_noise_reaches_the_reported_rates_through_the_filter(dt: float) -> None:
    """At hover the reported roll rate carries SIH's 0.14 rad/s per 250 Hz sample through the
    40 Hz low-pass (std = 0.14 * the filter's noise gain, independent of the physics rate);
    the true roll rate moves far less, and without the noise the two agree."""
    meas, true = _hover_attitude(ParamStore(), 8.0, dt)
    b, a = signal.butter(2, 40.0, fs=1.0 / SIH_IMU_PERIOD_S)
    _t, h = signal.dimpulse((b, a, SIH_IMU_PERIOD_S), n=400)
    expected = SIH_GYRO_NOISE[0] * math.sqrt(float(np.sum(np.square(h[0]))))
    noise = meas - true
    assert np.std(noise) == pytest.approx(expected, rel=0.2)
    assert np.std(true) < 0.5 * np.std(meas)
    quiet, quiet_true = _hover_attitude(ParamStore({"SIM_GYRO_SIH": 0.0}), 3.0, dt)
    assert np.max(np.abs(quiet - quiet_true)) < 1e-3


def test_gyro_is_the_true_rate_while_idle() -> None:
    v = Quadrotor(ParamStore(), seed=0)
    v.set_state(pos_ned=(0.0, 0.0, -100.0), omega_frd=(0.4, -0.2, 0.1))
    for _ in range(50):
        v.step(0.004, IdleTarget(), False)
        assert v.attitude[1] == v.state.omega_frd


def _switch_flight(phase_s: float) -> tuple[float, float]:
    """Level attitude, then -1 rad/s roll-rate setpoints, then level again (50 Hz messages):
    (time the true roll rate needs to reach -0.5 rad/s after the first rates setpoint, time
    it keeps below -0.5 rad/s after the first attitude setpoint) [s]."""
    v = Quadrotor(ParamStore({"SIM_GYRO_SIH": 0.0}), seed=0)
    v.set_state(pos_ned=(0.0, 0.0, -50.0), motors=0.49)
    v.mark_airborne(0.49)
    dt, t = 0.004, 0.0
    t_rates, t_back, t_end = 1.0 + phase_s, 1.8 + phase_s, 2.6 + phase_s
    rise = held = math.nan
    tgt = AttitudeTarget(q_wxyz=LEVEL, thrust_norm=0.49)
    for k in range(round(t_end / dt)):
        t = k * dt
        if k % 5 == 0:  # a new message every 20 ms
            if t_rates <= t < t_back:
                tgt = AttitudeTarget(q_wxyz=None, thrust_norm=0.49, body_rates_frd=(-1.0, 0, 0))
            else:
                tgt = AttitudeTarget(q_wxyz=LEVEL, thrust_norm=0.49)
        v.step(dt, tgt, True)
        p = v.state.omega_frd[0]
        if t >= t_rates and math.isnan(rise) and p <= -0.5:
            rise = t - t_rates
        if t >= t_back and math.isnan(held) and p > -0.5:
            held = t - t_back
    return rise, held


def test_switching_between_attitude_and_rates_takes_effect_at_the_control_mode_tick() -> None:
    """PX4 v1.16: after switching back from rates to attitude setpoints the rate stays at the
    rates setpoint until the commander republishes the control mode (every 0.5 s); the switch
    to rates lags likewise. Across the phase of the cycle the delays spread over about one
    period, and never vanish."""
    period = 0.5  # Commander: vehicle_control_mode at 2 Hz (or on a status change)
    runs = [_switch_flight(ph) for ph in np.linspace(0.0, period, 6, endpoint=False)]
    rises = np.array([r for r, _h in runs])
    helds = np.array([h for _r, h in runs])
    assert np.all(np.isfinite(rises)) and np.all(np.isfinite(helds))
    # an immediate switch (the mock before) reaches -0.5 rad/s in ~0.05 s and turns back at once
    assert helds.min() > 0.02 and helds.max() < period + 0.08
    assert np.ptp(helds) > 0.5 * period
    assert rises.max() > rises.min() + 0.03


@pytest.mark.parametrize("cutoff_hz", [1e-3, 1e-6, 1e-9, 1e-12])
def test_a_cutoff_far_below_the_sample_rate_keeps_a_steady_rate(cutoff_hz: float) -> None:
    # such cutoffs come in by PARAM_SET (IMU_GYRO_CUTOFF, IMU_DGYRO_CUTOFF): 1 + a1 + a2 then
    # cancels to (nearly) 0 in double precision, and the steady state must still be the input
    f = AngularVelocityFilter()
    f.update((0.5, -0.2, 0.1), 0.004, 40.0, 30.0)
    for _ in range(20):
        rates, accel = f.update((0.5, -0.2, 0.1), 0.004, cutoff_hz, cutoff_hz)
        assert rates == pytest.approx((0.5, -0.2, 0.1), abs=1e-6)
        assert accel == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)


@pytest.mark.parametrize("cutoff_hz", [1e-150, 1e-200, 5e-324])
def test_an_unrepresentable_cutoff_gives_finite_rates(cutoff_hz: float) -> None:
    f = AngularVelocityFilter()
    f.update((0.5, -0.2, 0.1), 0.004, 40.0, 30.0)
    for k in range(20):
        rates, accel = f.update((0.5 + 0.01 * k, -0.2, 0.1), 0.004, cutoff_hz, cutoff_hz)
        assert all(math.isfinite(v) for v in (*rates, *accel))
