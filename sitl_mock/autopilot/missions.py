"""Missions on the autopilot: the MAVLink mission protocol (upload, download, clear, set current)
and the executor that flies AUTO_MISSION, wired to the links.

The commander decides what a stored or finished mission means for the flight mode; it is told
through `on_loaded`, `on_item_current` and `on_finished`.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot.links import Link, Links
from sitl_mock.autopilot.shared import COMPID, SYSID, Clock, Msg, StateView, addressed_to_us
from sitl_mock.mission_server import MISSION, MissionExecutor, MissionServer
from sitl_mock.navigator import Navigator
from sitl_mock.params import ParamStore

MISSION_PROTOCOL_MESSAGES = (
    "MISSION_COUNT",
    "MISSION_ITEM",
    "MISSION_ITEM_INT",
    "MISSION_REQUEST",
    "MISSION_REQUEST_INT",
    "MISSION_REQUEST_LIST",
    "MISSION_ACK",
    "MISSION_CLEAR_ALL",
)


def _ignore(*_args: object) -> None:
    return None


class Missions:
    """The mission server (protocol), the executor, and MISSION_ITEM_REACHED repeats (1 Hz).

    home: (lat deg, lon deg, alt AMSL m), the executor's projection origin; mission_current:
    builds MISSION_CURRENT from the autopilot's status.
    """

    def __init__(
        self,
        clock: Clock,
        stats: Counter[str],
        links: Links,
        view: StateView,
        nav: Navigator,
        params: ParamStore,
        home: tuple[float, float, float],
        mission_current: Callable[[], Msg],
    ) -> None:
        self.clock = clock
        self.stats = stats
        self.links = links
        self.view = view
        self.mission_current = mission_current
        self.link_name = "offboard"  # the link of the last mission protocol message
        self.server = MissionServer(self._send_reply, links.statustext, self._on_changed,
                                    SYSID, COMPID)
        self.executor = MissionExecutor(
            nav, params, home, self._on_item_reached, self._on_item_current, self._on_finished
        )
        self.reached_seq: int | None = None
        self.reached_next_t = math.inf
        # the commander's hooks
        self.on_loaded: Callable[[], None] = _ignore
        self.on_item_current: Callable[[int], None] = _ignore
        self.on_finished: Callable[[bool], None] = _ignore

    def handlers(self) -> dict[str, Callable[[Link, Msg], None]]:
        """Message type -> handler for every mission message the autopilot takes."""
        out: dict[str, Callable[[Link, Msg], None]] = dict.fromkeys(
            MISSION_PROTOCOL_MESSAGES, self._on_protocol_message
        )
        out["MISSION_SET_CURRENT"] = self._on_set_current
        return out

    def update(self, t: float, flying_mission: bool) -> None:
        """Protocol timeouts / retries, the executor (in AUTO_MISSION), reached repeats."""
        if self.server.state != "idle":
            self.server.update(t)
        if flying_mission and self.executor.active:
            self.executor.update(t, self.view.state)
        if self.reached_seq is not None and t >= self.reached_next_t:
            self.reached_next_t += 1.0
            self.links.broadcast(mavlink.MAVLink_mission_item_reached_message(self.reached_seq))

    def _send_reply(self, msg: Msg) -> None:
        self.links.send(self.links.by_name[self.link_name], msg)

    def _on_protocol_message(self, link: Link, msg: Msg) -> None:
        if not addressed_to_us(self.stats, msg.target_system, msg.target_component):
            return
        self.link_name = link.name
        self.server.handle(msg, self.clock.t)

    def _on_set_current(self, link: Link, msg: Msg) -> None:
        if not addressed_to_us(self.stats, msg.target_system, msg.target_component):
            return
        if self.executor.set_current(int(msg.seq)):
            self.links.broadcast(self.mission_current())

    def _on_changed(self, mission_type: int) -> None:
        if mission_type != MISSION:
            return
        self.executor.load(self.server.items[MISSION])
        self.reached_seq = None
        self.reached_next_t = math.inf
        self.on_loaded()

    def _on_item_reached(self, seq: int) -> None:
        self.reached_seq = seq
        self.reached_next_t = self.clock.t + 1.0
        self.links.broadcast(mavlink.MAVLink_mission_item_reached_message(seq))

    def _on_item_current(self, seq: int) -> None:
        self.on_item_current(seq)

    def _on_finished(self, landed: bool) -> None:
        self.on_finished(landed)
