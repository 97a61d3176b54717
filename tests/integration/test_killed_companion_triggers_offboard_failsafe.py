"""Killing the companion mid-flight triggers the mock PX4's offboard-loss failsafe.

`python -m companion fly figure8` runs as a subprocess against a `sitl_mock serve` subprocess
over loopback UDP. The test watches the mock through its GCS link (a second UDP port, decoded
with pymavlink), SIGKILLs the companion while the vehicle is in OFFBOARD, and checks from the
GCS-link HEARTBEATs that the vehicle leaves OFFBOARD for the failsafe mode (POSCTL, default
COM_OBL_RC_ACT 0) within ~2 s of the mock's own clock, and that STATUSTEXT "Failsafe" arrives.
(`run_mock` / `mock_px4` start the mock with `--no-gcs`, hence the dedicated start here.)
"""

from __future__ import annotations

import contextlib
import re
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink

from tests.support.mock_process import free_udp_port

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime

OFFBOARD, POSCTL = 6, 3
MAV_STATE_CRITICAL = 5
COM_OF_LOSS_T_S = 1.0  # the mock's default offboard-loss timeout (PX4 COM_OF_LOSS_T)


@dataclass
class GcsView:
    """What the GCS link has shown so far (mock clock from ATTITUDE.time_boot_ms)."""

    sock: socket.socket
    parser: Any = field(default_factory=lambda: mavlink.MAVLink(None))
    boot_s: float = -1.0  # latest time_boot of the mock seen [s]
    heartbeats: list[tuple[float, int, int, int]] = field(default_factory=list)
    texts: dict[int, dict[int, str]] = field(default_factory=dict)  # id -> chunk_seq -> text
    text_boot_s: dict[int, float] = field(default_factory=dict)

    def pump(self, until: float) -> None:
        """Read datagrams until the wall-clock deadline `until` (monotonic) or none pending."""
        while time.monotonic() < until:
            try:
                data = self.sock.recv(65535)
            except TimeoutError:
                return
            for msg in self.parser.parse_buffer(data) or []:
                self._handle(msg)

    def _handle(self, msg: Any) -> None:
        kind = msg.get_type()
        if msg.get_srcSystem() != 1 or msg.get_srcComponent() != 1:
            return
        if kind == "ATTITUDE":
            self.boot_s = max(self.boot_s, msg.time_boot_ms / 1000.0)
        elif kind == "HEARTBEAT":
            main = (msg.custom_mode >> 16) & 0xFF
            self.heartbeats.append((self.boot_s, main, msg.base_mode, msg.system_status))
        elif kind == "STATUSTEXT":
            key = msg.id if msg.id else -len(self.text_boot_s) - 1
            self.texts.setdefault(key, {})[msg.chunk_seq] = msg.text
            self.text_boot_s.setdefault(key, self.boot_s)

    def statustexts(self) -> list[tuple[float, str]]:
        return [
            (self.text_boot_s[k], "".join(ch[i] for i in sorted(ch)))
            for k, ch in self.texts.items()
        ]


@contextlib.contextmanager
def mock_with_gcs(client_port: int, gcs_port: int) -> Iterator[subprocess.Popen[str]]:
    p = subprocess.Popen(
        [
            sys.executable, "-m", "sitl_mock", "serve",
            "--bind", "127.0.0.1:0", "--remote", f"127.0.0.1:{client_port}",
            "--gcs-bind", "127.0.0.1:0", "--gcs-remote", f"127.0.0.1:{gcs_port}",
            "--estimator-ready", "0.5",
        ],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )
    try:
        assert p.stdout is not None
        line = p.stdout.readline()
        assert re.search(r"gcs=127\.0\.0\.1:\d+->127\.0\.0\.1:" + str(gcs_port), line), line
        yield p
    finally:
        p.terminate()
        try:
            p.wait(5)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait(5)
        if p.stdout is not None:
            p.stdout.close()


def test_killing_the_companion_triggers_the_offboard_loss_failsafe(tmp_path: Path) -> None:
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.1)
    client_port = free_udp_port()
    out = open(tmp_path / "companion.out", "w")  # noqa: SIM115 - closed in finally
    companion: subprocess.Popen[str] | None = None
    try:
        with mock_with_gcs(client_port, gcs.getsockname()[1]):
            companion = subprocess.Popen(
                [
                    sys.executable, "-m", "companion", "fly", "figure8",
                    "--connect", f"udpin://127.0.0.1:{client_port}",
                    "--size", "6", "--speed", "2", "--alt", "2.5",
                    "--log", str(tmp_path / "killed.tlog"),
                ],
                stdout=out, stderr=subprocess.STDOUT, text=True,
            )
            view = GcsView(gcs)
            # 1. wait (bounded) until the GCS link shows the vehicle armed in OFFBOARD
            deadline = time.monotonic() + 45.0
            while time.monotonic() < deadline and not any(
                main == OFFBOARD and base & 128 for _, main, base, _ in view.heartbeats
            ):
                assert companion.poll() is None, "the companion exited before OFFBOARD"
                view.pump(time.monotonic() + 0.2)
            assert any(main == OFFBOARD for _, main, _, _ in view.heartbeats), (
                f"never saw OFFBOARD on the GCS link: {view.heartbeats[-5:]}"
            )
            # 2. let the companion fly the pattern a moment, then kill it without warning
            view.pump(time.monotonic() + 0.7)
            assert companion.poll() is None
            companion.send_signal(signal.SIGKILL)
            kill_boot_s = view.boot_s
            companion.wait(5)
            n_before = len(view.heartbeats)
            assert view.heartbeats[-1][1] == OFFBOARD, "not in OFFBOARD when the companion died"
            # 3. the mock must fail safe by itself
            deadline = time.monotonic() + 6.0
            while time.monotonic() < deadline and all(
                main == OFFBOARD for _, main, _, _ in view.heartbeats[n_before:]
            ):
                view.pump(time.monotonic() + 0.2)
            view.pump(time.monotonic() + 0.3)  # STATUSTEXT chunks around the mode change
            after = [hb for hb in view.heartbeats[n_before:] if hb[1] != OFFBOARD]
            assert after, f"still OFFBOARD 6 s after the companion was killed: {view.heartbeats}"
            boot_s, main, base, status = after[0]
            delay_s = boot_s - kill_boot_s
            assert main == POSCTL, f"failsafe mode {main}, expected POSCTL (3)"
            assert status == MAV_STATE_CRITICAL and base & 128, (status, base)
            # the mock's clock: loss declared COM_OF_LOSS_T after the last setpoint, the action
            # 0.5 s later (PX4: HEARTBEAT leaves OFFBOARD 1.3-1.7 s after the last setpoint)
            assert COM_OF_LOSS_T_S - 0.1 <= delay_s <= 2.0, (
                f"left OFFBOARD {delay_s:.2f} s after the kill (mock clock)"
            )
            texts = [(t, s) for t, s in view.statustexts() if t >= kill_boot_s - 0.1]
            assert any(s.startswith("Failsafe") for _, s in texts), texts
            print(f"OFFBOARD -> POSCTL {delay_s:.2f} s after SIGKILL (mock clock); texts {texts}")
    finally:
        if companion is not None and companion.poll() is None:
            companion.kill()
            companion.wait(5)
        out.close()
        gcs.close()
