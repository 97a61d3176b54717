"""Which PX4 planning parameters a flight uses: the vehicle file's [px4] table wins over the
vehicle, the vehicle's values win over PX4's defaults, a parameter the vehicle lacks falls back
to the default with a warning naming it, and a value the planner cannot use stops the flight
unless the vehicle file overrides it."""

from __future__ import annotations

import pytest

from companion.mission.px4_params import PLANNING_PARAM_NAMES, Px4PlanningParams
from companion.planning.vehicle_params import resolve_planning_params

ALL_READ = {n: v for n, v in Px4PlanningParams().as_dict().items()}


def test_vehicle_file_override_wins_over_the_vehicle_and_is_marked() -> None:
    read = {**ALL_READ, "MPC_XY_CRUISE": 7.0}
    r = resolve_planning_params(read, {"MPC_XY_CRUISE": 9.5})
    assert r.params.MPC_XY_CRUISE == 9.5
    assert r.source["MPC_XY_CRUISE"] == "file" and r.vehicle_values["MPC_XY_CRUISE"] == 7.0
    assert r.warnings == ()
    text = "\n".join(r.lines())
    assert "MPC_XY_CRUISE = 9.5 (vehicle file; vehicle 7)" in text
    assert all(name in text for name in PLANNING_PARAM_NAMES)


def test_values_read_from_the_vehicle_replace_the_defaults() -> None:
    read = {**ALL_READ, "MPC_TKO_SPEED": 2.5, "NAV_ACC_RAD": 0.8}
    r = resolve_planning_params(read)
    assert (r.params.MPC_TKO_SPEED, r.params.NAV_ACC_RAD) == (2.5, 0.8)
    assert set(r.source.values()) == {"vehicle"}
    assert r.as_report()["NAV_ACC_RAD"] == {"value": 0.8, "source": "vehicle"}


def test_a_parameter_the_vehicle_lacks_falls_back_to_the_default_with_a_warning() -> None:
    read = {n: v for n, v in ALL_READ.items() if n not in ("MPC_LAND_ALT2", "MPC_ACC_HOR_MAX")}
    read["MPC_XY_CRUISE"] = 6.0
    r = resolve_planning_params(read)
    assert r.defaulted == ("MPC_ACC_HOR_MAX", "MPC_LAND_ALT2")
    assert r.params.MPC_LAND_ALT2 == Px4PlanningParams().MPC_LAND_ALT2
    assert r.params.MPC_XY_CRUISE == 6.0
    (w,) = r.warnings
    assert "MPC_ACC_HOR_MAX" in w and "MPC_LAND_ALT2" in w and "default" in w
    assert "MPC_LAND_ALT2 = 5 (default)" in "\n".join(r.lines())
    # the vehicle file fills the gap: no warning for it any more
    r2 = resolve_planning_params(read, {"MPC_LAND_ALT2": 4.0, "MPC_ACC_HOR_MAX": 3.0})
    assert r2.warnings == () and r2.params.MPC_LAND_ALT2 == 4.0


def test_a_vehicle_that_answers_nothing_is_said_so() -> None:
    r = resolve_planning_params({})
    assert r.params == Px4PlanningParams()
    (w,) = r.warnings
    assert "answered no parameter request" in w


@pytest.mark.parametrize(("name", "value"), [("MPC_THR_HOVER", 0.0), ("MPC_TILTMAX_AIR", 95.0),
                                             ("MPC_XY_CRUISE", -1.0)])
def test_an_unusable_value_from_the_vehicle_is_an_error_unless_overridden(
    name: str, value: float
) -> None:
    read = {**ALL_READ, name: value}
    with pytest.raises(ValueError, match=f"{name}.*read from the vehicle.*\\[px4\\]"):
        resolve_planning_params(read)
    r = resolve_planning_params(read, {name: ALL_READ[name]})
    assert getattr(r.params, name) == ALL_READ[name]


def test_a_wrongly_typed_answer_is_an_error_unless_overridden() -> None:
    read = {n: v for n, v in ALL_READ.items() if n != "NAV_ACC_RAD"}
    why = {"NAV_ACC_RAD": "the vehicle sent INT32, expected REAL32"}
    with pytest.raises(ValueError, match="NAV_ACC_RAD from the vehicle: the vehicle sent INT32"):
        resolve_planning_params(read, wrong_type=why)
    r = resolve_planning_params(read, {"NAV_ACC_RAD": 1.5}, wrong_type=why)
    assert r.params.NAV_ACC_RAD == 1.5


def test_unknown_override_names_list_the_known_ones() -> None:
    with pytest.raises(ValueError, match=r"unknown PX4 parameter.*MPC_FOO.*known: MPC_XY_CRUISE"):
        resolve_planning_params(ALL_READ, {"MPC_FOO": 1.0})


