"""Lockstep replay of mission files against the `sitl_mock` autopilot (see `runner`)."""

from companion.replay.runner import (
    DEFAULT_QUAD,
    Draw,
    FlightPicture,
    PreparedMission,
    ReplayConfig,
    ReplayResult,
    ReplayRun,
    fly_px4_mission,
    mission_frames,
    planning_limits,
    prepare_mission,
    read_mock_params,
    replay_file,
    run_prepared,
)

__all__ = [
    "DEFAULT_QUAD", "Draw", "FlightPicture", "PreparedMission", "ReplayConfig", "ReplayResult",
    "ReplayRun", "fly_px4_mission", "mission_frames", "planning_limits", "prepare_mission",
    "read_mock_params", "replay_file", "run_prepared",
]
