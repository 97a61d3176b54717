"""`Vehicle.read_params` / `read_planning_params(Vehicle.fetch_params)` against the mock PX4
over loopback UDP (`python -m sitl_mock serve` subprocess): values set on the mock's command
line, an INT32 parameter (bytewise on the wire), a parameter changed by PARAM_SET from another
client (pymavlink, playing the ground station), and a name the vehicle does not have."""

from __future__ import annotations

import asyncio
import time

import pytest
from pymavlink import mavutil

from companion.aio import ParamReadError, Vehicle, VehicleConfig
from companion.planning.vehicle_params import read_planning_params
from tests.support.mock_process import bounded, free_udp_port, run_mock

# flies in wall-clock time (the mock served over a link): README's second test phase
pytestmark = pytest.mark.realtime


async def test_vehicle_reads_changed_planning_parameters_from_the_mock() -> None:
    # the GCS socket is bound before the mock starts: nothing the mock sends it is lost, and
    # no other socket can take its port in between
    gcs_port = free_udp_port()
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{gcs_port}", source_system=255,
                                     dialect="common")
    try:
        async with (
            run_mock("--param", "MPC_XY_CRUISE=8.5", "--param", "COM_OBL_RC_ACT=4",
                     "--param", "MPC_LAND_ALT1=12", gcs_port=gcs_port) as mock,
            Vehicle.connect(f"udpin://127.0.0.1:{mock.client_port}",
                            config=VehicleConfig(connect_timeout_s=15.0)) as v,
        ):
            got = await bounded(v.read_params(["MPC_XY_CRUISE", "COM_OBL_RC_ACT"]), 10.0,
                                "the parameter read")
            assert got == {"MPC_XY_CRUISE": 8.5, "COM_OBL_RC_ACT": 4.0}

            # the ground station changes a parameter; the next read sees it
            # (the mock sends first on its GCS link: its HEARTBEAT gives pymavlink the peer)
            assert await bounded(_recv(gcs, "HEARTBEAT"), 20.0, "the GCS link") is not None
            await asyncio.to_thread(_drain, gcs)  # telemetry queued since the mock started
            gcs.mav.param_set_send(1, 1, b"MPC_TKO_SPEED", 2.75,
                                   mavutil.mavlink.MAV_PARAM_TYPE_REAL32)
            echo = await bounded(_recv(gcs, "PARAM_VALUE", "MPC_TKO_SPEED"), 20.0,
                                 "the PARAM_SET echo")
            assert echo is not None
            r = await bounded(read_planning_params(v.fetch_params, {"NAV_ACC_RAD": 0.5}), 10.0,
                              "the planning parameter read")
            assert r.params.MPC_XY_CRUISE == 8.5 and r.params.MPC_LAND_ALT1 == 12.0
            assert r.params.MPC_TKO_SPEED == 2.75
            assert r.params.NAV_ACC_RAD == 0.5 and r.source["NAV_ACC_RAD"] == "file"
            assert r.vehicle_values["NAV_ACC_RAD"] == 2.0 and r.warnings == ()

            with pytest.raises(ParamReadError, match="no answer for MPC_NOT_A_PARAM") as exc:
                await bounded(v.read_params(["MPC_XY_CRUISE", "MPC_NOT_A_PARAM"]), 10.0,
                              "the failing read")
            assert exc.value.missing == ("MPC_NOT_A_PARAM",)
            assert exc.value.values == {"MPC_XY_CRUISE": 8.5}
            with pytest.raises(ParamReadError, match=r"COM_OBL_RC_ACT.*INT32"):
                await v.read_params(["COM_OBL_RC_ACT"], floats_only=True)
    finally:
        gcs.close()


async def _recv(gcs: mavutil.mavfile, kind: str, param_id: str | None = None) -> object | None:
    """The next ``kind`` message on the GCS link (with that ``param_id`` if given; 15 s at
    most), off the event loop."""
    def wait() -> object | None:
        deadline = time.monotonic() + 15.0
        while (left := deadline - time.monotonic()) > 0:
            m = gcs.recv_match(type=kind, blocking=True, timeout=left)
            if m is not None and (param_id is None or m.param_id == param_id):
                return m
        return None
    return await asyncio.to_thread(wait)


def _drain(gcs: mavutil.mavfile) -> None:
    """Read away what the GCS socket holds now (bounded: 10,000 messages)."""
    for _ in range(10_000):
        if gcs.recv_msg() is None:
            return
