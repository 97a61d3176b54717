"""A wrong MPC_THR_HOVER must not cause an altitude error in attitude mode.

The mock PX4 (`sitl_mock serve` subprocess, loopback UDP) is made heavier with SIH_MASS so its
true hover throttle m g / (4 x SIH_T_MAX) is 0.6, while the companion is configured with
hover_thrust 0.5 (and the default 1 kg). The companion holds a point in attitude mode with its
own tracking controller; the oracle is the mock's own LOCAL_POSITION_NED. With the online
hover-thrust estimator the estimate converges to 0.6 and the altitude holds; without it the
altitude error is larger. Both runs fly at the same time (two mocks) to keep the test short.
"""

from __future__ import annotations

import asyncio
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from companion.control import Reference, TrackingConfig
from companion.flatness import MultirotorParams
from companion.flight.tracking import TrackingSource
from companion.mavlink import SetpointCommand, TelemetrySnapshot
from tests.integration import test_companion_vehicle as vehicle_tests
from tests.integration.test_companion_vehicle import MockFactory, connected, ours, read_tlog

mock_px4 = vehicle_tests.mock_px4  # the fixture: `sitl_mock serve` on an ephemeral port

G0 = 9.80665
ROTOR_MAX_N = 5.0  # the mock's SIH_T_MAX default (PX4 SIH)
TRUE_HOVER = 0.6
MOCK_MASS_KG = TRUE_HOVER * 4 * ROTOR_MAX_N / G0  # 1.2237 kg
HOLD_S = 9.0  # OFFBOARD hold duration after confirmation [s]
SETTLE_S = 5.0  # the altitude must hold from this long after the OFFBOARD request [s]


@dataclass
class HoldRun:
    # (unix time [s], trajectory time t_s [s], z NED [m], hover thrust in use) per setpoint
    samples: list[tuple[float, float, float, float]] = field(default_factory=list)
    z_ref: float = math.nan
    t_request: float = math.nan  # unix time of the OFFBOARD request (tlog)
    hover_final: float = math.nan  # the estimate at the end of the OFFBOARD hold


async def hold_point(port: int, tlog: Path, estimate: bool) -> HoldRun:
    """Take off, hold the takeoff point in attitude mode for HOLD_S, record z and the estimate."""
    run = HoldRun()
    params = MultirotorParams(
        mass=1.0, inertia=(0.025, 0.025, 0.030), hover_thrust=0.5, drag=1.0
    )
    async with connected(port, tlog) as v:
        await v.arm()
        await v.takeoff(2.5)
        assert v.telemetry.position is not None
        p0 = np.array(v.telemetry.position.pos_ned)
        run.z_ref = float(p0[2])
        ref = Reference(pos_ned=p0)
        source = TrackingSource(
            lambda _t: ref,
            "attitude",
            tracking=TrackingConfig(params=params, estimate_hover_thrust=estimate),
        )
        assert source.controller is not None
        ctl = source.controller

        def recording(t_s: float, tel: TelemetrySnapshot) -> SetpointCommand:
            sp = source(t_s, tel)
            if tel.position is not None:
                run.samples.append(
                    (time.time(), t_s, tel.position.pos_ned[2], ctl.hover_thrust)
                )
            return sp

        rep = await v.fly(mode="attitude", setpoint_source=recording, duration_s=HOLD_S)
        assert rep.stream.producer_errors == 0
        # the estimate while the companion flew (after HOLD_S the vehicle is told to hold)
        run.hover_final = max(run.samples, key=lambda s: (s[1] <= HOLD_S, s[1]))[3]
    msgs = read_tlog(tlog)
    reqs = [m for m in ours(msgs, "COMMAND_LONG") if m.command == 176 and m.param2 == 6]
    assert len(reqs) >= 1
    run.t_request = reqs[0]._timestamp
    masks = {m.type_mask for m in ours(msgs, "SET_ATTITUDE_TARGET")}
    assert masks == {3}, masks
    return run


async def test_hover_thrust_estimate_converges_and_holds_altitude(
    mock_px4: MockFactory, tmp_path: Path
) -> None:
    mass = f"SIH_MASS={MOCK_MASS_KG:.5f}"
    port_on = mock_px4("--param", mass)
    port_off = mock_px4("--param", mass)
    on, off = await asyncio.wait_for(
        asyncio.gather(
            hold_point(port_on, tmp_path / "hte_on.tlog", True),
            hold_point(port_off, tmp_path / "hte_off.tlog", False),
        ),
        90.0,
    )

    def errors(run: HoldRun) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Time since the OFFBOARD request [s], altitude error [m], companion flying (bool)."""
        s = np.array(run.samples)
        s = s[s[:, 0] >= run.t_request]
        return s[:, 0] - run.t_request, s[:, 2] - run.z_ref, (s[:, 1] > 0) & (s[:, 1] <= HOLD_S)

    t_on, e_on, fly_on = errors(on)
    t_off, e_off, fly_off = errors(off)
    # from SETTLE_S after the OFFBOARD request to the end of the hold (then Hold is requested)
    w_on, w_off = (t_on >= SETTLE_S) & fly_on, (t_off >= SETTLE_S) & fly_off
    assert w_on.sum() > 200 and w_off.sum() > 200  # >= 2 s at 100 Hz
    late_on = float(np.abs(e_on[w_on]).max())
    late_off = float(np.abs(e_off[w_off]).max())
    rms_on = float(np.sqrt(np.mean(e_on[fly_on] ** 2)))
    rms_off = float(np.sqrt(np.mean(e_off[fly_off] ** 2)))
    numbers = (
        f"hover estimate {on.hover_final:.4f} (true {TRUE_HOVER}, prior 0.5); altitude error "
        f"after {SETTLE_S:g} s: max {late_on:.3f} m with the estimator, {late_off:.3f} m "
        f"without; RMS while the companion flew: {rms_on:.3f} m with, {rms_off:.3f} m without"
    )
    print(numbers)
    # nothing is learned while priming (PX4 does not apply those setpoints): prior until engaged
    primed = [h for _, t, _, h in on.samples if t <= 0.0]
    assert primed and all(h == 0.5 for h in primed), (min(primed), max(primed))
    assert abs(on.hover_final - TRUE_HOVER) <= 0.05 * TRUE_HOVER, numbers
    assert off.hover_final == 0.5, numbers  # disabled: the configured value stays in use
    assert late_on <= 0.3, numbers
    assert late_off > late_on, numbers
    assert rms_off > rms_on, numbers
