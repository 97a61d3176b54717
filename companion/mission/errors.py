"""The mission error hierarchy: one base, :class:`MissionError`, for every way a mission cannot
be loaded, converted, transferred or flown.

- :class:`MissionError` itself: a bad mission file, a mission downloaded from the vehicle that
  the companion cannot fly, a plan that breaches its geofence.
- ``companion.aio.MissionTransferError`` (a subclass, also a ``VehicleError``): a mission
  upload / download / clear with the vehicle failed (it lives in ``aio`` beside the other vehicle
  errors; the mission layer does no I/O).

``except MissionError`` catches them all.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["MissionError"]


class MissionError(ValueError):
    """A mission cannot be loaded, converted or flown.

    ``str(err)`` names the source and, when it applies, the item: ``"square.plan: item 4: frame
    10 (terrain) needs terrain data"``. ``source`` (a file name, ``"vehicle mission"`` for the
    vehicle's mission, ``""`` for no prefix), ``item`` (the model's item index) and ``detail``
    carry the parts.
    """

    def __init__(self, source: str | Path, detail: str, item: int | None = None) -> None:
        self.source = str(source)
        self.item = item
        self.detail = detail
        where = f"{self.source}: " if self.source else ""
        if item is not None:
            where += f"item {item}: "
        super().__init__(where + detail)

    def __reduce__(self) -> tuple[type[MissionError], tuple[str, str, int | None]]:
        # picklable with its parts (e.g. raised in a worker process of a parallel replay)
        return (MissionError, (self.source, self.detail, self.item))
