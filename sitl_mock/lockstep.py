"""Lockstep in-process API: the mock autopilot on a simulated clock over an in-memory link.

Simulated time advances only when the caller asks (`step_until`, `step`), as fast as the CPU
allows, so a replay or a test is deterministic for a given seed and input sequence::

    sim = LockstepSim("quad", seed=1)
    sim.send(heartbeat_bytes)          # delivered at sim.now
    sim.step_until(5.0)                # 5 simulated seconds after boot
    for datagram in sim.recv(): ...    # MAVLink 2 datagrams the autopilot sent, in order
"""

from __future__ import annotations

from collections.abc import Mapping

from sitl_mock.autopilot import Autopilot
from sitl_mock.faults import LinkFaults, ScenarioFaults
from sitl_mock.params import ParamStore
from sitl_mock.vehicle import DEFAULT_HOME

CLIENT_ADDR = ("lockstep-client", 14540)


class LockstepSim:
    """The autopilot's offboard link as an in-memory datagram pipe on simulated time [s].

    Time starts at 0 (boot). `send(data)` delivers a datagram at the current simulated time;
    `recv()` returns (and forgets) every datagram the autopilot has sent up to now.
    `unread_streams`: telemetry message ids the caller never reads (and logs nowhere); they
    are not built, and every other datagram is the same (`Autopilot.quiet_streams`).
    `onboard`: the autopilot hosts the onboard module (`sitl_mock.onboard`).
    """

    def __init__(
        self,
        kind: str = "quad",
        params: ParamStore | Mapping[str, float] | None = None,
        home: tuple[float, float, float] = DEFAULT_HOME,
        seed: int = 0,
        *,
        physics_hz: float = 250.0,
        faults: tuple[LinkFaults | None, LinkFaults | None] | None = None,
        scenario: ScenarioFaults | None = None,
        estimator_ready_s: float = 3.0,
        unread_streams: frozenset[int] = frozenset(),
        onboard: bool = False,
    ) -> None:
        self.autopilot = Autopilot(
            kind,
            params,
            home,
            seed,
            physics_hz=physics_hz,
            now=0.0,
            remotes={"offboard": CLIENT_ADDR},
            link_faults={"offboard": faults} if faults is not None else None,
            scenario=scenario,
            estimator_ready_s=estimator_ready_s,
            onboard=onboard,
        )
        if unread_streams:
            self.autopilot.quiet_streams("offboard", unread_streams)
        self._now = 0.0
        self._inbox: list[bytes] = []

    @property
    def now(self) -> float:
        """Simulated seconds since boot."""
        return self._now

    def send(self, data: bytes) -> None:
        """Deliver one datagram (one or more MAVLink frames) to the autopilot now."""
        self.autopilot.receive_datagram(data, CLIENT_ADDR, self._now, "offboard")
        self._drain()

    def recv(self) -> list[bytes]:
        """Datagrams the autopilot sent since the last call, oldest first."""
        self._drain()
        out, self._inbox = self._inbox, []
        return out

    def step_until(self, t_s: float) -> None:
        """Advance simulated time to `t_s` (no-op if not in the future)."""
        if t_s > self._now:
            self._now = t_s
            self.autopilot.advance(t_s)
            self._drain()

    def step(self, dt_s: float) -> None:
        """Advance simulated time by `dt_s` seconds."""
        self.step_until(self._now + dt_s)

    def _drain(self) -> None:
        self._inbox += self.autopilot.frames_to_send(self._now, "offboard")
