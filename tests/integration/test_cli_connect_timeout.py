"""`status` and `fly --connect` with no vehicle on the link: after `--timeout` seconds they say
that no vehicle was heard on the address and exit 3 (not "flight failed", exit 1).

Loopback only: a free port nobody sends from, or a bound socket that never answers; every
socket is closed, every subprocess bounded by a timeout.
"""

from __future__ import annotations

import re
import socket
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from companion.app.cli import main
from tests.support.mock_process import free_udp_port

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

EXIT_NO_VEHICLE = 3  # README "Conventions": no vehicle heard within --timeout
ROOT = Path(__file__).resolve().parents[2]
HANG_GUARD_S = 60.0  # far above the 0.5 s asked for: only stops a hung process


@pytest.fixture
def silent_peer() -> Iterator[int]:
    """A loopback UDP port with a socket bound to it that never sends (closed afterwards)."""
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", 0))
        yield int(s.getsockname()[1])
    finally:
        s.close()


def _status(url: str, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "companion", "status", "--connect", url, *extra],
        capture_output=True, text=True, timeout=HANG_GUARD_S, cwd=ROOT, check=False)


def _one_line(text: str) -> str:
    return re.sub(r"\s+", " ", text)


def test_status_with_nothing_listening_says_no_vehicle_heard_and_exits_3() -> None:
    url = f"udpin://127.0.0.1:{free_udp_port()}"
    proc = _status(url, "--timeout", "0.5")
    err = _one_line(proc.stderr)
    assert proc.returncode == EXIT_NO_VEHICLE, err
    assert f"no vehicle heard on {url} within 0.5 s" in err
    assert "flight failed" not in err and "Traceback" not in err


def test_status_with_a_silent_peer_exits_3(silent_peer: int) -> None:
    url = f"udpout://127.0.0.1:{silent_peer}"
    proc = _status(url, "--timeout", "0.5")
    err = _one_line(proc.stderr)
    assert proc.returncode == EXIT_NO_VEHICLE, err
    assert f"no vehicle heard on {url} within 0.5 s" in err


def test_fly_connect_timeout_exits_3_before_anything_is_flown(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    url = f"udpin://127.0.0.1:{free_udp_port()}"
    log = tmp_path / "f.tlog"
    code = main(["fly", "square", "--connect", url, "--timeout", "0.5", "--log", str(log)])
    _out, err = capsys.readouterr()
    assert code == EXIT_NO_VEHICLE, err
    assert f"no vehicle heard on {url} within 0.5 s" in _one_line(err)
    assert "flight failed" not in err
    assert not Path(f"{log}.report.json").exists()


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "soon"])
def test_bad_timeout_is_bad_input(capsys: pytest.CaptureFixture[str], value: str) -> None:
    code = main(["status", "--connect", "udpin://127.0.0.1:14540", "--timeout", value])
    _out, err = capsys.readouterr()
    assert code == 2
    assert "--timeout: expected a number > 0" in _one_line(err)
