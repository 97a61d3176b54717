"""``vehicle.mission``: mission upload, download, clear and start over the vehicle's link."""

from __future__ import annotations

import asyncio
import dataclasses
import time
from collections.abc import Callable, Sequence
from typing import Any

from companion.mavlink import FlightMode, MissionResult, MissionTransferDone, WireMissionItem

from .base import VehicleBase
from .errors import MissionTransferError, VehicleError
from .waits import bounded

__all__ = ["MissionAPI"]


def _as_item(obj: Any) -> WireMissionItem:
    if isinstance(obj, WireMissionItem):
        return obj
    fields = [f.name for f in dataclasses.fields(WireMissionItem)]
    return WireMissionItem(**{f: getattr(obj, f) for f in fields if hasattr(obj, f)})


class MissionAPI:
    """``vehicle.mission``: upload / download / clear / start."""

    def __init__(self, vehicle: VehicleBase) -> None:
        self._v = vehicle

    async def _run(self, start: Callable[[float], list[MissionTransferDone]],
                   timeout_s: float = 30.0) -> MissionTransferDone:
        v = self._v
        if v._mission_waiter is not None:
            raise VehicleError("a mission transfer is already running")
        fut: asyncio.Future[MissionTransferDone] = asyncio.get_running_loop().create_future()
        v._mission_waiter = fut
        try:
            immediate = start(time.monotonic())
            v._flush()
            v._wake.set()
            done = immediate[0] if immediate else await bounded(fut, timeout_s)
        except (asyncio.CancelledError, TimeoutError):
            v._dispatch(v.link.mission.cancel(time.monotonic()))
            v._flush()
            raise
        finally:
            v._mission_waiter = None
        if done.result is not MissionResult.SUCCESS:
            raise MissionTransferError(done.operation, done.result, done.mav_result, done.detail)
        return done

    async def upload(self, items: Sequence[Any], mission_type: int = 0) -> None:
        """Upload MISSION_ITEM_INT items (``WireMissionItem`` or objects with the same fields)."""
        its = [_as_item(i) for i in items]
        await self._run(lambda now: self._v.link.mission.upload(its, now, mission_type))

    async def download(self, mission_type: int = 0) -> list[WireMissionItem]:
        """Download the vehicle's mission."""
        done = await self._run(lambda now: self._v.link.mission.download(now, mission_type))
        return list(done.items)

    async def clear(self, mission_type: int = 0) -> None:
        """Clear the vehicle's mission."""
        await self._run(lambda now: self._v.link.mission.clear(now, mission_type))

    async def start(self) -> None:
        """Switch to AUTO.MISSION."""
        await self._v.set_mode(FlightMode.MISSION)
