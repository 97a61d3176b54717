"""Offline demo: plan a minimum-snap trajectory through waypoints, derive flatness setpoints,
print a table and save a plot. Needs no vehicle and no network."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.geometry import quat_to_euler321
from companion.trajectory import Limits, PiecewiseBezier, check, plan

#: Example waypoints (NED, metres): a climbing loop around a 20 m x 10 m field at 5-8 m altitude.
DEMO_WAYPOINTS_NED = np.array(
    [
        [0.0, 0.0, -5.0],
        [10.0, 0.0, -6.0],
        [20.0, 5.0, -8.0],
        [10.0, 10.0, -7.0],
        [0.0, 10.0, -6.0],
        [-5.0, 5.0, -5.0],
        [0.0, 0.0, -5.0],
    ]
)

#: PX4 SIH-like quadrotor: 1 kg, 4 x 5 N, linear drag 1 N/(m/s).
DEMO_PARAMS = MultirotorParams(
    mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0
)
DEMO_LIMITS = Limits(
    max_speed_m_s=6.0,
    max_acc_m_s2=4.0,
    max_tilt_rad=math.radians(35.0),
    max_thrust_n=18.0,
    min_thrust_n=2.0,
    max_body_rate_rad_s=3.0,
)


@dataclass(frozen=True)
class DemoResult:
    """What the demo computed: the trajectory and sampled setpoints (time in s)."""

    trajectory: PiecewiseBezier
    t_s: NDArray[np.float64]
    pos_ned: NDArray[np.float64]
    vel_ned: NDArray[np.float64]
    thrust_norm: NDArray[np.float64]
    euler_deg: NDArray[np.float64]
    omega_frd: NDArray[np.float64]
    limits_ok: bool


def run_demo(rate_hz: float = 50.0) -> DemoResult:
    """Plan through `DEMO_WAYPOINTS_NED` with yaw following the velocity and sample setpoints."""
    traj = plan(
        DEMO_WAYPOINTS_NED, limits=DEMO_LIMITS, params=DEMO_PARAMS, yaw="velocity"
    )
    t = np.arange(0.0, traj.duration, 1.0 / rate_hz)
    der = [traj.evaluate(t, k) for k in range(5)]
    assert traj.yaw is not None
    yaw = [traj.yaw.evaluate(t, k)[:, 0] for k in range(3)]
    sp = multirotor_setpoint(der[1], der[2], der[3], der[4], yaw[0], yaw[1], yaw[2], DEMO_PARAMS)
    psi, theta, phi = quat_to_euler321(sp.q_wxyz)
    euler = np.degrees(np.stack([phi, theta, psi], axis=-1))
    reports = check(traj, DEMO_LIMITS, DEMO_PARAMS)
    return DemoResult(
        trajectory=traj,
        t_s=t,
        pos_ned=der[0],
        vel_ned=der[1],
        thrust_norm=np.asarray(sp.thrust_norm),
        euler_deg=euler,
        omega_frd=np.asarray(sp.omega_frd),
        limits_ok=not any(r.exceeded for r in reports.values()),
    )


def save_plot(result: DemoResult, path: Path) -> None:
    """Top view, altitude, attitude and thrust of the demo trajectory, as a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(2, 2, figsize=(11, 8))
    p = result.pos_ned
    ax[0, 0].plot(p[:, 1], p[:, 0], label="planned path")
    ax[0, 0].plot(DEMO_WAYPOINTS_NED[:, 1], DEMO_WAYPOINTS_NED[:, 0], "o", label="waypoints")
    ax[0, 0].set(xlabel="East [m]", ylabel="North [m]", title="Top view", aspect="equal")
    ax[0, 0].legend()
    ax[0, 1].plot(result.t_s, -p[:, 2], label="altitude [m]")
    ax[0, 1].plot(result.t_s, np.linalg.norm(result.vel_ned, axis=1), label="speed [m/s]")
    ax[0, 1].set(xlabel="t [s]", title="Altitude and speed")
    ax[0, 1].legend()
    for i, name in enumerate(("roll", "pitch", "yaw")):
        ax[1, 0].plot(result.t_s, result.euler_deg[:, i], label=name)
    ax[1, 0].set(xlabel="t [s]", ylabel="deg", title="Attitude setpoint (3-2-1)")
    ax[1, 0].legend()
    ax[1, 1].plot(result.t_s, result.thrust_norm, label="thrust_norm")
    for i, name in enumerate(("p", "q", "r")):
        ax[1, 1].plot(result.t_s, result.omega_frd[:, i], label=f"{name} [rad/s]")
    ax[1, 1].set(xlabel="t [s]", title="Thrust and body-rate feed-forward")
    ax[1, 1].legend()
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.png")
    fig.savefig(tmp, dpi=90)
    plt.close(fig)
    tmp.replace(path)
