"""The lockstep link: the companion's `VehicleLink` and the `sitl_mock` autopilot core over an
in-memory link on a simulated clock, every frame tapped to a tlog.

Nothing here sleeps or reads a clock: both sides are sans-IO and advance together when the
caller asks, so a replay runs as fast as the CPU allows and is deterministic for a seed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from companion.aio.tlog import TlogWriter
from companion.mavlink.link import LinkConfig, VehicleLink
from companion.mavlink.params import ParamReadDone, ParamType
from companion.mission.px4_params import PLANNING_PARAM_NAMES
from companion.replay.config import TLOG_EPOCH_S, ReplayConfig
from sitl_mock.lockstep import LockstepSim

#: Messages the companion acts on during a replay; others (ATTITUDE at 100 Hz, ODOMETRY,
#: GLOBAL_POSITION_INT, targets, battery...) go to the tlog undecoded to save CPU.
COMPANION_MSG_IDS = frozenset(
    {
        0,  # HEARTBEAT
        1,  # SYS_STATUS
        31,  # ATTITUDE_QUATERNION
        32,  # LOCAL_POSITION_NED
        22,  # PARAM_VALUE (the planning parameters, read before planning)
        39, 40, 42, 44, 45, 46, 47, 51, 73, 77,  # MISSION_* and COMMAND_ACK
        111,  # TIMESYNC
        242,  # HOME_POSITION
        245,  # EXTENDED_SYS_STATE
        253,  # STATUSTEXT
    }
)


#: Telemetry streams of the mock the companion never reads (ATTITUDE, GLOBAL_POSITION_INT,
#: ATTITUDE_TARGET, POSITION_TARGET_LOCAL_NED, ODOMETRY: two thirds of its datagrams): a flight
#: that keeps no tlog has the mock leave them unbuilt (`LockstepSim`'s `unread_streams`); the
#: datagrams the companion reads are the same, byte for byte, so is the flight.
UNREAD_STREAMS = frozenset({30, 33, 83, 85, 331})
assert not UNREAD_STREAMS & COMPANION_MSG_IDS


def _msgid(frame: bytes) -> int | None:
    """Message id of a single MAVLink 2 frame, or None if it is not one."""
    if len(frame) < 12 or frame[0] != 0xFD:
        return None
    return frame[7] | (frame[8] << 8) | (frame[9] << 16)


class LockstepLink:
    """The companion's `VehicleLink` on `sitl_mock`'s lockstep pipe (`LockstepSim`), with a
    tlog tap: every frame both ways is logged at the simulated time it crossed.

    Each datagram of the mock is one frame; frames whose id is not in `wanted` are logged but
    not decoded (None decodes everything). `on_message(msg, t)` sees every decoded message.
    """

    def __init__(
        self,
        sim: LockstepSim,
        link: VehicleLink,
        tlog: TlogWriter | None,
        wanted: frozenset[int] | None = COMPANION_MSG_IDS,
    ) -> None:
        self.wanted = wanted
        self.sim = sim
        self.link = link
        self.tlog = tlog
        self.on_message: Callable[[Any, float], None] | None = None

    @property
    def now(self) -> float:
        """Simulated seconds since the mock booted."""
        return self.sim.now

    def to_vehicle(self, frames: list[bytes]) -> None:
        """Deliver the companion's frames to the mock now (one datagram each)."""
        sim = self.sim
        if self.tlog is not None:
            self.tlog.write_many(frames, TLOG_EPOCH_S + sim.now)
        for fr in frames:
            sim.send(fr)

    def advance(self, t: float) -> list[Any]:
        """Advance both sides to `t`; returns the link events produced."""
        sim = self.sim
        sim.step_until(t)
        events: list[Any] = []
        tlog = self.tlog
        wanted = self.wanted
        on_message = self.on_message
        link = self.link
        out = sim.recv()
        if tlog is not None and out:
            tlog.write_many(out, TLOG_EPOCH_S + t)
        for data in out:
            if wanted is not None and _msgid(data) not in wanted:
                continue
            for msg in link.codec.decode(data):
                if on_message is not None:
                    on_message(msg, t)
                events += link.handle_message(msg, t)
        events += link.handle_timer(t)
        frames = link.frames_to_send()
        if frames:
            self.to_vehicle(frames)
        return events


