"""The mock's parameters carry PX4's metadata ranges (or the mock's own where PX4 has none):
PARAM_SET outside them is refused with a STATUSTEXT and the unchanged value echoed, and any
accepted value leaves the simulation running."""

from __future__ import annotations

import json
import lzma
import math
import struct
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.params import PARAMS, PX4_RANGES, ParamStore
from tests.sitl_mock.test_sitl_autopilot_core import flying
from tests.support.autopilot_harness import Harness

REPO = Path(__file__).resolve().parents[2]
_META = [d / "shared" / "px4_sitl" / "etc" / "extras" / "parameters.json.xz" for d in REPO.parents]


def _int_bits(v: int) -> float:
    return float(struct.unpack("<f", struct.pack("<i", v))[0])


def _set(h: Harness, name: str, value: float) -> None:
    spec = PARAMS[name]
    if spec.is_int and -(2**31) <= value < 2**31 and float(value).is_integer():
        h.send(mavlink.MAVLink_param_set_message(
            1, 1, name.encode(), _int_bits(int(value)), mavlink.MAV_PARAM_TYPE_INT32))
    else:
        h.send(mavlink.MAVLink_param_set_message(
            1, 1, name.encode(), value, mavlink.MAV_PARAM_TYPE_REAL32))


def test_ranges_match_px4_parameter_metadata() -> None:
    meta = next((p for p in _META if p.is_file()), None)
    if meta is None:
        pytest.skip("PX4 SITL's etc/extras/parameters.json.xz not found beside the repository")
    with lzma.open(meta) as f:
        doc = json.loads(f.read())
    px4 = {p["name"]: p for p in doc["parameters"]}
    for name, spec in PARAMS.items():
        if name not in px4:
            assert spec.mock_range, f"{name} is not a PX4 parameter: it needs a mock range"
            continue
        p = px4[name]
        assert spec.is_int == (p["type"] == "Int32"), name
        values = tuple(v["value"] for v in p.get("values", []))
        assert PX4_RANGES[name] == (p.get("min"), p.get("max"), values), name
        if not spec.mock_range:
            assert (spec.lo, spec.hi) == (p.get("min", -math.inf), p.get("max", math.inf)), name
        else:  # the mock's range may only narrow PX4's
            assert p.get("min", -math.inf) <= spec.lo and spec.hi <= p.get("max", math.inf), name


def test_every_parameter_has_a_bounded_range_holding_its_default() -> None:
    for name, spec in PARAMS.items():
        assert spec.values or (math.isfinite(spec.lo) and math.isfinite(spec.hi)), name
        assert spec.lo <= spec.default <= spec.hi, name
        assert not spec.values or spec.default in spec.values, name


@pytest.mark.parametrize(
    ("name", "value"),
    [("SIH_IXX", 1e6), ("SIH_MASS", 0.0), ("MPC_XY_P", -1.0), ("COM_OBL_RC_ACT", 3e9),
     ("COM_OBL_RC_ACT", 8), ("NAV_ACC_RAD", math.nan), ("MPC_THR_HOVER", math.inf)],
)
def test_out_of_range_param_set_is_refused_and_explained(name: str, value: float) -> None:
    h = Harness()
    h.run(0.2)
    before = h.ap.params[name]
    n_text = len(h.texts())
    _set(h, name, value)
    assert h.ap.params[name] == before
    echo = h.last("PARAM_VALUE")
    assert echo.param_id == name
    got = (struct.unpack("<i", struct.pack("<f", echo.param_value))[0]
           if PARAMS[name].is_int else echo.param_value)
    assert got == pytest.approx(before)
    assert any(name in t for t in h.texts()[n_text:])
    h.send(mavlink.MAVLink_param_request_list_message(1, 1))
    listed = {m.param_id for m in h.msgs("PARAM_VALUE")}
    assert listed == set(PARAMS)


def test_float_type_for_a_float_parameter_only() -> None:
    h = Harness()
    h.run(0.2)
    h.send(mavlink.MAVLink_param_set_message(
        1, 1, b"MPC_THR_HOVER", _int_bits(1), mavlink.MAV_PARAM_TYPE_INT32))
    assert h.ap.params["MPC_THR_HOVER"] == 0.5
    assert any("param types mismatch" in t for t in h.texts())


def test_store_rejects_out_of_range_overrides_at_start() -> None:
    with pytest.raises(ValueError, match="out of range"):
        ParamStore({"SIH_IXX": 1e6})


@pytest.mark.parametrize("kind", ["quad", "rover"])
def test_every_parameter_at_either_end_of_its_range_keeps_the_simulation_running(
    kind: str,
) -> None:
    """In flight (rover: armed), each parameter in turn at its lowest and highest value
    (enumerations: every value) for 0.3 s: the autopilot keeps its 1 Hz heartbeat and a finite
    state throughout."""
    h = Harness(step_s=0.02, vehicle_kind=kind)
    if kind == "quad":
        flying(h)
    else:
        h.wait_ready()
        h.arm()
    for name, spec in PARAMS.items():
        if name == "MAV_SYS_ID":
            continue  # changes who we talk to, by design
        extremes = list(spec.values) if spec.values else [spec.lo, spec.hi]
        for v in extremes:
            h.ap.params.set(name, v)
            h.run(0.3)
        h.ap.params.set(name, spec.default)
    t0 = h.now_boot
    h.run(3.0)
    assert len(h.msgs("HEARTBEAT", since=t0)) >= 2
    s = h.ap.state
    assert all(math.isfinite(x) for x in (*s.pos_ned, *s.vel_ned))


def _mc_airframe_defaults() -> dict[str, float] | None:
    """``param set-default NAME VALUE`` lines of PX4's multicopter defaults script (every MC
    airframe, SIH quad included, runs it), or None without PX4 SITL beside the repository."""
    for d in REPO.parents:
        script = d / "shared" / "px4_sitl" / "etc" / "init.d" / "rc.mc_defaults"
        if script.is_file():
            out: dict[str, float] = {}
            for line in script.read_text().splitlines():
                words = line.split()
                if len(words) == 4 and words[:2] == ["param", "set-default"]:
                    out[words[2]] = float(words[3])
            return out
    return None


def test_mock_has_every_planning_parameter_with_px4_multicopter_defaults() -> None:
    """The companion reads PLANNING_PARAM_NAMES from the vehicle: the mock answers each of them
    with PX4 v1.16's default for a multicopter (parameters.json, then rc.mc_defaults)."""
    from companion.mission.px4_params import PLANNING_PARAM_NAMES

    meta = next((p for p in _META if p.is_file()), None)
    mc = _mc_airframe_defaults()
    if meta is None or mc is None:
        pytest.skip("PX4 SITL's parameters.json.xz / rc.mc_defaults not found")
    with lzma.open(meta) as f:
        px4 = {p["name"]: p for p in json.loads(f.read())["parameters"]}
    for name in PLANNING_PARAM_NAMES:
        assert name in PARAMS, f"the mock lacks {name}"
        assert not PARAMS[name].is_int and px4[name]["type"] == "Float", name
        assert PARAMS[name].default == pytest.approx(mc.get(name, px4[name]["default"])), name
