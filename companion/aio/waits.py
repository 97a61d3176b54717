"""Bounded waits of the asyncio layer."""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Awaitable
from typing import TypeVar

T = TypeVar("T")


async def bounded(aw: Awaitable[T], timeout_s: float) -> T:
    """``await aw`` with a timeout (TimeoutError). Unlike ``asyncio.wait_for`` on Python 3.11,
    ``asyncio.timeout`` never swallows an outside cancellation that races with completion (a
    lost cancellation would make SIGINT handling miss)."""
    async with asyncio.timeout(timeout_s):
        return await aw


async def wait_event(ev: asyncio.Event, timeout_s: float) -> None:
    """Wait for ``ev`` at most ``timeout_s`` (no error on timeout)."""
    with contextlib.suppress(TimeoutError):
        async with asyncio.timeout(timeout_s):
            await ev.wait()

