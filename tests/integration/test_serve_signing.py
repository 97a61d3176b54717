"""`companion serve --signing-key` against a keyed mock (`sitl_mock serve --signing-key`): with
the mock's key the service connects (its events.jsonl says so); with another key it never does
and says why (the connect error names the differing keys)."""

from __future__ import annotations

import asyncio
import os
from collections.abc import Callable
from pathlib import Path

import pytest

from tests.integration.test_serve_mock import Service, run_service
from tests.support.mock_process import run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime


def _key(path: Path, seed: int) -> Path:
    path.write_text(bytes((seed + i) % 256 for i in range(32)).hex())
    os.chmod(path, 0o600)
    return path


async def _wait_event(svc: Service, pred: Callable[[dict[str, object]], bool],
                      timeout_s: float) -> list[dict[str, object]]:
    """The service's events once one satisfies `pred`, or all of them after `timeout_s`."""
    loop = asyncio.get_running_loop()
    deadline = loop.time() + timeout_s
    while loop.time() < deadline:
        evs = svc.events()
        if any(pred(e) for e in evs):
            return evs
        await asyncio.sleep(0.1)  # poll the service's log file (bounded)
    return svc.events()


@pytest.mark.parametrize("same_key", [True, False])
async def test_serve_connects_only_with_the_vehicles_signing_key(tmp_path: Path,
                                                                 same_key: bool) -> None:
    mock_key = _key(tmp_path / "vehicle.key", 7)
    svc_key = mock_key if same_key else _key(tmp_path / "other.key", 99)
    async with run_mock("--signing-key", str(mock_key)) as mock, \
            run_service(mock.client_port, tmp_path / "logs", "--signing-key", str(svc_key)) as svc:
        if same_key:
            evs = await _wait_event(svc, lambda e: e.get("event") == "connected", 30.0)
            assert any(e.get("event") == "connected" for e in evs), evs
        else:
            evs = await _wait_event(svc, lambda e: "differ" in str(e), 30.0)
            assert not any(e.get("event") == "connected" for e in evs), evs
            assert any("differ" in str(e) for e in evs), evs
