"""The companion reads the PX4 parameters it plans with from real PX4 v1.16 SITL (SIH quad).

Oracles are PX4's own: its parameter metadata (etc/extras/parameters.json.xz) with the
multicopter airframe defaults (etc/init.d/rc.mc_defaults), its MAV_SYS_ID (the instance's
system id, an INT32 sent bytewise), and a value set with PARAM_SET first.
"""

from __future__ import annotations

import json
import lzma

import pytest
from pymavlink.dialects.v20 import common as mavlink2

from companion.aio import ParamReadError, Vehicle, VehicleConfig
from companion.mavlink import LinkConfig
from companion.mission.px4_params import PLANNING_PARAM_NAMES
from companion.planning.vehicle_params import read_planning_params
from px4_harness import Px4Sitl


def _px4_defaults(px4: Px4Sitl) -> dict[str, float]:
    """PX4's default of every parameter, with the multicopter airframes' set-defaults."""
    etc = px4.location.etc
    with lzma.open(etc / "extras" / "parameters.json.xz") as f:
        out = {p["name"]: float(p["default"]) for p in json.loads(f.read())["parameters"]}
    for line in (etc / "init.d" / "rc.mc_defaults").read_text().splitlines():
        words = line.split()
        if len(words) == 4 and words[:2] == ["param", "set-default"]:
            out[words[2]] = float(words[3])
    return out


async def test_planning_parameters_read_from_px4_are_its_defaults_and_follow_param_set(
    px4: Px4Sitl,
) -> None:
    defaults = _px4_defaults(px4)
    link = LinkConfig(target_sysid=px4.target_system)
    async with Vehicle.connect(px4.url, config=VehicleConfig(connect_timeout_s=15.0),
                               link_config=link) as v:
        r = await read_planning_params(v.fetch_params)
        assert r.defaulted == () and r.warnings == ()
        for name in PLANNING_PARAM_NAMES:
            assert r.vehicle_values[name] == pytest.approx(defaults[name], rel=1e-6), name
        assert r.params.NAV_ACC_RAD == 2.0 and r.params.RTL_RETURN_ALT == 30.0  # MC airframe

        sysid = await v.read_params(["MAV_SYS_ID"])  # INT32, bytewise on the wire
        assert sysid == {"MAV_SYS_ID": float(px4.target_system)}

        v.link.send_message(mavlink2.MAVLink_param_set_message(
            px4.target_system, 1, b"MPC_XY_CRUISE", 7.5, mavlink2.MAV_PARAM_TYPE_REAL32))
        v._flush()
        assert await v.read_params(["MPC_XY_CRUISE"], floats_only=True) == {
            "MPC_XY_CRUISE": 7.5}

        # PX4 v1.16 does not answer a name it does not have: named after three tries
        with pytest.raises(ParamReadError) as exc:
            await v.read_params(["MPC_XY_CRUISE", "ECCA_NO_PARAM"])
        assert exc.value.missing == ("ECCA_NO_PARAM",)
        assert exc.value.values == {"MPC_XY_CRUISE": 7.5}
