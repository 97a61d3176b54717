"""The onboard module in real PX4 (v1.16 SITL, loaded with `dyn`): it refuses a foreign uORB
layout, refuses a corrupted upload, flies a mission uploaded by `fly --onboard` and finishes it
(lands, no failsafe) after the companion is killed mid-flight; a pilot's mode change stops it
for good, and from that hold `serve --onboard` (triggered as from QGroundControl) uploads the
mission into the stopped module, which flies it and lands, with no setpoint from the companion.
The companion runs as a subprocess, as a user runs it."""

from __future__ import annotations

import asyncio
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink import mavutil

import companion.onboard.protocol as P
from companion.aio import Vehicle, VehicleConfig
from companion.aio.onboard import _AckQueue, module_status
from companion.aio.tlog import offboard_setpoints
from companion.mavlink import LinkConfig
from gen_c import px4module
from px4_harness import Px4Sitl
from tests.support.gcs import ground_station, local_of, plan_file_items
from tests.support.onboard import module_folder, module_state, sdk_dir

REPO = Path(__file__).resolve().parents[2]
MISSION = REPO / "tests" / "data" / "missions" / "px4_short.plan"
SDK = sdk_dir()
pytestmark = pytest.mark.skipif(SDK is None, reason="no PX4 dyn SDK beside the PX4 SITL")


@pytest.fixture(scope="module")
def modules() -> Iterator[tuple[Path, Path]]:
    """(the module, one built for another vehicle_status layout), outside /tmp."""
    assert SDK is not None
    with module_folder() as d:
        good = px4module.build_px4_module(SDK, d / "ecca_onboard.px4mod")
        bad = px4module.build_px4_module(SDK, d / "ecca_onboard_other.px4mod",
                                         hash_overrides={"vehicle_status": 12345})
        yield good, bad


def _fly(px4: Px4Sitl, log: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-m", "companion", "fly", str(MISSION), "--onboard", "--connect",
         px4.url, "--target-system", str(px4.target_system), "--log", str(log)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)


def _wait_state(px4: Px4Sitl, module: Path, want: set[int], timeout_s: float,
                min_progress: float = 0.0) -> tuple[int, float]:
    end = time.monotonic() + timeout_s
    st = (-1, 0.0)
    while time.monotonic() < end:
        st = module_state(px4, module)
        if st[0] in want and st[1] >= min_progress:
            return st
        time.sleep(0.2)  # polling the module's status (bounded by the deadline)
    raise AssertionError(f"module state {st}, waited for {want} (progress {min_progress})")


async def _corrupted_upload(px4: Px4Sitl) -> P.Ack | None:
    """Upload a 2-segment trajectory whose second segment is altered after the CRC was
    taken (as a link corrupting one value would), COMMIT; the module's CRC answer."""
    law = P.LawParams((2.0, 2.0, 3.0), (2.5, 2.5, 3.0), (0.2, 0.2, 0.3), (2.0, 2.0, 3.0), 0.5,
                      0.4, 1.0, 9.80665, 0.08, 1.0, math.radians(40.0))
    cp = [[[0.0, 0.0, -float(i + k)] for i in range(8)] for k in range(2)]
    link = LinkConfig(target_sysid=px4.target_system)
    async with Vehicle.connect(px4.url, config=VehicleConfig(),
                               link_config=link) as v:
        st = await module_status(v)
        assert st is not None and st.state == P.STATE_READY
        up = P.encode_upload([0.0, 1.0, 2.0], cp, None, law, sysid=link.sysid,  # type: ignore[arg-type]
                             compid=link.compid)
        bad = list(up.segments[1])
        bad[P.S_CTRL + 4] += 0.5
        q = _AckQueue(v)
        try:
            for op, data in ((P.OP_BEGIN, up.begin), (P.OP_SEGMENT, up.segments[0]),
                             (P.OP_SEGMENT, tuple(bad)), (P.OP_COMMIT, up.commit())):
                v.send_float_array(P.PROTO_NAME, op, data)
                ack = None
                while ack is None or ack.start or (ack.op == P.OP_STATUS and not ack.crc):
                    ack = await q.get(2.0)
                    assert ack is not None, f"no answer to opcode {op}"
            return ack
        finally:
            await q.close()


