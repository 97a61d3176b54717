"""``safe_exit``: SIGINT/SIGTERM end the enclosed block with the vehicle in Hold (or Land)."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import signal
from collections.abc import AsyncIterator, Sequence

from .base import VehicleBase

__all__ = ["safe_exit"]

log = logging.getLogger("companion.aio")


@contextlib.asynccontextmanager
async def safe_exit(vehicle: VehicleBase, action: str | None = None,
                    signals: Sequence[int] = (signal.SIGINT, signal.SIGTERM)
                    ) -> AsyncIterator[list[int]]:
    """On SIGINT/SIGTERM: cancel the enclosed block, switch the vehicle to Hold (or Land), and
    re-raise as KeyboardInterrupt. Yields the list of signals received (for the CLI's exit code).
    """
    loop = asyncio.get_running_loop()
    task = asyncio.current_task()
    hit: list[int] = []

    def handler(sig: int) -> None:
        if not hit and task is not None:
            task.cancel()
        hit.append(sig)

    installed = []
    for s in signals:
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(s, handler, s)
            installed.append(s)
    try:
        yield hit
    except asyncio.CancelledError:
        if not hit:
            raise
        log.warning("signal %s: %s before exit", hit[0], (action or vehicle.config.exit_action))
        await vehicle.exit_action(action)
        raise KeyboardInterrupt from None
    else:
        if hit:  # the block ended on its own while the signal was being delivered
            with contextlib.suppress(asyncio.CancelledError):
                await asyncio.sleep(0)  # absorb the cancellation if it is still pending
            if task is not None and task.cancelling():
                task.uncancel()
            log.warning("signal %s: %s before exit", hit[0], (action or vehicle.config.exit_action))
            await vehicle.exit_action(action)
            raise KeyboardInterrupt
    finally:
        for s in installed:
            loop.remove_signal_handler(s)
