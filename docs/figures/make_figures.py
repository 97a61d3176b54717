"""Draw the manual's figures into docs/figures/ (run from the repository root).

    python docs/figures/make_figures.py            # all figures
    python docs/figures/make_figures.py min_snap   # one of: min_snap, derivatives, frames, replay

The PNGs are committed; re-run this after a change that alters what they show. Needs the
`plot` extra (matplotlib). `replay` flies examples/missions/square.plan against the mock
(about 10 s) and copies its flight.png.
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from companion.flatness import MultirotorParams, multirotor_setpoint
from companion.geometry import quat_to_dcm
from companion.trajectory import plan

OUT = Path(__file__).resolve().parent
ROOT = OUT.parents[1]
WAYPOINTS = np.array([[0.0, 0.0], [6.0, 1.0], [8.0, 7.0], [2.0, 9.0], [0.0, 4.0]])
DURATIONS = [2.5, 2.5, 2.5, 2.0]
DPI = 110


def _save(fig: plt.Figure, name: str) -> None:
    path = OUT / name
    fig.savefig(path, dpi=DPI, bbox_inches="tight", metadata={"Software": None})
    plt.close(fig)
    print(f"wrote {path.relative_to(ROOT)}")


def min_snap() -> None:
    """A 2-D minimum-snap trajectory with the Bezier control points of each segment."""
    traj = plan(WAYPOINTS, durations=DURATIONS)
    t = np.linspace(0.0, traj.duration, 600)
    p = traj.evaluate(t)
    fig, ax = plt.subplots(figsize=(6.4, 5.2))
    colors = plt.get_cmap("tab10").colors
    for k, seg in enumerate(traj.segments):
        cp = seg.control_points
        c = colors[k % len(colors)]
        ax.plot(cp[:, 0], cp[:, 1], "--", color=c, lw=0.8, alpha=0.7)
        ax.plot(cp[:, 0], cp[:, 1], "o", color=c, ms=4, mfc="white",
                label=f"segment {k + 1} control points (degree {seg.degree})")
    ax.plot(p[:, 0], p[:, 1], "k-", lw=2, label="trajectory")
    ax.plot(WAYPOINTS[:, 0], WAYPOINTS[:, 1], "s", color="crimson", ms=8, label="waypoints")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.set_title("Minimum snap through 5 waypoints (fixed durations)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.02, 1.0))
    ax.grid(alpha=0.3)
    _save(fig, "min_snap.png")


def derivatives() -> None:
    """Speed, acceleration, jerk and snap of the same trajectory: continuous through snap."""
    traj = plan(WAYPOINTS, durations=DURATIONS)
    t = np.linspace(0.0, traj.duration, 2000)
    names = ["speed [m/s]", "|acceleration| [m/s²]", "|jerk| [m/s³]", "|snap| [m/s⁴]"]
    fig, axes = plt.subplots(4, 1, figsize=(6.4, 6.4), sharex=True)
    for order, (ax, name) in enumerate(zip(axes, names, strict=True), start=1):
        ax.plot(t, np.linalg.norm(traj.evaluate(t, order), axis=1), "k-", lw=1.5)
        for b in traj.breaks[1:-1]:
            ax.axvline(b, color="crimson", lw=0.8, ls=":")
        ax.set_ylabel(name, fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("t [s] (dotted: waypoint times)")
    axes[0].set_title("Derivatives of the minimum-snap trajectory")
    _save(fig, "derivatives.png")


def frames() -> None:
    """Attitude from the flatness map along a corner: top view of the tilt and nose, and the
    body rates and thrust over time."""
    wp = np.array([[0.0, 0.0, -5.0], [10.0, 0.0, -5.0], [10.0, 10.0, -5.0]])
    traj = plan(wp, durations=[3.2, 3.2], yaw="velocity")
    params = MultirotorParams(mass=1.0, inertia=np.diag([0.025, 0.025, 0.03]), drag=1.0)
    assert traj.yaw is not None

    def setpoint(t: np.ndarray):  # type: ignore[no-untyped-def]
        vel, acc, jerk, snap = (traj.evaluate(t, k) for k in (1, 2, 3, 4))
        yaw, yaw_rate, yaw_acc = (traj.yaw.evaluate(t, k)[:, 0] for k in (0, 1, 2))
        return multirotor_setpoint(vel, acc, jerk, snap, yaw, yaw_rate, yaw_acc, params)

    t = np.linspace(0.0, traj.duration, 15)[1:-1]
    C = quat_to_dcm(setpoint(t).q_wxyz)
    pos = traj.evaluate(t)
    tt = np.linspace(0.0, traj.duration, 400)
    path = traj.evaluate(tt)
    sp = setpoint(tt)
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10.5, 4.6))
    # top view, East right and North up
    ax.plot(path[:, 1], path[:, 0], "k-", lw=1.2)
    lift_h = -C[:, :2, 2] * 4.0  # horizontal part of the lift direction, x4
    nose = C[:, :2, 0] * 1.5
    ax.quiver(pos[:, 1], pos[:, 0], lift_h[:, 1], lift_h[:, 0], color="royalblue",
              angles="xy", scale_units="xy", scale=1, width=0.006,
              label="tilt: horizontal part of the lift -z_b, x4")
    ax.quiver(pos[:, 1], pos[:, 0], nose[:, 1], nose[:, 0], color="crimson",
              angles="xy", scale_units="xy", scale=1, width=0.005, label="nose x_b")
    ax.set_xlabel("East [m]")
    ax.set_ylabel("North [m]")
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="lower right")
    ax.set_title("Top view: tilt and heading (yaw follows the velocity)", fontsize=9)
    for k, name in enumerate(("p (roll rate)", "q (pitch rate)", "r (yaw rate)")):
        bx.plot(tt, sp.omega_frd[:, k], lw=1.4, label=name)
    bx.plot(tt, sp.thrust_norm, "k--", lw=1.2, label="normalised thrust")
    bx.set_xlabel("t [s]")
    bx.set_ylabel("body rates [rad/s], thrust [0..1]")
    bx.grid(alpha=0.3)
    bx.legend(fontsize=8)
    bx.set_title("Feed-forward from the flatness map (drag 1 N/(m/s), 1 kg)", fontsize=9)
    _save(fig, "flatness_frames.png")


def replay() -> None:
    """flight.png of a replay of the bundled square mission."""
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "companion", "replay", "examples/missions/square.plan",
             "--out", tmp],
            cwd=ROOT, check=True, stdout=subprocess.DEVNULL,
        )
        shutil.copyfile(Path(tmp) / "square" / "flight.png", OUT / "replay_square.png")
    print("wrote docs/figures/replay_square.png")


FIGURES = {"min_snap": min_snap, "derivatives": derivatives, "frames": frames, "replay": replay}


def main(argv: list[str]) -> int:
    for name in argv or list(FIGURES):
        FIGURES[name]()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
