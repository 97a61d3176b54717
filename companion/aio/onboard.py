"""The onboard module over the vehicle's link: is it there, upload a trajectory, follow it.

The protocol itself is `companion.onboard.protocol` (sans I/O); this drives it with a
`VehicleBase`: DEBUG_FLOAT_ARRAY out, the module's COMMAND_ACKs in (`command_acks`).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import AsyncIterator

from companion.mavlink.commands import UnsolicitedAck
from companion.onboard.protocol import (
    OP_STATUS,
    PROTO_NAME,
    Ack,
    Upload,
    Uploader,
    decode_ack,
    request,
)

from .base import VehicleBase


async def module_states(v: VehicleBase) -> AsyncIterator[tuple[float, Ack]]:
    """The module's reports as they come (its status every 0.5 s, its answers), with their
    receive times [s, time.monotonic]."""
    stream: AsyncIterator[UnsolicitedAck] = v.command_acks()
    async for a in stream:
        ack = decode_ack(a.command, a.result, a.progress, a.result_param2)
        if ack is not None:
            yield a.t_s, ack


class _AckQueue:
    """The module's acknowledgements collected in the background (from subscription on)."""

    def __init__(self, v: VehicleBase) -> None:
        self.queue: asyncio.Queue[Ack] = asyncio.Queue()
        self._task = asyncio.get_running_loop().create_task(self._run(v))

    async def _run(self, v: VehicleBase) -> None:
        async for _, ack in module_states(v):
            self.queue.put_nowait(ack)

    async def get(self, timeout_s: float) -> Ack | None:
        try:
            return await asyncio.wait_for(self.queue.get(), max(timeout_s, 0.0))
        except TimeoutError:
            return None

    async def close(self) -> None:
        self._task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await self._task


async def module_status(v: VehicleBase, timeout_s: float = 3.0,
                        interval_s: float = 0.5) -> Ack | None:
    """Ask the module for its state (it answers to our system and component id); None if no
    answer within `timeout_s` (no module running, or its reports do not reach us)."""
    q = _AckQueue(v)
    await asyncio.sleep(0)  # let the subscription start before the first request
    cfg = v.link.config
    try:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            v.send_float_array(PROTO_NAME, OP_STATUS, request(cfg.sysid, cfg.compid))
            until = min(end, time.monotonic() + interval_s)
            while (left := until - time.monotonic()) > 0:
                ack = await q.get(left)
                if ack is not None and ack.op == OP_STATUS:
                    return ack
        return None
    finally:
        await q.close()


async def upload(v: VehicleBase, up: Upload, *, timeout_s: float = 60.0,
                 part_timeout_s: float = 0.3, retries: int = 10) -> Uploader:
    """Upload `up` part by part (each acknowledged; resent when not, after a timeout adapted
    to the measured round trip and at most `part_timeout_s`: see `Uploader`) and verify its CRC
    with the module. Returns the finished `Uploader` (`verified`, or `failed` with the reason)."""
    u = Uploader(up, timeout_s=part_timeout_s, retries=retries)
    q = _AckQueue(v)
    await asyncio.sleep(0)
    try:
        end = time.monotonic() + timeout_s
        while not u.done:
            now = time.monotonic()
            if now > end:
                u.failed = f"upload not finished within {timeout_s:g} s"
                break
            msg = u.poll(now)
            if msg is not None:
                v.send_float_array(PROTO_NAME, msg[0], msg[1])
            # until the next (re)send is due, in steps of at most part_timeout_s / 3
            ack = await q.get(min(max(u.wait_s(time.monotonic()), 0.001), part_timeout_s / 3))
            if ack is not None:
                u.on_ack(ack, time.monotonic())
        return u
    finally:
        await q.close()