def make_sim(config: ReplayConfig, home: tuple[float, float, float], *,
             unread: frozenset[int] = frozenset()) -> LockstepSim:
    """A fresh mock for `config` (its mock parameters, start offset, link faults and wind)
    booting at `home` (lat [deg], lon [deg], alt AMSL [m]) at simulated t = 0; `unread`:
    telemetry streams nobody reads nor logs (e.g. `UNREAD_STREAMS` without a tlog)."""
    from gen_c.native import NativeBuildError
    from sitl_mock.faults import LinkFaults
    from sitl_mock.params import ParamStore

    if config.start_offset_ne_m != (0.0, 0.0):
        from sitl_mock.vehicle import ned_to_geodetic

        n, e = config.start_offset_ne_m
        home = ned_to_geodetic((n, e, 0.0), home)  # the vehicle boots (and PX4's home is) here
    faults = None
    if config.latency_s or config.jitter_s or config.loss_pct:
        # the mock's view: in = companion -> vehicle (setpoints, commands), out = telemetry
        f_in = LinkFaults(loss_pct=config.loss_pct)
        f_out = LinkFaults(loss_pct=config.loss_pct, latency_s=config.latency_s,
                           jitter_s=config.jitter_s)
        faults = (f_in, f_out)
    try:
        sim = LockstepSim(config.vehicle, ParamStore(dict(config.mock_params)), home,
                          config.seed, physics_hz=config.physics_hz, faults=faults,
                          unread_streams=unread, onboard=config.onboard)
    except (NativeBuildError, OSError) as exc:
        if not config.onboard:
            raise
        raise ValueError(f"the mock's onboard module cannot be built: {exc}") from exc
    if config.wind_m_s > 0.0:
        sim.autopilot.vehicle.set_wind(config.wind_ned())
    return sim


def read_mock_params(
    config: ReplayConfig,
    home: tuple[float, float, float],
    names: tuple[str, ...] = PLANNING_PARAM_NAMES,
    *,
    floats: bool = True,
    second_pass: bool = True,
    dt: float = 0.01,
    t_max: float = 10.0,
) -> ParamReadDone:
    """Read parameters from a fresh mock built from `config` (its `mock_params` applied) the
    way `fly` reads them from PX4: PARAM_REQUEST_READ by name over the lockstep link, with the
    client's retries, on simulated time (`floats`: each must come back as REAL32;
    `second_pass`: names not answered are asked for once more, as `Vehicle` does)."""
    sim = make_sim(config, home)
    link = VehicleLink(LinkConfig())
    lk = LockstepLink(sim, link, None, wanted=frozenset({22}))  # PARAM_VALUE only
    expect = {n: ParamType.REAL32 for n in names} if floats else None
    t = 0.0

    def read(wanted: tuple[str, ...]) -> ParamReadDone:
        nonlocal t
        done = [e for e in link.params.read(wanted, t, expect) if isinstance(e, ParamReadDone)]
        lk.to_vehicle(link.frames_to_send())
        while not done:
            t += dt
            if t > t_max:  # the client gives up after its tries long before this
                raise RuntimeError(f"parameter read from the mock did not finish in {t_max:g} s")
            done = [e for e in lk.advance(t) if isinstance(e, ParamReadDone)]
        return done[0]

    first = read(names)
    if not (second_pass and first.missing):
        return first
    again = read(first.missing)  # a second pass, as Vehicle.read_planning_params does
    return ParamReadDone(again.t_s, {**first.values, **again.values}, again.missing,
                         {**first.wrong_type, **again.wrong_type}, first.attempts + again.attempts)

