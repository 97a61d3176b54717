"""Vehicle TOML files (`companion.planning.config`) and the rover speed cap they feed to the
schedule."""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from companion.control import AttitudeGains, TrackingGains
from companion.mavlink.velocity_correction import VELOCITY_CORRECTION_RAD_S
from companion.mission import load_mission, mission_to_flight_plan
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.chunks import ROVER_SPEED_SHARE
from companion.planning.config import ONBOARD_DEFAULTS, load_vehicle_file
from companion.planning.onboard_segments import law_params
from companion.planning.schedule import VehicleLimits, build_schedule

ROOT = Path(__file__).resolve().parents[3]


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "vehicle.toml"
    p.write_text(text, encoding="utf-8")
    return p


def test_every_key_is_read_with_its_unit(tmp_path: Path) -> None:
    vf = load_vehicle_file(_write(tmp_path, """
[vehicle]
mass_kg = 1.5
inertia_kg_m2 = [0.03, 0.03, 0.05]
hover_thrust = 0.6
drag_n_per_m_s = 0.4
[limits]
max_acc_m_s2 = 4.0
max_tilt_deg = 30.0
max_body_rate_rad_s = 2.0
rover_max_speed_m_s = 1.5
[tracking]
kp_xy = 6.0
kd_xy = 4.5
ki_z = 0.0
k_roll = 5.0
"""))
    assert vf.params.mass == 1.5 and vf.params.hover_thrust == 0.6 and vf.params.drag == 0.4
    np.testing.assert_allclose(np.diag(vf.params.inertia), [0.03, 0.03, 0.05])
    lim = vf.limits
    assert lim.max_acc_m_s2 == 4.0 and lim.max_body_rate_rad_s == 2.0
    assert lim.max_tilt_rad == pytest.approx(math.pi / 6)
    assert lim.rover_max_speed_m_s == 1.5
    g, a = vf.gains, vf.attitude_gains
    assert (g.kp_xy, g.kd_xy, g.ki_z, a.k_roll) == (6.0, 4.5, 0.0, 5.0)
    assert g.kp_z == TrackingGains().kp_z and a.k_pitch == AttitudeGains().k_pitch  # untouched
    cfg = vf.tracking_config(math.radians(40.0))
    assert cfg.gains == g and cfg.attitude_gains == a and cfg.params == vf.params
    assert cfg.max_tilt_rad == pytest.approx(math.radians(40.0))


def test_an_empty_file_gives_the_defaults(tmp_path: Path) -> None:
    vf = load_vehicle_file(_write(tmp_path, ""))
    assert vf.limits == VehicleLimits()
    assert vf.limits.rover_max_speed_m_s is None
    assert vf.gains == TrackingGains() and vf.attitude_gains == AttitudeGains()


def test_the_onboard_law_takes_tracking_s_gains_with_onboard_s_over_them(tmp_path: Path) -> None:
    """[onboard] overrides [tracking] for the module's law only; by default only ki_xy differs
    and the disturbance observer's bandwidth (ONBOARD_DEFAULTS), and what the module is
    uploaded is those."""
    vf = load_vehicle_file(_write(tmp_path, "[tracking]\nkp_xy = 12.0\nki_xy = 2.0\n"
                                            "[onboard]\nkd_xy = 6.0\n"))
    law = law_params(vf, 0.5, math.radians(40.0))
    assert vf.tracking_config(0.7).gains.ki_xy == 2.0  # the streamed law keeps its own
    assert law.kp == (12.0, 12.0, TrackingGains().kp_z)
    assert law.kd == (6.0, 6.0, TrackingGains().kd_z)
    assert law.ki == (ONBOARD_DEFAULTS["ki_xy"],) * 2 + (TrackingGains().ki_z,)
    assert law.dist_bandwidth_rad_s == ONBOARD_DEFAULTS["disturbance_bandwidth_rad_s"] == 0.0
    vf2 = load_vehicle_file(_write(tmp_path, "[onboard]\nki_xy = 4.0\n"
                                             "disturbance_bandwidth_rad_s = 1.5\n"))
    assert law_params(vf2, 0.5, 0.7).ki[:2] == (4.0, 4.0)
    assert law_params(vf2, 0.5, 0.7).dist_bandwidth_rad_s == 1.5
    # the velocity correction: the streamed law's frequency by default, [onboard]'s over it
    assert law.vel_correction_rad_s == ONBOARD_DEFAULTS["velocity_correction_rad_s"] == 4.0
    assert law.vel_correction_rad_s == VELOCITY_CORRECTION_RAD_S
    vf3 = load_vehicle_file(_write(tmp_path, "[onboard]\nvelocity_correction_rad_s = 0\n"))
    assert law_params(vf3, 0.5, 0.7).vel_correction_rad_s == 0.0
    plain = law_params(load_vehicle_file(_write(tmp_path, "")), 0.5, 0.7)
    assert law_params(vf3, 0.5, 0.7) == dataclasses.replace(plain, vel_correction_rad_s=0.0)
    assert vf2.tracking_config(0.7).estimate_disturbance  # the streamed law's own observer
    assert law_params(load_vehicle_file(_write(tmp_path, "")), 0.5, 0.7).kd[:2] == (
        TrackingGains().kd_xy,) * 2