def test_onboard_module_refuses_a_foreign_layout_and_a_bad_upload_and_finishes_without_the_companion(  # noqa: E501
        px4: Px4Sitl, modules: tuple[Path, Path], tmp_path: Path) -> None:
    good, other = modules
    r = px4.command("dyn", str(other), "start")
    assert r.returncode != 0 and "vehicle_status" in r.stdout and "refusing" in r.stdout
    r = px4.command("dyn", str(good), "start")
    assert r.returncode == 0, r.stdout
    # a corrupted upload: every part acknowledged, the whole refused, nothing held
    ack = asyncio.run(_corrupted_upload(px4))
    assert ack is not None and ack.crc and ack.result != 0 and ack.state == P.STATE_READY
    assert module_state(px4, good)[0] == P.STATE_READY
    # the mission, and the companion killed a third of the way through
    fly = _fly(px4, tmp_path / "flight.tlog")
    try:
        _wait_state(px4, good, {P.STATE_FLYING}, 90.0, min_progress=0.3)
        os.kill(fly.pid, signal.SIGKILL)
        fly.wait(timeout=10)
        _, progress = _wait_state(px4, good, {P.STATE_DONE}, 60.0)
        assert progress == 1.0
        # its own timing of the law's steps, as `status` prints it (the bench reads it there)
        st = px4.command("dyn", str(good), "status").stdout
        m = re.search(r"cycles (\d+), step mean (\d+) ns p99 < (\d+) ns", st)
        assert m is not None and int(m[1]) > 1000 and 0 < int(m[2]) <= int(m[3]), st
        assert re.search(r"velocity correction \S+ \S+ m/s \(4\.0 rad/s\)", st), st
        end = time.monotonic() + 40.0
        while "Disarmed by landing" not in px4.console_text() and time.monotonic() < end:
            time.sleep(0.5)  # PX4's AUTO.LAND, commanded by the module (bounded)
    finally:
        if fly.poll() is None:
            fly.kill()
            fly.wait(timeout=10)
        if fly.stdout is not None:
            fly.stdout.close()
    console = px4.console_text()
    assert "Disarmed by landing" in console, console[-2000:]
    assert "final action commanded" in console
    assert "failsafe" not in console.lower(), console[-2000:]


def test_a_pilot_mode_change_stops_the_module_for_good_then_serve_onboard_flies_from_there(
        px4: Px4Sitl, modules: tuple[Path, Path], tmp_path: Path) -> None:
    good, _ = modules
    assert px4.command("dyn", str(good), "start").returncode == 0
    fly = _fly(px4, tmp_path / "flight.tlog")
    try:
        _wait_state(px4, good, {P.STATE_FLYING}, 90.0, min_progress=0.2)
        r = px4.command("commander", "mode", "auto:loiter")  # as a pilot's switch would
        assert r.returncode == 0, r.stdout
        out, _ = fly.communicate(timeout=60)
    finally:
        if fly.poll() is None:
            fly.kill()
            fly.wait(timeout=10)
    assert fly.returncode == 1, out
    assert "stopped" in out
    assert module_state(px4, good)[0] == P.STATE_STOPPED
    time.sleep(1.5)  # the module must not take OFFBOARD back: look again after a while
    assert module_state(px4, good)[0] == P.STATE_STOPPED
    assert "OFFBOARD left: trajectory stopped" in px4.console_text()
    # the vehicle holds in the air, as after a pilot's takeoff: `serve --onboard` flies the
    # mission from there (a fresh trajectory into the stopped module)
    asyncio.run(_serve_onboard_flies_the_mission(px4, tmp_path / "serve"))


