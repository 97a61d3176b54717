"""Fan-out of telemetry values to ``async for`` subscribers."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from typing import Generic, TypeVar

T = TypeVar("T")


class Broadcast(Generic[T]):
    """Fan-out of values to ``async for`` subscribers (each keeps the latest ``maxsize``)."""

    def __init__(self, maxsize: int = 1) -> None:
        self._subs: set[asyncio.Queue[T]] = set()
        self._maxsize = maxsize

    def publish(self, value: T) -> None:
        for q in self._subs:
            if q.full():
                with contextlib.suppress(asyncio.QueueEmpty):
                    q.get_nowait()
            q.put_nowait(value)

    async def stream(self, initial: T | None = None) -> AsyncIterator[T]:
        q: asyncio.Queue[T] = asyncio.Queue(self._maxsize)
        if initial is not None:
            q.put_nowait(initial)
        self._subs.add(q)
        try:
            while True:
                yield await q.get()
        finally:
            self._subs.discard(q)
