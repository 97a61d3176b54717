"""MAVLink 2 signing against real PX4 v1.16 SITL, which has none (signing arrived in later PX4
with MAV_SIGN_CFG and SETUP_SIGNING): it sends unsigned frames and ignores signatures. What is
testable there: a keyed companion hears nothing from it and says why, and PX4 v1.16 obeys a
command signed with an arbitrary key (the keyed mock is the stand-in for a signing autopilot)."""

from __future__ import annotations

import os
import socket
import time

import pytest
from pymavlink.dialects.v20 import common as m

from companion.aio import ConnectTimeoutError, Vehicle, VehicleConfig
from companion.mavlink import LinkConfig, SigningConfig
from px4_harness import Px4Sitl


def _recv_until(sock: socket.socket, rx: m.MAVLink, pred: object, timeout_s: float) -> object:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        sock.settimeout(max(deadline - time.monotonic(), 0.01))
        try:
            data, addr = sock.recvfrom(65536)
        except TimeoutError:
            break
        for msg in rx.parse_buffer(data) or []:
            if pred(msg):  # type: ignore[operator]
                return msg, addr
    pytest.fail(f"nothing matching within {timeout_s} s")


async def test_px4_v1_16_neither_signs_nor_checks_signatures(px4: Px4Sitl) -> None:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind(("127.0.0.1", px4.port))
        rx = m.MAVLink(None)
        rx.robust_parsing = True
        hb, addr = _recv_until(sock, rx, lambda x: x.get_type() == "HEARTBEAT", 10.0)  # type: ignore[misc]
        assert not hb.get_msgbuf()[2] & 0x01  # PX4 v1.16 does not sign
        tx = m.MAVLink(None, srcSystem=1, srcComponent=191)
        tx.signing.secret_key = os.urandom(32)  # a key PX4 was never given
        tx.signing.sign_outgoing = True
        tx.signing.timestamp = int((time.time() - 1_420_070_400) * 100_000)
        sock.sendto(m.MAVLink_command_long_message(
            px4.target_system, 1, 31999, 0, 0, 0, 0, 0, 0, 0, 0).pack(tx), addr)
        ack, _ = _recv_until(sock, rx, lambda x: x.get_type() == "COMMAND_ACK"  # type: ignore[misc]
                             and x.command == 31999, 5.0)
        assert ack.result == 3  # answered (UNSUPPORTED): the signature was not checked
    finally:
        sock.close()

    link = LinkConfig(target_sysid=px4.target_system, signing=SigningConfig(os.urandom(32)))
    with pytest.raises(ConnectTimeoutError, match="unsigned frames dropped"):
        await Vehicle.connect(px4.url, config=VehicleConfig(connect_timeout_s=4.0),
                              link_config=link)
