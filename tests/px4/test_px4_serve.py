"""`python -m companion serve` against real PX4 v1.16 SITL, the test playing QGroundControl on
PX4's GCS link (pymavlink, tests/support/gcs.py): upload a mission, arm and take off in AUTO,
OFFBOARD -> the service flies the smooth mission; Hold (AUTO.LOITER: PX4 refuses POSCTL without RC)
mid-way -> it stops; OFFBOARD again -> it resumes from there and at the end switches PX4 to
LAND. Oracles: PX4's HEARTBEAT and LOCAL_POSITION_NED as the GCS sees them, the service's event
log. About 60-75 s (PX4 runs in real time).
"""

from __future__ import annotations

import asyncio
import contextlib
import itertools
import json
import math
import re
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavutil

from px4_harness import Px4Sitl
from tests.integration.test_serve_mock import relay
from tests.support.gcs import Gcs, ground_station, local_of, plan_file_items
from tests.support.mock_process import free_udp_port

REPO = Path(__file__).resolve().parents[2]
MISSION = REPO / "tests" / "data" / "missions" / "px4_short.plan"
# px4_short.plan: takeoff to 4 m at home, (10, 0), (10, 8), land there (NED from home, m)
WP1, WP2 = (10.0, 0.0), (10.0, 8.0)


def dist_xy(p: tuple[float, ...] | None, q: tuple[float, float]) -> float:
    return math.inf if p is None else math.hypot(p[0] - q[0], p[1] - q[1])


def events(folder: Path) -> list[dict[str, object]]:
    path = folder / "events.jsonl"
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def takeover_unix_s(folder: Path, after_s: float, px4_sysid: int) -> float:
    """Unix time of PX4's first ATTITUDE_TARGET after ``after_s`` that echoes one of the
    service's SET_ATTITUDE_TARGETs of the 0.5 s before it (thrust within 1e-3, attitude within
    ~1 deg), from the service's tlogs: PX4 flies the service's setpoints from then on (until
    then its own position control may still fly, see HANDOVER_S)."""
    ours: list[tuple[float, tuple[float, ...], float]] = []
    for path in sorted(folder.glob("*.tlog")):
        log = mavutil.mavlink_connection(str(path), dialect="common")
        try:
            kinds = ["SET_ATTITUDE_TARGET", "ATTITUDE_TARGET"]
            while (m := log.recv_match(type=kinds)) is not None:
                t = float(m._timestamp)
                if t < after_s:
                    continue
                if m.get_type() == "SET_ATTITUDE_TARGET":
                    ours.append((t, tuple(m.q), float(m.thrust)))
                elif m.get_srcSystem() == px4_sysid:
                    for ts, q, thrust in reversed(ours):
                        if t - ts > 0.5:
                            break
                        if abs(thrust - m.thrust) < 1e-3 and abs(
                                sum(a * b for a, b in zip(q, m.q, strict=True))) > 0.99996:
                            return t
        finally:
            log.close()
    raise AssertionError("PX4 never flew the service's attitude setpoints after the resume")


async def pilot_takes_off(gcs: Gcs) -> None:
    for _ in range(40):  # EKF2 needs a few seconds after boot (bounded retries)
        if await gcs.command(400, 1.0) == 0:
            break
        await asyncio.sleep(0.5)
    await gcs.wait_for(lambda: gcs.armed, 5.0, "armed")
    assert await gcs.command(22, 0, 0, 0, math.nan, math.nan, math.nan, math.nan) == 0
    await gcs.wait_for(lambda: gcs.position is not None and gcs.position[2] < -2.0
                       and gcs.mode == "HOLD", 30.0, "the takeoff to end in Hold")