async def _serve_onboard_flies_the_mission(px4: Px4Sitl, logs: Path) -> None:
    """`serve --onboard` as a subprocess; the test plays QGroundControl (tests/support/gcs.py):
    it uploads px4_short.plan, waits for the service's onboard upload, switches to OFFBOARD.
    The module flies the rest of the mission and lands. Oracles: the service's tlog (PX4's
    LOCAL_POSITION_NED: every waypoint after the takeoff within 0.5 m; the companion's
    setpoints while PX4 said OFFBOARD, `offboard_setpoints`: none), PX4's disarm."""
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion", "serve", "--onboard", "--connect", px4.url,
        "--target-system", str(px4.target_system), "--log-dir", str(logs), cwd=REPO,
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
    t0 = time.monotonic()
    try:
        async with ground_station(px4.gcs_port, px4.target_system) as gcs:
            await gcs.wait_for(lambda: gcs.heartbeat is not None, 15.0, "PX4's HEARTBEAT")
            wire = plan_file_items(MISSION, px4.target_system)
            await gcs.upload_mission(wire)
            await gcs.wait_for(lambda: _event(logs, "onboard_loaded"), 30.0,
                               "the service's verified upload")
            await gcs.wait_for(lambda: gcs.text_seen("ecca: onboard ready"), 5.0,
                               "the announcement at the ground station")
            for _ in range(5):  # the pilot's switch (retried if PX4 is still settling)
                if await gcs.set_mode("OFFBOARD") == 0:
                    break
                await asyncio.sleep(0.3)
            await gcs.wait_for(lambda: gcs.mode == "OFFBOARD", 3.0, "OFFBOARD")
            await gcs.wait_for(lambda: not gcs.armed, 60.0, "the module's land and disarm")
            flown_s = time.monotonic() - t0
            await gcs.wait_for(lambda: gcs.text_seen("ecca: mission complete"), 5.0,
                               "the completion announced")
            if gcs.home is None:
                gcs.send(gcs.mav.command_long_encode(px4.target_system, 1, 512, 0, 242, 0, 0,
                                                     0, 0, 0, 0))  # MAV_CMD_REQUEST_MESSAGE
                await gcs.wait_for(lambda: gcs.home is not None, 5.0, "HOME_POSITION")
            home = gcs.home
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 15.0) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
    tlogs = sorted(logs.glob("serve-*.tlog"))
    track = [p for t in tlogs for p in _offboard_positions(t, px4.target_system)]
    # the mission's waypoints after the takeoff (wp 1, wp 2; the land point is wp 2's)
    wps = [(*local_of(home, m.x * 1e-7, m.y * 1e-7), home.z - m.z) for m in wire[1:3]]
    errs = [min(math.dist(p, w) for p in track) for w in wps]
    counts = [offboard_setpoints(t) for t in tlogs]
    n_sp = sum(c[0] for c in counts)
    n_hb = sum(c[1] for c in counts)
    print(f"serve --onboard: {len(track)} positions in OFFBOARD, waypoint errors "
          f"{[round(e, 3) for e in errs]} m, {n_sp} companion setpoints in OFFBOARD "
          f"({n_hb} OFFBOARD heartbeats), {flown_s:.1f} s from the service's start to disarm")
    assert len(track) > 50 and n_hb > 3
    assert max(errs) < 0.5
    assert n_sp == 0
    ev = [e["event"] for e in _events(logs)]
    assert "mission_complete" in ev and "mode_request" not in ev
    said = [str(e["text"]) for e in _events(logs) if e["event"] == "announce"]
    assert not any("module silent" in t or "answers again" in t for t in said), said


def _events(logs: Path) -> list[dict[str, object]]:
    path = logs / "events.jsonl"
    return [json.loads(x) for x in path.read_text().splitlines() if x.strip()] \
        if path.exists() else []


def _event(logs: Path, name: str) -> bool:
    return any(e["event"] == name for e in _events(logs))


def _offboard_positions(path: Path, sysid: int) -> list[tuple[float, float, float]]:
    """PX4's LOCAL_POSITION_NED in a tlog while its last HEARTBEAT said OFFBOARD."""
    log = mavutil.mavlink_connection(str(path), dialect="common")
    out, offboard = [], False
    try:
        while (m := log.recv_match(type=["HEARTBEAT", "LOCAL_POSITION_NED"])) is not None:
            if m.get_srcSystem() != sysid or m.get_srcComponent() != 1:
                continue
            if m.get_type() == "HEARTBEAT":
                offboard = ((m.custom_mode >> 16) & 0xFF) == 6  # PX4's main mode OFFBOARD
            elif offboard:
                out.append((float(m.x), float(m.y), float(m.z)))
    finally:
        log.close()
    return out
