"""Floor of a mission's flight time under its own speeds: every leg flown at its planned speed
cap (the mission speed, PX4's climb/descent rates, the landing profile) with infinite
acceleration, plus the holds; no arming, turning or landing overhead. No trajectory can be
quicker at the mission's speeds, so a goal below it is out of reach whatever the planner does.

Usage: ``python bench/mission_floor.py [FILE ...]`` (default: the bundled missions); prints a
Markdown table (floor, and the floor as a fraction of the AUTO.MISSION times given with
``--auto NAME=SECONDS``). A rover plan (vehicleType 10) drives every leg at its mission speed
capped at RO_MAX_SPEED (``--ro-max-speed``, default the mock's), as the mock's AUTO.MISSION
rover does; the companion plans a rover below that (replay: 0.9 RO_MAX_SPEED)."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from companion.mission import load_mission, mission_to_flight_plan, split_flight_plan
from companion.mission.px4_params import Px4PlanningParams
from companion.planning.chunks import land_profile, leg_speed_caps
from sitl_mock.params import PARAMS

MAV_TYPE_GROUND_ROVER = 10

ROOT = Path(__file__).resolve().parents[1]


def floor_s(path: Path, px4: Px4PlanningParams, ro_max_speed: float) -> float:
    """Sum over the legs of length / speed cap, plus the holds [s]."""
    mission = load_mission(path)
    rover = mission.vehicle_type == MAV_TYPE_GROUND_ROVER
    fp = mission_to_flight_plan(mission, vehicle="rover" if rover else "quad", px4=px4)
    total = 0.0
    for ch in split_flight_plan(fp):
        pts = np.array(ch.points_ned_m, dtype=np.float64)
        caps = leg_speed_caps(ch, pts, fp.px4, rover)
        if rover:
            caps = np.minimum(caps, ro_max_speed)
        if ch.phase == "land":
            pts, caps = land_profile(pts, caps, fp.px4, float(fp.start_ned_m[2]))
        total += float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1) / caps))
        total += ch.hold_after_s
    return total


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path)
    ap.add_argument("--auto", nargs="*", default=[], metavar="NAME=SECONDS")
    ap.add_argument("--ro-max-speed", type=float, default=PARAMS["RO_MAX_SPEED"].default,
                    help="rover top speed [m/s] (default: the mock's RO_MAX_SPEED)")
    args = ap.parse_args()
    files = args.files or sorted((ROOT / "examples" / "missions").glob("*.plan"))
    auto = {k: float(v) for k, v in (a.split("=", 1) for a in args.auto)}
    print("| mission | floor [s] | AUTO.MISSION [s] | floor / AUTO.MISSION |")
    print("| --- | ---: | ---: | ---: |")
    for f in files:
        fl = floor_s(f, Px4PlanningParams(), args.ro_max_speed)
        a = auto.get(f.name)
        ratio = f"{fl / a:.2f}" if a else "-"
        print(f"| {f.name} | {fl:.1f} | {a if a else '-'} | {ratio} |")


if __name__ == "__main__":
    main()