async def test_px4_serve_flies_pauses_resumes_and_lands(px4: Px4Sitl, tmp_path: Path) -> None:
    logs = tmp_path / "serve"
    proc = await asyncio.create_subprocess_exec(
        sys.executable, "-m", "companion", "serve", "--connect", px4.url,
        "--target-system", str(px4.target_system), "--log-dir", str(logs),
        stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
    gcs_seen: list[Gcs] = []
    try:
        async with ground_station(px4.gcs_port, px4.target_system) as gcs:
            gcs_seen.append(gcs)
            await gcs.wait_for(lambda: gcs.heartbeat is not None, 15.0, "PX4's HEARTBEAT")
            await gcs.upload_mission(plan_file_items(MISSION, px4.target_system))
            await gcs.wait_for(lambda: any(e["event"] == "mission_planned"
                                           for e in events(logs)), 20.0, "the plan")
            # the announcement reaches the ground station through PX4's forwarding
            await gcs.wait_for(lambda: gcs.text_seen("ecca: mission"), 5.0,
                               "the STATUSTEXT announcement at the GCS")
            # the ground station's LOCAL_POSITION_NED at 20 Hz (PX4's GCS link sends ~1 Hz)
            assert await gcs.command(511, 32, 50_000) == 0
            # ... and PX4 SITL's ground truth (HIL_STATE_QUATERNION) at 50 Hz
            assert await gcs.command(511, 115, 20_000) == 0
            await pilot_takes_off(gcs)
            assert await gcs.set_mode("OFFBOARD") == 0
            await gcs.wait_for(lambda: gcs.mode == "OFFBOARD", 3.0, "OFFBOARD")
            await gcs.wait_for(lambda: dist_xy(gcs.position, WP1) < 1.5, 30.0, "wp 1")
            # the pilot takes over just after wp 1 (the plan reaches 5 m/s within ~2 m, PX4's
            # MPC_ACC_HOR_MAX)
            await gcs.wait_for(lambda: gcs.position[1] > 0.3, 15.0, "leaving wp 1")  # type: ignore[index]
            assert await gcs.set_mode("HOLD") == 0
            await gcs.wait_for(lambda: gcs.mode == "HOLD", 3.0, "Hold")
            i_hold = len(gcs.track)
            t_hold = gcs.track[-1].t
            await gcs.wait_for(lambda: gcs.track[-1].t > t_hold + 3.0, 8.0, "3 s in Hold")
            held = [s.pos_ned for s in gcs.track[i_hold:]]
            assert min(dist_xy(p, WP2) for p in held) > 2.0  # braked short of wp 2
            # the pilot hands back once PX4's Hold has stopped pulling back from its braking
            # overshoot (it may take longer than 3 s: then the service starts from that motion)
            with contextlib.suppress(AssertionError):
                await gcs.wait_for(lambda: len(gcs.track) > 10 and all(
                    math.hypot(*s.vel_ned[:2]) < 0.1 for s in gcs.track[-10:]), 6.0, "rest")
            i_resume = len(gcs.track)
            for _ in range(5):  # the pilot retries if PX4 is still settling into Hold
                if await gcs.set_mode("OFFBOARD") == 0:
                    break
            await gcs.wait_for(lambda: gcs.mode == "LAND", 30.0, "the service's LAND")
            resumed = [s for s in gcs.track[i_resume:] if s.mode == "OFFBOARD"]
            closest = min(dist_xy(s.pos_ned, WP2) for s in resumed)
            # resumed from where it held, on to wp 2 (along +y): never back toward wp 1 (until
            # it arrives at wp 2, where it stops and may come back from an overshoot). Judged
            # on PX4's ground truth, not its estimate: EKF2's position on SIH is corrected by
            # tenths of a metre, once 2.2 m, after the braking of a Hold, which counts as a
            # flight back that never happened. But PX4's estimate is all the service has, and
            # on this VM EKF2 can be far off after a Hold (CI and a loaded host, 2026-11-29):
            # velocity 0.3-0.75 m/s, attitude ~2 deg (a "level" vehicle accelerating at
            # 0.3 m/s^2), its position lagging the truth. PX4's own control flies on it from
            # the pilot's switch (its Hold, then serve's hold setpoint until the service sees
            # the switch by a 1 Hz HEARTBEAT and PX4 applies the service's attitude setpoints
            # at its 2 Hz control mode update). So: (1) the resumed leg never goes back faster
            # than 0.6 m/s (a join led a stopped vehicle back at 0.5 m/s in session 16; braking
            # EKF2's velocity error flew back at 0.8-1.05 m/s before the velocity correction;
            # at most 0.37 since); (2) from when PX4 flies the service's setpoints (its
            # ATTITUDE_TARGET echoes them) the service does not add to the motion back it took
            # over by more than that attitude error gives in its 0.6 s handover (0.2 m/s):
            # before the correction it added 0.34-0.36, since then 0.11-0.18.
            leg = list(itertools.takewhile(lambda s: dist_xy(s.pos_ned, WP2) > 1.0, resumed))
            t0, t1 = gcs.track[i_resume].t, leg[-1].t
            true_leg = [u for u in gcs.truth if resumed[0].t <= u.t <= t1]
            back_m_s = max(-u.vel_ned[1] for u in true_leg)
            had_m_s = max([0.0, *(-u.vel_ned[1] for u in gcs.truth if abs(u.t - t0) < 0.1)])
            unix = time.time() - time.monotonic()  # the tlogs' clock less the ground's
            t_ctl = takeover_unix_s(logs, t0 + unix, px4.target_system) - unix
            ctl_leg = [u for u in gcs.truth if t_ctl <= u.t <= t1]
            took_m_s = max([0.0, *(-u.vel_ned[1] for u in gcs.truth if abs(u.t - t_ctl) < 0.1)])
            ctl_back_m_s = max(-u.vel_ned[1] for u in ctl_leg)
            est_m_s = max(-s.vel_ned[1] for s in leg)
            start_y = gcs.track[i_resume].pos_ned[1]
            back_m = start_y - min(s.pos_ned[1] for s in leg)
            print(f"resume: {len(resumed)} samples, closest to wp 2 {closest:.2f} m, toward "
                  f"wp 1 at most {back_m_s:.2f} m/s (had {had_m_s:.2f} at the switch); from the "
                  f"service's control {t_ctl - t0:.2f} s later {ctl_back_m_s:.2f} m/s (took over "
                  f"{took_m_s:.2f}); by the estimate {est_m_s:.2f} m/s and {back_m:.2f} m")
            assert len(resumed) > 20 and closest < 1.5 and len(true_leg) > 50
            assert len(ctl_leg) > 50
            assert back_m_s < 0.6
            assert ctl_back_m_s < max(0.3, took_m_s + 0.2)
            # the service's part: it hands over at the land point (its settle_m, 0.5 m), by
            # the position it requested LAND at. The ground station's first position in LAND
            # comes with the next 1 Hz HEARTBEAT, up to a second into PX4's LAND, which holds
            # its entry point on EKF2's estimate (corrected by tenths of a metre here)
            req = [e for e in events(logs) if e["event"] == "mode_request"
                   and e["mode"] == "LAND"]
            assert req and req[0]["pos_ned"] is not None
            # the land point where PX4's local frame has it: the plan's wp 2 (lat/lon) from
            # PX4's HOME_POSITION. (10, 8) assumes the local origin is the plan's home; EKF2
            # sets it from SIH's noisy GPS, 0.05-0.4 m away (CI had a request 0.60 m from
            # (10, 8) that the service measured within 0.5 m of its plan's end)
            if gcs.home is None:
                gcs.send(gcs.mav.command_long_encode(px4.target_system, 1, 512, 0, 242, 0, 0, 0,
                                                     0, 0, 0))  # MAV_CMD_REQUEST_MESSAGE
                await gcs.wait_for(lambda: gcs.home is not None, 5.0, "HOME_POSITION")
            wp2_item = json.loads(MISSION.read_text())["mission"]["items"][2]["params"]
            land_pt = local_of(gcs.home, float(wp2_item[4]), float(wp2_item[5]))
            at_request = dist_xy(tuple(req[0]["pos_ned"]), land_pt)  # type: ignore[arg-type]
            await gcs.wait_for(lambda: gcs.track[-1].mode == "LAND", 5.0, "a position in LAND")
            handover = next(s.pos_ned for s in gcs.track[i_resume:] if s.mode == "LAND")
            # the service's own measure when it decided: within settle_m of its plan's end
            own = re.search(r"trajectory complete, ([0-9.]+) m from its end", req[0]["why"])
            print(f"handover to LAND {at_request:.2f} m from the land point (the service: "
                  f"{own.group(1) if own else '?'} m from its plan's end; the ground station: "
                  f"{dist_xy(handover, land_pt):.2f} m; the land point is "
                  f"{dist_xy(land_pt, WP2):.2f} m from (10, 8))")
            assert own is not None and float(own.group(1)) <= 0.5, req[0]["why"]
            assert at_request < 0.5 and dist_xy(handover, land_pt) < 1.0
            await gcs.wait_for(lambda: not gcs.armed, 40.0, "landing and disarm")
            # PX4's part: its LAND holds the entry point on EKF2's estimate, which on SIH drifts
            # 1.0-1.4 m during the descent after a flight (ULog, truth and estimate alike: a
            # 2-3 deg roll estimate error; PX4's own AUTO.MISSION of this file drifted 1.0 m in
            # its descent); CI saw 2.45 m once, after a resume that swung back and forth
            assert dist_xy(gcs.track[-1].pos_ned, WP2) < 2.5
            ev = events(logs)
            flights = [e for e in ev if e["event"] == "state" and e["state"] == "mission"]
            assert len(flights) == 2
            assert any(e["event"] == "mode_request" and e["mode"] == "LAND" for e in ev)
            err = np.array([dist_xy(s.pos_ned, WP2) for s in gcs.track[-20:]])
            print("landed within", float(err.max()), "m of the land point")
        proc.send_signal(signal.SIGTERM)
        assert await asyncio.wait_for(proc.wait(), 15.0) == 0
    finally:
        if proc.returncode is None:
            proc.kill()
            await proc.wait()
        if gcs_seen:  # for a post-mortem beside the service's tlog: what the ground saw
            g = gcs_seen[0]
            (tmp_path / "ground.json").write_text(json.dumps({
                "unix_minus_monotonic": time.time() - time.monotonic(),
                "track": [[s.t, s.pos_ned, s.vel_ned, s.mode] for s in g.track],
                "truth": [[u.t, u.vel_ned] for u in g.truth]}))
        if (logs / "events.jsonl").exists():
            print((logs / "events.jsonl").read_text()[-3000:])


async def test_px4_serve_link_loss_and_kill_leave_it_to_px4s_failsafe(
        px4: Px4Sitl, tmp_path: Path) -> None:
    """Link cut (a UDP relay between PX4's onboard link and the service drops everything) ->
    PX4's offboard-loss failsafe; link back -> the service streams hold again and OFFBOARD
    resumes the mission; SIGKILL -> the failsafe again."""
    logs = tmp_path / "serve"
    svc_port = free_udp_port()
    async with relay(px4.port, svc_port) as link, ground_station(
            px4.gcs_port, px4.target_system) as gcs:
        proc = await asyncio.create_subprocess_exec(
            sys.executable, "-m", "companion", "serve", "--connect",
            f"udpin://127.0.0.1:{svc_port}", "--target-system", str(px4.target_system),
            "--log-dir", str(logs),
            stdout=asyncio.subprocess.DEVNULL, stderr=asyncio.subprocess.DEVNULL)
        try:
            await gcs.wait_for(lambda: gcs.heartbeat is not None, 15.0, "PX4's HEARTBEAT")
            await gcs.upload_mission(plan_file_items(MISSION, px4.target_system))
            await gcs.wait_for(lambda: any(e["event"] == "mission_planned"
                                           for e in events(logs)), 20.0, "the plan")
            await pilot_takes_off(gcs)
            assert await gcs.set_mode("OFFBOARD") == 0
            await gcs.wait_for(lambda: gcs.position[0] > 3.0, 20.0, "mission flight")  # type: ignore[index]
            n = len(events(logs))
            link.drop = True
            await gcs.wait_for(lambda: gcs.mode != "OFFBOARD", 5.0, "PX4's failsafe")
            print("link loss ->", gcs.mode, "system_status", gcs.heartbeat.system_status)
            assert gcs.heartbeat.system_status == 5  # CRITICAL: a failsafe, not a mode change
            assert await gcs.set_mode("HOLD") == 0  # the pilot stops the no-RC descent
            await gcs.wait_for(lambda: any(e["event"] == "link" and e["ok"] is False
                                           for e in events(logs)[n:]), 10.0, "link lost seen")
            n = len(events(logs))
            link.drop = False
            await gcs.wait_for(lambda: any(e["event"] == "link" and e["ok"] is True
                                           for e in events(logs)[n:]), 15.0, "relink seen")
            for _ in range(10):  # the first hold setpoints may still be on their way
                if await gcs.set_mode("OFFBOARD") == 0:
                    break
            await gcs.wait_for(lambda: gcs.mode == "OFFBOARD", 3.0, "OFFBOARD again")
            await gcs.wait_for(lambda: sum(e["event"] == "state" and e["state"] == "mission"
                                           for e in events(logs)) >= 2, 5.0, "the resume")
            proc.kill()
            await proc.wait()
            await gcs.wait_for(lambda: gcs.mode != "OFFBOARD", 5.0, "failsafe after the kill")
            print("kill ->", gcs.mode, "system_status", gcs.heartbeat.system_status)
            assert gcs.heartbeat.system_status == 5
        finally:
            if proc.returncode is None:
                proc.kill()
                await proc.wait()


pytestmark = pytest.mark.px4
