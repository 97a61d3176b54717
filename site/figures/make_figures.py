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


def layers() -> None:
    """companion's packages by layer (the list tests/architecture/test_layers.py enforces)."""
    sys.path.insert(0, str(ROOT))
    from tests.architecture.test_layers import LAYERS

    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    what = {
        "geometry": "SO(3), frames", "_frozen": "fast frozen values",
        "flatness": "flat outputs -> setpoints", "mavlink": "sans-IO MAVLink core",
        "trajectory": "Bezier, min-snap planner", "control": "tracking law, estimators",
        "mission": "files <-> model <-> wire", "planning": "schedule, vehicle limits",
        "flight": "flight sequence, report", "aio": "asyncio Vehicle facade",
        "replay": "lockstep replay vs mock", "serve": "on-vehicle service",
        "campaign": "Monte-Carlo on Dask", "app": "commands, console, plots",
    }
    for i, layer in enumerate(LAYERS):
        names = sorted(n for n in layer if n != "_frozen")
        w = 1.0 / len(names)
        for j, name in enumerate(names):
            x = j * w
            ax.add_patch(plt.Rectangle((x + 0.01, i + 0.08), w - 0.02, 0.84, fc="#e3ecf7",
                                       ec="#33557a", lw=1.0))
            ax.text(x + w / 2, i + 0.58, name, ha="center", va="center", fontsize=10,
                    weight="bold")
            ax.text(x + w / 2, i + 0.3, what[name], ha="center", va="center", fontsize=8)
        ax.text(-0.02, i + 0.5, str(i), ha="right", va="center", fontsize=9, color="#555")
    ax.annotate("", xy=(1.05, 0.2), xytext=(1.05, len(LAYERS) - 0.2),
                arrowprops={"arrowstyle": "->", "color": "#555"})
    ax.text(1.07, len(LAYERS) / 2, "imports point down", rotation=90, va="center", fontsize=9,
            color="#555")
    ax.set_xlim(-0.06, 1.12)
    ax.set_ylim(0, len(LAYERS))
    ax.axis("off")
    ax.set_title("companion: layers (a module imports its own layer or lower)", fontsize=10)
    _save(fig, "layers.png")


def sequence() -> None:
    """The phases of the one flight sequence (companion.flight.sequence.Phase)."""
    fig, ax = plt.subplots(figsize=(8.0, 2.6))
    main_path = ["WAIT_READY", "PRIME", "REQUEST_OFFBOARD", "ARM", "CONFIRM_ARM", "FLY",
                 "HANDOVER", "WAIT_DISARM", "DONE"]
    for i, name in enumerate(main_path):
        ax.add_patch(plt.Rectangle((i + 0.05, 1.1), 0.9, 0.6, fc="#e3ecf7", ec="#33557a"))
        ax.text(i + 0.5, 1.4, name.replace("_", "\n"), ha="center", va="center", fontsize=7)
        if i:
            ax.annotate("", xy=(i + 0.05, 1.4), xytext=(i - 0.05, 1.4),
                        arrowprops={"arrowstyle": "->"})
    ax.annotate("", xy=(7.5, 1.1), xytext=(5.5, 1.1),
                arrowprops={"arrowstyle": "->", "connectionstyle": "arc3,rad=0.35"})
    ax.text(6.5, 0.62, "touchdown: disarm once PX4 reports on ground", ha="center", fontsize=7)
    ax.add_patch(plt.Rectangle((3.55, 0.0), 1.9, 0.45, fc="#f7e3e3", ec="#7a3333"))
    ax.text(4.5, 0.22, "FAILED (reason)", ha="center", va="center", fontsize=8)
    ax.text(4.5, 2.0, "refused OFFBOARD / arm, left OFFBOARD, link lost: FAILED, no arm sent "
            "after a refusal", ha="center", fontsize=7)
    ax.set_xlim(0, len(main_path))
    ax.set_ylim(-0.1, 2.2)
    ax.axis("off")
    _save(fig, "sequence.png")


FIGURES = {"min_snap": min_snap, "derivatives": derivatives, "frames": frames, "replay": replay,
           "layers": layers, "sequence": sequence}


def main(argv: list[str]) -> int:
    for name in argv or list(FIGURES):
        FIGURES[name]()
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))
