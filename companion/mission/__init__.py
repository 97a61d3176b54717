"""Missions: one model (:class:`Mission`, :class:`MissionItem`), every conversion file <-> model
<-> wire in :mod:`companion.mission.convert` (QGroundControl ``.plan`` and ``QGC WPL 110`` files,
the vehicle's MISSION_ITEM_INTs), one error hierarchy (:class:`MissionError`), PX4's geodetic
<-> local NED projection, geofence tests, and the mission -> flight plan expansion. Pure: no I/O
besides reading the file in :func:`load_mission`, no asyncio, no sockets.

Typical use::

    from companion.mission import load_mission, mission_to_flight_plan, split_flight_plan
    mission = load_mission("examples/missions/square.plan")     # MissionError on bad input
    plan = mission_to_flight_plan(mission)                       # local NED about home
    for chunk in split_flight_plan(plan):                        # stop-to-stop pieces
        traj = plan_trajectory(chunk.points_ned_m, ...)          # companion.trajectory.plan
"""

from companion.mission.checks import MAX_RANGE_M
from companion.mission.convert import (
    UploadItem,
    geofence_from_wire,
    load_mission,
    loads_mission,
    mission_from_wire,
    mission_to_wpl,
    mission_upload_items,
    rehome_mission,
)
from companion.mission.errors import MissionError
from companion.mission.flightplan import (
    FinalAction,
    FlightChunk,
    FlightPlan,
    FlightWaypoint,
    Phase,
    expand_jumps,
    mission_to_flight_plan,
    split_flight_plan,
)
from companion.mission.geodesy import EARTH_RADIUS_M, GeoPoint, geodetic_to_ned, ned_to_geodetic
from companion.mission.geofence import FenceCircle, FencePolygon, FenceViolation, Geofence
from companion.mission.model import (
    Mission,
    MissionItem,
    RallyPoint,
    command_name,
    frame_name,
)
from companion.mission.plan_file import parse_plan
from companion.mission.wpl_file import parse_wpl

__all__ = [
    "EARTH_RADIUS_M",
    "MAX_RANGE_M",
    "FenceCircle",
    "FencePolygon",
    "FenceViolation",
    "FinalAction",
    "FlightChunk",
    "FlightPlan",
    "FlightWaypoint",
    "GeoPoint",
    "Geofence",
    "Mission",
    "MissionError",
    "MissionItem",
    "Phase",
    "RallyPoint",
    "UploadItem",
    "command_name",
    "expand_jumps",
    "frame_name",
    "geodetic_to_ned",
    "geofence_from_wire",
    "load_mission",
    "loads_mission",
    "mission_from_wire",
    "mission_to_flight_plan",
    "mission_to_wpl",
    "mission_upload_items",
    "ned_to_geodetic",
    "parse_plan",
    "parse_wpl",
    "rehome_mission",
    "split_flight_plan",
]