@pytest.mark.parametrize(
    ("text", "words"),
    [
        ("[limits]\nmax_speed = 3\n", "unknown key"),
        ("[wheels]\n", "unknown section"),
        ("[limits]\nrover_max_speed_m_s = 0\n", "rover_max_speed_m_s > 0"),
        ("[limits]\nrover_max_speed_m_s = -2.0\n", "rover_max_speed_m_s > 0"),
        ("[limits]\nrover_max_speed_m_s = 'fast'\n", "must be a finite number"),
        ("[limits]\nrover_max_speed_m_s = nan\n", "must be a finite number"),
        ("[limits]\nmax_tilt_deg = 85\n", "max_tilt_deg < 80"),
        ("[limits\n", "not valid TOML"),
        ("[tracking]\nkp = 3\n", "unknown key"),
        ("[tracking]\nkp_xy = -1\n", "gains must be >= 0"),
        ("[tracking]\nk_yaw = 0\n", "attitude gains > 0"),
        ("[onboard]\nk_roll = 5\n", "unknown key"),
        ("[onboard]\nki_xy = -1\n", "gains must be >= 0"),
        ("[onboard]\ndisturbance_bandwidth_rad_s = -1\n", "gains must be >= 0"),
        ("tracking = 3\n", r"\[tracking\] must be a table"),
        ("[px4]\nMPC_XY_CRUSE = 8\n", r"unknown PX4 parameter.*MPC_XY_CRUSE.*known: .*CRUISE"),
        ("[px4]\nMPC_THR_HOVER = 1.2\n", r"\[px4\]: MPC_THR_HOVER must be in \(0, 1\)"),
        ("[px4]\nNAV_ACC_RAD = 'two'\n", "NAV_ACC_RAD must be a number"),
    ],
)
def test_bad_files_name_the_file_and_the_problem(tmp_path: Path, text: str, words: str) -> None:
    p = _write(tmp_path, text)
    with pytest.raises(ValueError, match=words) as exc:
        load_vehicle_file(p)
    assert str(p) in str(exc.value)


def test_px4_table_reads_overrides_by_px4_name(tmp_path: Path) -> None:
    vf = load_vehicle_file(_write(tmp_path, "[px4]\nMPC_XY_CRUISE = 8\nNAV_ACC_RAD = 0.5\n"))
    assert vf.px4_overrides == {"MPC_XY_CRUISE": 8.0, "NAV_ACC_RAD": 0.5}
    assert load_vehicle_file(_write(tmp_path, "")).px4_overrides == {}


def test_missing_file_is_a_clean_error(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="not found"):
        load_vehicle_file(tmp_path / "nope.toml")


@pytest.mark.parametrize("planner", ["arcs", "minsnap"])
@pytest.mark.parametrize("cap", [None, 1.2, 2.7])
def test_rover_speed_cap_bounds_the_planned_speed(cap: float | None, planner: str) -> None:
    """Planned ground speed (sampled derivative of every trajectory piece) <= the cap, and
    reaches close to it on the square's 30 m legs; without a cap, ROVER_SPEED_SHARE of PX4's
    RO_SPEED_LIM (the rover's mission speed; the 5 m/s of a multicopter's MPC_XY_CRUISE made a
    plan the real rover could not drive)."""
    fp = mission_to_flight_plan(
        load_mission(ROOT / "examples" / "missions" / "rover_square.plan"), vehicle="rover"
    )
    sched = build_schedule(fp, None, VehicleLimits(rover_max_speed_m_s=cap,
                                                   rover_planner=planner))  # type: ignore[arg-type]
    top = 0.0
    for piece in sched.pieces:
        if piece.traj is not None:
            t = np.linspace(0.0, piece.traj.duration, 4000)
            top = max(top, float(np.max(np.linalg.norm(piece.traj.evaluate(t, 1), axis=1))))
    want = ROVER_SPEED_SHARE * Px4PlanningParams().RO_SPEED_LIM if cap is None else cap
    assert top <= want * (1 + 1e-6)
    assert top >= 0.8 * want