def test_read_planning_params_asks_again_for_unanswered_names() -> None:
    import asyncio
    from collections.abc import Sequence

    from companion.mavlink.params import ParamReadDone
    from companion.planning.vehicle_params import read_planning_params

    calls: list[tuple[list[str], bool]] = []

    async def read(names: Sequence[str], timeout_s: float, *,
                   floats_only: bool) -> ParamReadDone:
        calls.append((list(names), floats_only))
        if len(calls) == 1:  # the first pass loses MPC_XY_CRUISE and NAV_ACC_RAD
            lost = ("MPC_XY_CRUISE", "NAV_ACC_RAD")
            return ParamReadDone(0.0, {n: ALL_READ[n] for n in names if n not in lost}, lost)
        return ParamReadDone(1.0, {"MPC_XY_CRUISE": 7.0}, ("NAV_ACC_RAD",))

    r = asyncio.run(read_planning_params(read, {"MPC_LAND_SPEED": 0.6}))
    assert calls[0] == (list(PLANNING_PARAM_NAMES), True)
    assert calls[1] == (["MPC_XY_CRUISE", "NAV_ACC_RAD"], True)
    assert r.params.MPC_XY_CRUISE == 7.0 and r.source["MPC_XY_CRUISE"] == "vehicle"
    assert r.defaulted == ("NAV_ACC_RAD",) and r.source["MPC_LAND_SPEED"] == "file"


def test_a_rover_reads_its_own_parameters_not_a_multicopters() -> None:
    """A rover (PX4's rover modules have no MPC_* limits) is asked for NAV_ACC_RAD and its
    RO_* / RA_* parameters only; what it answers plans it, and the printed lines and the
    report name those; a multicopter is never asked for them."""
    import asyncio
    from collections.abc import Sequence

    from companion.mavlink.params import ParamReadDone
    from companion.mission.px4_params import ROVER_PARAM_NAMES
    from companion.planning.vehicle_params import read_planning_params

    asked: list[list[str]] = []
    answers = {"NAV_ACC_RAD": 0.5, "RO_SPEED_LIM": 1.8, "RO_ACCEL_LIM": 1.0,
               "RO_DECEL_LIM": 2.0, "RO_JERK_LIM": 5.0, "RO_YAW_RATE_LIM": 90.0,
               "RA_WHEEL_BASE": 0.5, "RA_MAX_STR_ANG": 0.4}

    async def read(names: Sequence[str], timeout_s: float, *,
                   floats_only: bool) -> ParamReadDone:
        asked.append(list(names))
        return ParamReadDone(0.0, {n: answers[n] for n in names if n in answers},
                             tuple(n for n in names if n not in answers))

    r = asyncio.run(read_planning_params(read, vehicle="rover"))
    assert asked == [list(ROVER_PARAM_NAMES)] and sorted(ROVER_PARAM_NAMES) == sorted(answers)
    assert r.params.RO_SPEED_LIM == 1.8 and r.params.RA_WHEEL_BASE == 0.5
    assert r.defaulted == () and r.warnings == ()
    assert set(r.as_report()) == set(ROVER_PARAM_NAMES)
    assert "MPC" not in "\n".join(r.lines()) and "RO_SPEED_LIM = 1.8" in "\n".join(r.lines())
    assert abs(r.params.rover_max_curvature_1_m - 0.4227932187 / 0.5) < 1e-9  # tan(0.4) / 0.5
    asked.clear()
    asyncio.run(read_planning_params(read))
    assert not any(n.startswith(("RO_", "RA_")) for n in asked[0])


def test_a_rover_limit_px4_leaves_unconfigured_is_planned_with_the_default_and_said() -> None:
    """PX4's rover reads RO_SPEED_LIM / RO_ACCEL_LIM ... = -1 as "not configured" (no limit):
    the plan uses the default and a warning names them; a wheel base of -1 is no vehicle the
    planner can plan for: an error naming it."""
    read = {"NAV_ACC_RAD": 0.5, "RO_SPEED_LIM": -1.0, "RO_ACCEL_LIM": 2.0, "RO_DECEL_LIM": -1.0,
            "RO_JERK_LIM": 5.0, "RO_YAW_RATE_LIM": 90.0, "RA_WHEEL_BASE": 0.5,
            "RA_MAX_STR_ANG": 0.4}
    r = resolve_planning_params(read, vehicle="rover")
    assert r.params.RO_SPEED_LIM == Px4PlanningParams().RO_SPEED_LIM
    assert r.params.RO_ACCEL_LIM == 2.0
    assert r.source["RO_SPEED_LIM"] == "default" and r.source["RO_ACCEL_LIM"] == "vehicle"
    assert len(r.warnings) == 1 and "RO_SPEED_LIM, RO_DECEL_LIM not configured" in r.warnings[0]
    with pytest.raises(ValueError, match="RA_WHEEL_BASE"):
        resolve_planning_params({**read, "RA_WHEEL_BASE": -1.0}, vehicle="rover")
