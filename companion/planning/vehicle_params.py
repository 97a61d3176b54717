"""Which PX4 planning parameters a flight uses: read from the vehicle, overridden by the vehicle
file's ``[px4]`` table, PX4's default where the vehicle has no such parameter (pure: no I/O).

Policy (safety): a value the vehicle sent is used unless the vehicle file overrides it. A
parameter the vehicle did not answer, even on a second pass of requests (a PX4 build or airframe
without it, an autopilot that answers no parameter request at all, or a link losing most
frames), falls back to PX4 v1.16's multicopter default with a warning naming it: PX4 without
that parameter does not apply its limit either, and the default is what the companion planned
with before it read parameters. Since the companion's own attitude/rates setpoints are not held
to PX4's MPC_* limits, a vehicle configured below PX4's defaults must then say so in the
vehicle file's ``[px4]`` table (which also silences the warning). A parameter answered with the
wrong type or an impossible value (e.g. MPC_THR_HOVER 0, MPC_TILTMAX_AIR 95) is an error: the
vehicle is not what the planner assumes, so nothing is flown until the vehicle file overrides it.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Awaitable, Mapping, Sequence
from dataclasses import dataclass
from typing import Literal, Protocol

from companion.mavlink.params import ParamReadDone
from companion.mission.px4_params import (
    ALL_PARAM_NAMES,
    PLANNING_PARAM_NAMES,
    Px4PlanningParams,
    planning_param_names,
)

__all__ = [
    "ParamReader", "ParamSource", "ResolvedPlanningParams", "check_overrides",
    "read_planning_params", "resolve_planning_params",
]

_log = logging.getLogger("companion.planning.vehicle_params")

#: A rover's limits that PX4 reads as "not configured" at -1 (or any value <= 0): planned with
#: the default, with a warning, instead of refusing the vehicle.
UNSET_AT_OR_BELOW_ZERO = frozenset(
    {"RO_SPEED_LIM", "RO_ACCEL_LIM", "RO_DECEL_LIM", "RO_JERK_LIM", "RO_YAW_RATE_LIM"})

ParamSource = Literal["vehicle", "file", "default"]
_MARK: dict[ParamSource, str] = {"vehicle": "", "file": " (vehicle file)", "default": " (default)"}


def check_overrides(overrides: Mapping[str, float], where: str = "[px4]") -> dict[str, float]:
    """The ``[px4]`` table as {PX4 name: value}; ValueError naming unknown names (and listing the
    known ones) or an invalid value."""
    unknown = sorted(set(overrides) - set(ALL_PARAM_NAMES))
    if unknown:
        raise ValueError(f"{where}: unknown PX4 parameter(s) {', '.join(unknown)}; known: "
                         f"{', '.join(ALL_PARAM_NAMES)}")
    out: dict[str, float] = {}
    for name, value in overrides.items():
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{where}: {name} must be a number, got {value!r}")
        try:
            Px4PlanningParams(**{name: float(value)})
        except ValueError as exc:
            raise ValueError(f"{where}: {exc}") from None
        out[name] = float(value)
    return out


@dataclass(frozen=True)
class ResolvedPlanningParams:
    """The parameters a flight plans with and where each came from."""

    params: Px4PlanningParams
    source: dict[str, ParamSource]
    """PX4 name -> "vehicle" (read from it), "file" (vehicle file override), "default"; for
    ``names`` and the overridden names (others plan with PX4's default, unreported)."""
    vehicle_values: dict[str, float]
    """What the vehicle answered (also for overridden names)."""
    warnings: tuple[str, ...] = ()
    names: tuple[str, ...] = PLANNING_PARAM_NAMES
    """The names this vehicle's plan reads (``planning_param_names``), in their order."""

    @property
    def defaulted(self) -> tuple[str, ...]:
        """Names planned with PX4's default because the vehicle did not answer them."""
        return tuple(n for n in self.names if self.source[n] == "default")

    def lines(self, per_line: int = 4) -> list[str]:
        """``NAME = value`` entries, ``per_line`` to a line; overridden and defaulted values are
        marked, an override shows the vehicle's own value too."""
        entries = []
        for name, value in self.params.as_dict(self.names).items():
            src = self.source[name]
            text = f"{name} = {value:g}{_MARK[src]}"
            if src == "file" and name in self.vehicle_values:
                text = f"{name} = {value:g} (vehicle file; vehicle {self.vehicle_values[name]:g})"
            entries.append(text)
        return ["   ".join(entries[i:i + per_line]) for i in range(0, len(entries), per_line)]

    def as_report(self) -> dict[str, dict[str, float | str]]:
        """{name: {"value": v, "source": s}} for report.json."""
        return {n: {"value": v, "source": self.source[n]}
                for n, v in self.params.as_dict(self.names).items()}


def resolve_planning_params(
    read: Mapping[str, float],
    overrides: Mapping[str, float] | None = None,
    *,
    wrong_type: Mapping[str, str] | None = None,
    where: str = "the vehicle",
    vehicle: str = "quad",
) -> ResolvedPlanningParams:
    """Combine the values read from ``where`` with the vehicle file's ``overrides`` (see the
    module doc) for the names ``vehicle``'s plan reads (an override of another name applies
    too). ValueError naming the parameter for an invalid or wrongly typed value that the
    vehicle file does not override."""
    names = planning_param_names(vehicle)
    over = check_overrides(overrides or {})
    bad = {n: why for n, why in (wrong_type or {}).items() if n not in over}
    if bad:
        raise ValueError("; ".join(f"{n} from {where}: {why}" for n, why in sorted(bad.items()))
                         + " (set it in the vehicle file's [px4] table to override)")
    source: dict[str, ParamSource] = {}
    values: dict[str, float] = {}
    unset: list[str] = []
    for name in dict.fromkeys([*names, *over]):
        if name in over:
            source[name], values[name] = "file", over[name]
        elif name in read and name in UNSET_AT_OR_BELOW_ZERO and float(read[name]) <= 0.0:
            source[name] = "default"  # PX4's "not configured" (-1): no limit there
            unset.append(name)
        elif name in read:
            source[name], values[name] = "vehicle", float(read[name])
            try:
                Px4PlanningParams(**{name: values[name]})
            except ValueError as exc:
                raise ValueError(f"{exc} (read from {where}; set it in the vehicle file's "
                                 "[px4] table to override)") from None
        else:
            source[name] = "default"
    params = dataclasses.replace(Px4PlanningParams(), **values)
    warnings: list[str] = []
    defaulted = [n for n in names if source[n] == "default" and n not in unset]
    if unset:
        warnings.append(f"{where} has {', '.join(unset)} not configured (<= 0: no limit in "
                        f"PX4): planning with "
                        f"{', '.join(f'{n} = {getattr(params, n):g}' for n in unset)}; set them "
                        "on the vehicle or in the vehicle file's [px4] table")
    if defaulted and not read:
        warnings.append(f"{where} answered no parameter request: planning with PX4's defaults "
                        "(and the vehicle file's [px4] table)")
    elif defaulted:
        warnings.append(f"{where} did not answer for {', '.join(defaulted)} (not there, or lost "
                        f"on the link): planning with PX4's default "
                        f"({', '.join(f'{getattr(params, n):g}' for n in defaulted)})")
    return ResolvedPlanningParams(params, source, {n: float(v) for n, v in read.items()
                                                   if n in ALL_PARAM_NAMES},
                                  tuple(warnings), names)


class ParamReader(Protocol):
    """Reads PX4 parameters by name without raising for missing ones (e.g.
    ``companion.aio.Vehicle.fetch_params``); ``floats_only``: an answer of another type than
    REAL32 counts as wrong-typed."""

    def __call__(self, names: Sequence[str], timeout_s: float, *,
                 floats_only: bool) -> Awaitable[ParamReadDone]: ...


async def read_planning_params(read: ParamReader, overrides: Mapping[str, float] | None = None,
                               timeout_s: float = 10.0, *, vehicle: str = "quad"
                               ) -> ResolvedPlanningParams:
    """The PX4 parameters the mission planner uses for ``vehicle`` ("quad":
    ``PLANNING_PARAM_NAMES``, "rover": ``ROVER_PARAM_NAMES``; all REAL32 in PX4) read with
    ``read`` (names not answered are asked for once more: tells a lossy link from a parameter
    PX4 lacks), combined with the vehicle file's ``[px4]`` ``overrides``
    (:func:`resolve_planning_params`); its warnings are logged too. ``timeout_s`` [s] per pass.
    ValueError for a value the planner cannot use (wrong type, out of range) unless overridden.

        resolved = await read_planning_params(vehicle.fetch_params, overrides)
    """
    names = list(planning_param_names(vehicle))
    done = await read(names, timeout_s, floats_only=True)
    values, wrong = dict(done.values), dict(done.wrong_type)
    if done.missing:  # a second pass
        again = await read(list(done.missing), timeout_s, floats_only=True)
        values.update(again.values)
        wrong.update(again.wrong_type)
    resolved = resolve_planning_params(values, overrides, wrong_type=wrong, vehicle=vehicle)
    for w in resolved.warnings:
        _log.warning("%s", w)
    return resolved
