"""Mission files: QGroundControl ``.plan`` and ``QGC WPL 110`` loaders, PX4's geodetic <-> local
NED projection, geofence tests, and the mission -> flight plan expansion. Pure: no I/O besides
reading the file in :func:`load_mission`, no asyncio, no sockets.

Typical use::

    from companion.mission import load_mission, mission_to_flight_plan, split_flight_plan
    mission = load_mission("examples/missions/square.plan")     # MissionError on bad input
    plan = mission_to_flight_plan(mission)                       # local NED about home
    for chunk in split_flight_plan(plan):                        # stop-to-stop pieces
        traj = plan_trajectory(chunk.points_ned_m, ...)          # companion.trajectory.plan
"""

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
from companion.mission.loaders import (
    MAX_RANGE_M,
    load_mission,
    loads_mission,
    parse_plan,
    parse_wpl,
)
from companion.mission.model import (
    Mission,
    MissionError,
    MissionItem,
    RallyPoint,
    command_name,
    frame_name,
)
from companion.mission.upload import UploadItem, mission_upload_items

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
    "load_mission",
    "loads_mission",
    "mission_to_flight_plan",
    "mission_upload_items",
    "ned_to_geodetic",
    "parse_plan",
    "parse_wpl",
    "split_flight_plan",
]
